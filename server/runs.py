"""Runs: the requests on them, the queue of runs waiting for a solver process, the solver
processes that step them and their restarts. This module composes the parts: the run records
and their folder (``server.records``), the bridge thread booking the solvers' events
(``server.bridge``), the error estimates (``server.estimate``) and the kept frames
(``server.history``). Nothing here waits on a solve.

A new run joins the queue; a free solver process (``Slot``; ``settings.solvers`` of them)
takes the first queued run, and takes the next when its run ends, in whatever way it ends. A
queued run can be cancelled, and never starts. The queue is bounded (``settings.queue_limit``):
past it a start is refused (429) rather than left to wait for hours.

``RunManager.lock`` guards the run records, the queue and the slots, and is held only for
bookkeeping (a few dict and list updates, commands put on the solvers' queues): the viewer's
pushes, file writes, the error estimate and recording repairs run outside it, so a status
request never waits on them.
"""

from __future__ import annotations

import collections
import secrets
import threading
import time
from typing import TYPE_CHECKING

from server import scenediff, tomlout
from server.bridge import Bridge
from server.estimate import EstimateCache
from server.events import Changes
from server.history import Histories
from server.problems import Busy, Conflict, Invalid, NotFound, NotReady
from server.records import (
    ACTIVE,
    AS_WRITTEN,
    CANCELLED,
    QUEUED,
    Run,
    RunFiles,
    ordinal,
    repair_recording,
)
from server.settings import Settings, check_run_id
from server.store import SceneStore
from server.views import Views
from server.worker import worker_main
from server.workerhandle import Slot, WorkerHandle, WorkerTarget, solvers
from sim.stepping import parameters as live

if TYPE_CHECKING:  # imports viser
    from server.viewer import Viewer


class RunManager:
    def __init__(self, settings: Settings, store: SceneStore,
                 worker_target: WorkerTarget = worker_main):
        self.settings, self.store = settings, store
        self.files = RunFiles(settings.runs_dir)
        self.estimates = EstimateCache(settings.runs_dir)
        self.history = Histories(settings.solvers, settings.history_frames,
                                 settings.history_bytes)
        # live parameters and their ranges come from the solver process once it has imported
        # the solver: the server never imports it, so the page is up in about a second
        self.parameter_ranges: dict = {}
        self.ready = threading.Event()
        self.lock = threading.RLock()
        self.changes = Changes()  # wakes the event streams of scripts (server.events)
        self.runs: dict[str, Run] = self.files.load()
        self.queue: list[str] = []  # the queued runs' ids, the next to start first
        self._starts: dict[str, dict] = {}  # a queued run's start command, sent when it starts
        self.waiters: dict[int, dict] = {}  # request id -> {"event", "reply"}
        self.sent: dict[int, str] = {}  # request id -> run id, until the solver replies
        self.logs: collections.deque = collections.deque(maxlen=50)  # the solver's log events
        self.viewer: Viewer | None = None  # set by the app when the viewer is on
        self._solvers = solvers(settings, worker_target)  # local processes or a Dask cluster
        self.slots = [Slot(self._new_worker()) for _ in range(max(1, settings.solvers))]
        self.views = Views(self)  # what the page and the viewer show
        self._retired: list[WorkerHandle] = []  # ended by a stop during a build; the bridge closes
        self.restarts = 0
        # why the last solvers were replaced, newest last: what an operator (or a failing test)
        # reads when runs do not start, e.g. a Dask cluster whose workers cannot make one
        self.losses: collections.deque = collections.deque(maxlen=5)
        self.closing = threading.Event()  # the server shuts down: no new solver process
        self.bridge = Bridge(self)

    # ---- life cycle -------------------------------------------------------------------------
    def _new_worker(self) -> WorkerHandle:
        return self._solvers.new()

    def start(self) -> None:
        if self.viewer:
            self.viewer.set_runs(self.run_ids())
            self.views.show_selected()
        self.bridge.start()

    def close(self) -> None:
        """Shut down: the queued runs are cancelled (first: no run starts meanwhile), the
        active runs are stopped by their solvers (result.json and a closed recording) when
        they answer within ``stop_timeout``; no new solver process starts."""
        with self.lock:
            cancelled = [self._cancel(self.runs[r], "not run: the server shut down before "
                                                    "its turn") for r in list(self.queue)]
            running = [(s, self.runs.get(s.run or "")) for s in self.slots]
        for run in cancelled:
            self.save(run)
        if self.bridge.running():
            for slot, run in running:
                if run is not None and slot.worker.alive():
                    slot.worker.send("stop", reason="server shut down")
            deadline = time.monotonic() + self.settings.stop_timeout
            while self.active_runs() and time.monotonic() < deadline:
                time.sleep(0.02)
        self.closing.set()  # the bridge ends its loop
        self.bridge.join(2.0)
        self.close_retired()
        for slot, _ in running:  # all asked at once: the processes exit side by side
            if slot.worker.alive():
                slot.worker.send("shutdown")
        for slot, run in running:
            self._close_slot(slot, run)
        self._solvers.close()

    def _close_slot(self, slot: Slot, run: Run | None) -> None:
        """At shutdown: end the slot's process (a solver still inside a step is asked, then
        killed) and its run, if the solver did not."""
        clean = slot.worker.close()
        if run is None:
            return
        note = self.repair(run) if not clean else ""
        with self.lock:
            if run.state in ACTIVE:
                self.finish(run, "stopped", "server shut down" + note)
        self._result_if_missing(run)
        self.save(run)

    def repair(self, run: Run) -> str:
        """Make the recording of a run whose solver was killed verifiable again; returns what
        to add to the run's reason ("" when all went well)."""
        with self.bridge.repairing_recording(run.id):
            return repair_recording(self.files.recording(run.id))

    def save(self, run: Run) -> None:
        with self.lock:  # a consistent snapshot; the encoding and the write come after
            snapshot = run.snapshot()
        self.files.save(run.id, snapshot)

    def health(self) -> dict:
        b = self.bridge
        with self.lock:
            solvers = [{"pid": s.worker.pid, "alive": s.worker.alive(), "run": s.run}
                       for s in self.slots]
            queued = list(self.queue)
        bridge, workers = b.alive(), all(s["alive"] for s in solvers)
        return {"ok": bridge and workers, "worker_alive": workers,
                "worker_pid": solvers[0]["pid"], "worker_restarts": self.restarts,
                "solvers": solvers, "bridge_alive": bridge, "repairing_recording": b.repairing,
                "bridge_errors": b.errors, "bridge_error": b.error,
                "active": [s["run"] for s in solvers if s["run"]], "queued": queued,
                "queue_limit": self.settings.queue_limit,
                "solver_losses": list(self.losses), "solver_log": list(self.logs)[-5:]}

    def active_runs(self) -> list[str]:
        """The runs on a solver process now."""
        with self.lock:
            return [s.run for s in self.slots if s.run]

    # ---- requests ---------------------------------------------------------------------------
    def get(self, run_id: str) -> Run:
        check_run_id(run_id)
        try:
            return self.runs[run_id]
        except KeyError:
            raise NotFound(f"no run {run_id!r}") from None

    def list(self) -> list[dict]:
        """Every run, newest first, with what the Runs table shows: its ``results`` (peak
        punch force, minimum thickness, maximum thinning, from result.json) besides the
        summary."""
        with self.lock:
            out = [r.summary() for r in sorted(self.runs.values(), key=lambda r: -r.created)]
        for r in out:  # reads files: outside the lock
            r["results"] = {} if r["state"] in ACTIVE else self.files.tabled(r["id"])
        return out

    def status(self, run_id: str, since: int = 0, limit: int | None = None) -> dict:
        """The run's summary, its step records after step ``since`` (at most ``limit``) and
        ``records_left``: how many more follow those."""
        with self.lock:
            run = self.get(run_id)
            after = [r for r in run.records if r["step"] > since]
            page = after[:limit]
            out = {**run.summary(), "records": page, "records_left": len(after) - len(page)}
            # a queued run waits on the runs the solvers hold: a paused one holds its solver
            # until it is resumed or stopped, which the page says (it waited in silence)
            out["waiting_for"] = [{"id": s.run, "state": self.runs[s.run].state}
                                  for s in self.slots if s.run and s.run in self.runs] \
                if run.state == QUEUED else []
            # a run saved before its status held every parameter: the others were as written
            out["parameters"] = self._start_values(out["parameters"])
        out["estimate"] = self.estimates.get(run)  # reads files: outside the lock
        return out

    def _edits(self, scene: str, text: str) -> list[str]:
        """What the page's edits ``text`` changed of the saved ``scene`` (none saved: [])."""
        try:
            return scenediff.edits(self.store.text(scene), text)
        except NotFound:
            return []

    def run_ids(self) -> list[str]:
        """Every run, newest first."""
        with self.lock:
            return [r.id for r in sorted(self.runs.values(), key=lambda r: -r.created)]

    def start_run(self, scene: str, element: str | None = None, overrides: dict | None = None,
                  parameters: dict | None = None, paused: bool = False,
                  toml: str | None = None, by: str | None = None) -> Run:
        """Validate the run (scene, element, parameters, model size), then queue it: it
        starts at once on a free solver process, else when one is free (its ``place`` in the
        queue says when); refused with a reason naming the field before anything is written,
        and with 429 when the queue is full. ``toml``: the scene as the page shows it, edits
        not saved yet; it is validated as a saved scene is, and runs (kept as the run's
        scene.toml) instead of the saved file. The new run is selected in the view ``by``
        (the page that started it; None: the default view of scripts)."""
        text, edited = self.store.run_text(scene, toml)
        overrides = dict(overrides or {})
        if element:
            overrides["shell.element"] = element
        spec, solver_overrides = self.store.checked(text, overrides,
                                                    self.settings.max_model_bytes)
        edits = self._edits(scene, text) if edited else []
        tools = live.per_tool(spec.tools)  # its per-tool live parameters
        for name, value in (parameters or {}).items():
            self.check_parameter(name, value, tools)
        with self.lock:
            self._check_room()
            stamp = time.strftime("%Y%m%d-%H%M%S")
            run = Run(f"{scene}-{spec.shell.element}-{stamp}-{secrets.token_hex(2)}", scene,
                      spec.shell.element, overrides, time.time(), edited=edited, edits=edits,
                      parameters=self._start_values({**dict.fromkeys(tools, AS_WRITTEN),
                                                     **(parameters or {})}),
                      given=dict(parameters or {}),
                      scene_element=scenediff.element_of(text, spec.shell.element))
            run.place = len(self.queue) + 1  # run.json says queued, and where
            ran = text if run.scene_element is None else tomlout.with_element(text, run.element)
            out = self.files.create(run, scenediff.ran_head(
                run.id, scene, text, edits if edited else None, overrides, parameters,
                run.scene_element) + ran)
            self.runs[run.id] = run
            self._starts[run.id] = dict(run=run.id, out=str(out), scene_toml=text,
                                        overrides=solver_overrides,
                                        parameters=parameters or {}, paused=paused,
                                        record_every=self.settings.record_every)
            self.queue.append(run.id)
            self._dispatch()
        if self.viewer:
            self.viewer.set_runs(self.run_ids())
        self.views.started(run, by)
        return run

    def _start_values(self, given: dict) -> dict:
        """Every live parameter's value at the start: as written unless ``given``. The solver's
        own values replace these once it has built the run (its ``meta``)."""
        return {**dict.fromkeys(self.parameter_ranges, AS_WRITTEN), **given}

    def command(self, run_id: str, cmd: str) -> dict:
        """pause, resume, step or stop an active run; stop a queued one (it never starts)."""
        with self.lock:
            run = self.get(run_id)
            if run.state == QUEUED:
                if cmd != "stop":
                    raise Conflict(f"run {run_id!r} is queued ({ordinal(run.place)} in the "
                                   f"queue): it can only be stopped (cancelled) until it "
                                   "starts")
                self._cancel(run, "cancelled before it started")
                old = None
            elif run.state not in ACTIVE:
                raise Conflict(f"run {run_id!r} is {run.state}, not active")
            elif cmd == "stop" and run.state in ("starting", "building"):
                old = self._end_build(run)
            elif cmd == "resume" and run.state == "running":  # a page's stale button, say
                raise Conflict(f"run {run_id!r} is running, not paused: nothing to resume")
            else:
                if cmd in ("pause", "step"):
                    run.state = "paused"  # at once, so a status read after the request agrees
                elif cmd == "resume" and run.state == "paused":
                    run.state = "running"
                rid = self._send(run, cmd)
                if cmd == "stop":
                    grace = threading.Timer(self.settings.stop_grace, self._stop_overdue,
                                            (run.id, rid))
                    grace.daemon = True
                    grace.start()
                return run.summary()
        self._after_build_ended(run, old)
        return run.summary()

    def check_parameter(self, name: str, value: object, tools: dict) -> float:
        """``value`` for the live parameter ``name`` of a run whose per-tool parameters are
        ``tools`` (sim.stepping.parameters.per_tool), in its range; Invalid naming the
        parameter (and an unknown tool) otherwise."""
        if not self.ready.wait(self.settings.ack_timeout):
            raise NotReady("the solver process is still starting (it names the live "
                           "parameters); retry in a moment")
        try:
            return live.check(name, value, {**self.parameter_ranges, **tools})
        except ValueError as exc:
            raise Invalid(str(exc)) from None

    def set_parameter(self, run_id: str, name: str, value: object) -> dict:
        """Send a live parameter change and wait (``ack_timeout``) for the solver to say from
        which step it applies. A solver inside a long step answers later: then ``applied`` is
        false and the step appears in the run's ``parameter_log``."""
        with self.lock:
            run = self.get(run_id)
            # the run's per-tool parameters: those its start values name (from its scene)
            tools = live.per_tool_of(run.parameters)
        value = self.check_parameter(name, value, tools)
        waiter = {"event": threading.Event(), "reply": None}
        with self.lock:  # the bridge handles the reply under this lock: registered in time
            if run.state not in ACTIVE:
                raise Conflict(f"run {run_id!r} is {run.state}, not active")
            rid = self._send(run, "set", name=name, value=value)
            self.waiters[rid] = waiter
        answered = waiter["event"].wait(self.settings.ack_timeout)
        with self.lock:
            self.waiters.pop(rid, None)
        out = {"run": run.id, "name": name, "value": value, "applied": False,
               "applies_from_step": None}
        if not answered:
            out["detail"] = ("sent; the solver is inside a step and applies it from the next: "
                             "see parameter_log in the run's status")
            return out
        reply = waiter["reply"]
        if not reply["ok"]:
            raise Conflict(f"{name}: the solver refused: {reply['error']}")
        return {**out, "applied": True, "applies_from_step": reply["result"]["step"]}

    def delete(self, run_id: str, by: str | None = None) -> str | None:
        """Delete a run that has ended, or a queued one (which then never starts); ``by``:
        the view that asked. Returns the notice when the run was another view's."""
        with self.lock:
            run = self.get(run_id)
            if run.state in ACTIVE:
                raise Conflict(f"run {run_id!r} is {run.state}; stop it first")
            if run.state == QUEUED:
                self._cancel(run, "deleted before it started")
            del self.runs[run.id]
            self.history.forget(run.id)
        self.changes.touch()
        self.estimates.forget(run.id)
        self.files.delete(run.id)
        if self.viewer:
            self.viewer.set_runs(self.run_ids())
        return self.views.deleted(run, by)

    # ---- the run records: changed under ``lock`` ----------------------------------------------
    def _slot(self, run_id: str) -> Slot | None:
        """Under ``lock``: the slot stepping ``run_id``, if any."""
        return next((s for s in self.slots if s.run == run_id), None)

    def _send(self, run: Run, cmd: str, **kw: object) -> int:
        """Under ``lock``: a command for the active ``run``, listed in its ``pending`` until
        the solver replies."""
        rid = self._slot(run.id).worker.send(cmd, **kw)
        self.sent[rid] = run.id
        run.pending.append(cmd)
        return rid

    def finish(self, run: Run, state: str, reason: str | None) -> None:
        """Under ``lock``: the run is over; its solver process, if it had one, takes the next
        queued run. The caller saves it (outside the lock)."""
        run.state, run.reason = state, reason
        run.ended = time.time()
        run.pending.clear()  # what the solver did not do, it will not do for this run
        self.sent = {rid: r for rid, r in self.sent.items() if r != run.id}
        slot = self._slot(run.id)
        if slot is not None:
            slot.run = None
            self._dispatch()
        self.changes.touch()

    # ---- the queue: changed under ``lock`` ----------------------------------------------------
    def _check_room(self) -> None:
        """Under ``lock``: refuse a new run when every solver is busy and the queue full."""
        limit = self.settings.queue_limit
        if len(self.queue) >= limit and all(s.run for s in self.slots):
            raise Busy(f"the run queue is full: {len(self.queue)} runs wait for "
                       f"{len(self.slots)} solver process(es) (the server's --queue {limit}); "
                       "start this one when a queued run has started, or cancel one")

    def _dispatch(self) -> None:
        """Under ``lock``: the first queued runs start on the free solver processes (one
        found dead waits for the bridge to replace it); the rest learn their new places."""
        for slot in self.slots:
            if not self.queue or self.closing.is_set():
                break
            if slot.run is None and slot.worker.alive():
                run = self.runs[self.queue.pop(0)]
                slot.run, run.state, run.started, run.place = run.id, "starting", time.time(), \
                    None
                self.history.start(run.id, {s.run for s in self.slots if s.run})
                slot.worker.send("start", **self._starts.pop(run.id))
        self._renumber()

    def _renumber(self) -> None:
        for place, run_id in enumerate(self.queue, 1):
            self.runs[run_id].place = place

    def _cancel(self, run: Run, reason: str) -> Run:
        """Under ``lock``: a queued run leaves the queue, never to start. The caller saves it
        (outside the lock)."""
        self.queue.remove(run.id)
        self._starts.pop(run.id, None)
        self.finish(run, CANCELLED, reason)
        run.place = None
        self._renumber()
        return run

    def run_ended(self, run: Run) -> None:
        """The viewer's line and controls for a run that is over (when it is shown)."""
        if self.viewer:
            with self.lock:
                line = run.line()
            self.viewer.run_status(run.id, line, active=False, controls=())

    def note(self, run_id: str | None, text: str) -> None:
        """Replace the run's reason (a problem that does not end it)."""
        with self.lock:
            run = self.runs.get(run_id or "")
            if run is not None:
                run.reason = text

    def fail_run(self, run_id: str | None, reason: str) -> None:
        """The server cannot follow an active run any more: fail it, and stop its solver
        (which closes the recording; its later events for this run are ignored)."""
        with self.lock:
            slot = self._slot(run_id or "")
            if slot is None:
                return
            run = self.runs[slot.run]
            slot.worker.send("stop", reason=reason)  # before the next run's start
            self.finish(run, "failed", reason)
        self.save(run)

    def _result_if_missing(self, run: Run, reason: str | None = None) -> None:
        """A run whose solver ended without writing result.json gets one from what the
        server knows: the reason (``reason``, else the run's own) and the step records."""
        with self.lock:
            reason, steps = reason or run.reason or run.state, list(run.records)
        problem = self.files.result_if_missing(run.id, run.scene, run.element, reason, steps)
        if problem:
            self.note(run.id, f"{reason}; {problem}")

    # ---- the solver process: ended by a stop during a build, or dead --------------------------
    def _end_build(self, run: Run) -> WorkerHandle:
        """Under ``lock``: stop a run that is still building. The solver process reads commands
        only between steps, and a build is one long call (minutes for a large model), so the
        process is killed and a new one started: the stop takes effect at once, and the memory
        the build held is freed. Returns the old process's handle."""
        old, how = self._replace(run)
        self.finish(run, "stopped", f"stopped during the build ({how} and a new one started)")
        return old

    def _replace(self, run: Run) -> tuple[WorkerHandle, str]:
        """Under ``lock``: kill ``run``'s solver process and start a new one in its slot;
        the old process's handle and how it ended."""
        slot = self._slot(run.id)
        old = slot.worker
        how = old.kill()
        slot.worker = self._new_worker()
        self.restarts += 1
        return old, how

    def _stop_overdue(self, run_id: str, rid: int) -> None:
        """A stop sent ``stop_grace`` seconds ago: if the solver has not answered it (it is
        still inside a step), its process is killed and a new one started, and the run ends
        stopped with the steps it finished: result.json from them and its recording repaired
        before it reads as stopped (as ``worker_died`` does), so a client that sees it stopped
        finds them. The new process takes the next queued run once it has."""
        with self.lock:
            run = self.runs.get(run_id)
            if (run is None or run.state not in ACTIVE or self.sent.get(rid) != run_id
                    or self.closing.is_set()):
                return
            old, how = self._replace(run)
        reason = (f"stopped by request in step {run.step + 1}, which had not ended "
                  f"{self.settings.stop_grace:g} s after the stop ({how} and a new one started)")
        self._retire(old)
        reason += self._mend(run, reason)
        with self.lock:
            self.finish(run, "stopped", reason)
        self.save(run)
        self.run_ended(run)

    def _after_build_ended(self, run: Run, old: WorkerHandle | None) -> None:
        """The files of a run whose build was stopped: result.json, its recording repaired if
        the build had finished after all and steps were recorded, run.json. ``old``: the
        process ended; None for a queued run, which has no files to mend."""
        if old is None:
            self.save(run)
            self.run_ended(run)
            return
        self._retire(old)
        note = self._mend(run)
        if note:
            self.note(run.id, run.reason + note)
        self.save(run)
        self.run_ended(run)

    def _retire(self, old: WorkerHandle) -> None:
        """A killed solver process: reaped, its handle closed later (:meth:`close_retired`)."""
        old.join(5.0)
        self._retired.append(old)

    def _mend(self, run: Run, reason: str | None = None) -> str:
        """The files of a run whose solver process was killed in it: result.json from what the
        server knows (:meth:`_result_if_missing`) and its recording, if any, repaired; returns
        what the repair adds to the reason."""
        self._result_if_missing(run, reason)
        return self.repair(run) if self.files.recording(run.id).is_file() else ""

    def close_retired(self) -> None:
        """Close the handles of processes ended by a stop (during a build, or overdue; the
        bridge calls this: it is the one thread that reads their queues)."""
        while self._retired:
            self._retired.pop().close(timeout=0.1)

    def worker_died(self, w: WorkerHandle) -> None:
        """The bridge found a solver process dead: fail its run (after repairing the
        recording, so a download after that verifies) and start a new process in its slot,
        which then takes the next queued run. The other slots' runs go on."""
        with self.lock:
            slot = next((s for s in self.slots if s.worker is w), None)
            if slot is None:  # already replaced (a build stopped by request)
                return
            run = self.runs.get(slot.run or "")
        note = self.repair(run) if run is not None else ""
        reason = f"{w.death()}{note}"
        self.losses.append(reason)
        if run is not None:
            # before the run reads as failed: a client that sees it failed finds its result.json
            self._result_if_missing(run, reason)
        with self.lock:
            if self.closing.is_set() or slot.worker is not w:
                return
            slot.worker = self._new_worker()
            self.restarts += 1
            if run is not None and slot.run == run.id:
                self.finish(run, "failed", reason)
            self._dispatch()
        w.close(timeout=0.1)
        if run is not None:
            self._result_if_missing(run)
            self.save(run)
            self.run_ended(run)


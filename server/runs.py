"""Runs: their state, the solver process that steps them, and the bridge thread that carries
its events to the run records and the viewer. Nothing here waits on a solve.

``RunManager.lock`` guards the run records and is held only for bookkeeping (a few dict and
list updates): the viewer's pushes, file writes, the error estimate and recording repairs run
outside it, so a status request never waits on them. One bad event never stops the bridge: an
error while handling it fails the active run with the reason (the solver is told to stop), a
viewer error is reported on the run, and the bridge's liveness is part of ``/api/health``.
"""

from __future__ import annotations

import collections
import copy
import json
import queue
import secrets
import sys
import threading
import time
import traceback
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

from server.estimate import estimate as study_estimate
from server.estimate import find_study
from server.history import FrameHistory
from server.problems import Conflict, Invalid, NotFound, NotReady
from server.settings import Settings, check_run_id
from server.store import SceneStore, atomic_write
from server.worker import worker_main
from server.workerhandle import WorkerHandle
from sim.frames import results
from sim.model import size
from sim.scene.load import SceneError, scene_from_toml

ACTIVE = {"starting", "building", "running", "paused"}
HEARTBEAT_S = 5.0  # a bridge silent for longer than this is reported dead
LOST = "the server stopped during the run"


@dataclass
class Run:
    id: str
    scene: str
    element: str
    overrides: dict
    created: float
    state: str = "starting"
    reason: str | None = None
    step: int = 0
    n_steps: int | None = None
    counts: dict | None = None
    probes: list[str] = field(default_factory=list)
    tools: list[str] = field(default_factory=list)
    timing: dict = field(default_factory=dict)  # build_s, tool_meshes_s, first_frame_s, ...
    parameters: dict = field(default_factory=dict)
    parameter_log: list[dict] = field(default_factory=list)
    # frames made and dropped (queue full) by the solver; received and pushed to the viewer here
    frames: dict = field(default_factory=dict)
    records: list[dict] = field(default_factory=list)
    # commands sent to the solver that it has not done yet, in order (pause, step, set, ...):
    # empty once it has acted on every request (a step asked for is then made)
    pending: list[str] = field(default_factory=list)
    # finished runs: error estimate from a study of the scene, and the run's cost
    estimate: dict | None = None

    def summary(self) -> dict:
        """Everything but the records, copied (the bridge may change the run meanwhile)."""
        return {f.name: copy.deepcopy(getattr(self, f.name)) for f in fields(self)
                if f.name != "records"}


class RunManager:
    def __init__(self, settings: Settings, store: SceneStore, worker_target=worker_main):
        self.settings, self.store = settings, store
        self.root = settings.runs_dir
        self.root.mkdir(parents=True, exist_ok=True)
        # live parameters and their ranges come from the solver process once it has imported
        # the solver: the server never imports it, so the page is up in about a second
        self.parameter_ranges: dict = {}
        self.ready = threading.Event()
        self.lock = threading.RLock()
        self._save_lock = threading.Lock()
        self._estimate_lock = threading.Lock()
        self.runs: dict[str, Run] = self._load()
        self.active: str | None = None
        self.viewer = None
        self.history = FrameHistory(settings.history_frames, settings.history_bytes)
        self._target = worker_target
        self.worker = self._new_worker()
        self._retired: list[WorkerHandle] = []  # ended by a stop during a build; the bridge closes
        self.restarts = 0
        self._stop = threading.Event()
        self.bridge = threading.Thread(target=self._bridge, name="q3t-bridge", daemon=True)
        self.heartbeat = time.monotonic()
        self.repairing: str | None = None  # the run whose recording the bridge is repairing
        self.bridge_errors = 0
        self.bridge_error: str | None = None
        self.logs: collections.deque = collections.deque(maxlen=50)  # the solver's log events
        self._pending: dict[int, dict] = {}  # request id -> {"event", "reply"}
        self._sent: dict[int, str] = {}  # request id -> run id, until the solver replies
        self._facts: dict[str, tuple] = {}  # run id -> (edge length, result.json)
        self._estimate_keys: dict[str, tuple] = {}  # run id -> the study report it used

    # ---- life cycle -------------------------------------------------------------------------
    def _new_worker(self) -> WorkerHandle:
        s = self.settings
        return WorkerHandle(s.frame_queue, s.record_every, s.step_delay, self._target)

    def start(self) -> None:
        if self.viewer:
            self.viewer.set_recordings(self.recorded())
        self.bridge.start()

    def close(self) -> None:
        """Shut down: the active run is stopped by the solver (result.json and a closed
        recording) when it answers within ``stop_timeout``; no new solver process starts."""
        with self.lock:
            run = self.runs.get(self.active) if self.active else None
        if run is not None and self.worker.alive() and self.bridge.is_alive():
            self.worker.send("stop", reason="server shut down")
            deadline = time.monotonic() + self.settings.stop_timeout
            while self.active == run.id and time.monotonic() < deadline:
                time.sleep(0.02)
        self._stop.set()
        self.bridge.join(2.0)
        self._close_retired()
        clean = self.worker.close()  # a solver still inside a step is asked, then killed
        note = self._repair(run) if run is not None and not clean else ""
        with self.lock:
            if self.active:
                self._finish(self.runs[self.active], "stopped", "server shut down" + note)
        if run is not None:
            self._result_if_missing(run)
            self._save(run)

    def _load(self) -> dict[str, Run]:
        runs = {}
        for p in sorted(self.root.glob("*/run.json")):
            try:
                run = Run(**json.loads(p.read_text()))
            except (ValueError, TypeError):
                continue
            runs[run.id] = run
            if run.state in ACTIVE:  # the server died during the run
                self._recover(run, self._repair(run))
                self._save(run)
        return runs

    def _recover(self, run: Run, note: str) -> None:
        """The status of a run the server lost track of, rebuilt from what the solver left on
        disk (``run.json`` is saved at the run's start and end only): result.json when it was
        written - the solver finishes its run when the server dies - else the steps the
        recording holds. ``note``: what the recording's repair said."""
        from server.recording import read_steps  # imports rerun: see _repair

        d = self.dir(run.id)
        state, reason = "failed", LOST
        try:
            result = json.loads((d / "result.json").read_text())
            run.records, run.counts = result["steps"], result["counts"]
            if result["converged"]:
                state, reason = "finished", None
            elif result["failure"]:
                reason = result["failure"]["reason"]
        except (OSError, ValueError, KeyError, TypeError):
            try:  # none when the server died before the solver began the recording
                run.records = read_steps(d / "run.rrd") if (d / "run.rrd").is_file() else []
            except Exception as exc:  # an unreadable recording: the run keeps no records
                note += f"; its steps could not be read: {exc}"
        run.step = run.records[-1]["step"] if run.records else 0
        run.state, run.reason = state, ((reason or "") + note).removeprefix("; ") or None
        run.pending.clear()

    def _repair(self, run: Run) -> str:
        """Make the recording of a run whose recording process was killed verifiable again.
        Returns what to add to the run's reason ("" when all went well)."""
        from server.recording import repair  # imports rerun: only the solver needs it otherwise

        # a repair (rerun rrd merge) can outlast the heartbeat: health says what the bridge does
        self.repairing = run.id
        try:
            repair(self.dir(run.id) / "run.rrd")
            return ""
        except Exception as exc:
            return f"; recording unreadable: {exc}"
        finally:
            self.repairing = None
            self.heartbeat = time.monotonic()

    def dir(self, run_id: str) -> Path:
        return self.root / check_run_id(run_id)

    def _save(self, run: Run) -> None:
        with self.lock:  # a consistent snapshot; the encoding and the write come after
            data = {**run.summary(), "records": list(run.records)}
        text = results.dumps(data, indent=1)
        with self._save_lock:
            atomic_write(self.dir(run.id) / "run.json", text)

    def health(self) -> dict:
        repairing = self.repairing
        bridge = self.bridge.is_alive() and (
            repairing is not None or time.monotonic() - self.heartbeat < HEARTBEAT_S)
        worker = self.worker.alive()
        return {"ok": bridge and worker, "worker_alive": worker, "worker_pid": self.worker.pid,
                "worker_restarts": self.restarts, "bridge_alive": bridge,
                "repairing_recording": repairing,
                "bridge_errors": self.bridge_errors, "bridge_error": self.bridge_error,
                "active": self.active}

    # ---- requests ---------------------------------------------------------------------------
    def get(self, run_id: str) -> Run:
        check_run_id(run_id)
        try:
            return self.runs[run_id]
        except KeyError:
            raise NotFound(f"no run {run_id!r}") from None

    def list(self) -> list[dict]:
        with self.lock:
            return [r.summary() for r in sorted(self.runs.values(), key=lambda r: -r.created)]

    def status(self, run_id: str, since: int = 0, limit: int | None = None) -> dict:
        """The run's summary, its step records after step ``since`` (at most ``limit``) and
        ``records_left``: how many more follow those."""
        with self.lock:
            run = self.get(run_id)
            after = [r for r in run.records if r["step"] > since]
            page = after[:limit]
            out = {**run.summary(), "records": page, "records_left": len(after) - len(page)}
        out["estimate"] = self.estimate(run)  # reads files: outside the lock
        return out

    def recorded(self) -> list[str]:
        """Runs with a recording to replay, newest first (not the active one)."""
        with self.lock:
            runs = sorted(self.runs.values(), key=lambda r: -r.created)
            return [r.id for r in runs if r.id != self.active
                    and (self.root / r.id / "run.rrd").is_file()]

    def start_run(self, scene: str, element: str | None = None, overrides: dict | None = None,
                  parameters: dict | None = None, paused: bool = False) -> Run:
        text = self.store.text(scene)
        overrides = dict(overrides or {})
        if element:
            overrides["shell.element"] = element
        spec = self.store.validate(text, overrides)  # SceneError -> 422
        from sim.elements import get_element

        try:
            get_element(spec.shell.element)
        except ValueError as exc:  # names the known elements
            raise Invalid(f"shell.element: {exc}") from None
        for name, value in (parameters or {}).items():
            self.check_parameter(name, value)
        solver_overrides = {**overrides, **self.store.solver_overrides(spec)}
        # as the solver will read it (mesh files by their full paths): refused before any build
        size.check(scene_from_toml(text, solver_overrides), self.settings.max_model_bytes,
                   "the server's --max-memory")
        with self.lock:
            if self.active:
                raise Conflict(f"run {self.active!r} is {self.runs[self.active].state}; "
                               "stop it first")
            stamp = time.strftime("%Y%m%d-%H%M%S")
            run = Run(f"{scene}-{spec.shell.element}-{stamp}-{secrets.token_hex(2)}", scene,
                      spec.shell.element, overrides, time.time(), parameters=dict(parameters or {}))
            out = self.dir(run.id)
            out.mkdir(parents=True)
            atomic_write(out / "scene.toml", text)
            atomic_write(out / "run.json", results.dumps(asdict(run), indent=1))
            self.runs[run.id], self.active = run, run.id
            self.history.reset(run.id)
            self.worker.send("start", run=run.id, out=str(out), scene_toml=text,
                             overrides=solver_overrides, parameters=parameters or {},
                             paused=paused, record_every=self.settings.record_every)
        return run

    def command(self, run_id: str, cmd: str) -> dict:
        with self.lock:
            run = self.get(run_id)
            if run.id != self.active:
                raise Conflict(f"run {run_id!r} is {run.state}, not active")
            if cmd == "stop" and run.state in ("starting", "building"):
                old = self._end_build(run)
            else:
                if cmd in ("pause", "step"):
                    run.state = "paused"  # at once, so a status read after the request agrees
                elif cmd == "resume" and run.state == "paused":
                    run.state = "running"
                self._send(run, cmd)
                return run.summary()
        self._after_build_ended(run, old)
        return run.summary()

    def _end_build(self, run: Run) -> WorkerHandle:
        """Under ``lock``: stop a run that is still building. The solver process reads commands
        only between steps, and a build is one long call (minutes for a large model), so the
        process is killed and a new one started: the stop takes effect at once, and the memory
        the build held is freed. Returns the old process's handle."""
        old = self.worker
        old.process.kill()
        self.worker = self._new_worker()
        self.restarts += 1
        self._finish(run, "stopped", "stopped during the build (its solver process was ended "
                                     "and a new one started)")
        return old

    def _after_build_ended(self, run: Run, old: WorkerHandle) -> None:
        """The files of a run whose build was stopped: result.json, its recording repaired if
        the build had finished after all and steps were recorded, run.json."""
        old.process.join(5.0)
        self._retired.append(old)
        d = self.dir(run.id)
        self._result_if_missing(run)
        if (d / "run.rrd").is_file():
            note = self._repair(run)
            if note:
                self._note(run.id, run.reason + note)
        self._save(run)
        if self.viewer:
            self.viewer.set_recordings(self.recorded())

    def _result_if_missing(self, run: Run) -> None:
        """A run whose solver ended without writing result.json (killed while building or
        stepping) gets one from what the server knows: the reason and the step records."""
        path = self.dir(run.id) / "result.json"
        if path.exists():
            return
        with self.lock:
            reason, steps = run.reason or run.state, list(run.records)
        try:
            results.write(path, results.interrupted(run.scene, run.element, reason, steps))
        except (OSError, ValueError) as exc:
            self._note(run.id, f"{reason}; writing result.json failed: {exc}")

    def _close_retired(self) -> None:
        while self._retired:
            self._retired.pop().close(timeout=0.1)

    def _send(self, run: Run, cmd: str, **kw) -> int:
        """Under ``lock``: a command for the active ``run``, listed in its ``pending`` until
        the solver replies."""
        rid = self.worker.send(cmd, **kw)
        self._sent[rid] = run.id
        run.pending.append(cmd)
        return rid

    def check_parameter(self, name: str, value) -> float:
        if not self.ready.wait(self.settings.ack_timeout):
            raise NotReady("the solver process is still starting (it names the live "
                           "parameters); retry in a moment")
        if name not in self.parameter_ranges:
            raise Invalid(f"{name}: unknown parameter; known: {sorted(self.parameter_ranges)}")
        lo, hi = self.parameter_ranges[name]
        if isinstance(value, bool) or not isinstance(value, (int, float)) \
                or not lo <= value <= hi:
            raise Invalid(f"{name}: {value!r} out of range [{lo}, {hi}]")
        return float(value)

    def set_parameter(self, run_id: str, name: str, value) -> dict:
        """Send a live parameter change and wait (``ack_timeout``) for the solver to say from
        which step it applies. A solver inside a long step answers later: then ``applied`` is
        false and the step appears in the run's ``parameter_log``."""
        value = self.check_parameter(name, value)
        waiter = {"event": threading.Event(), "reply": None}
        with self.lock:  # the bridge handles the reply under this lock: registered in time
            run = self.get(run_id)
            if run.id != self.active:
                raise Conflict(f"run {run_id!r} is {run.state}, not active")
            rid = self._send(run, "set", name=name, value=value)
            self._pending[rid] = waiter
        answered = waiter["event"].wait(self.settings.ack_timeout)
        with self.lock:
            self._pending.pop(rid, None)
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

    def delete(self, run_id: str) -> None:
        import shutil

        with self.lock:
            run = self.get(run_id)
            if run.id == self.active:
                raise Conflict(f"run {run_id!r} is {run.state}; stop it first")
            del self.runs[run.id]
            self._facts.pop(run.id, None)
            self._estimate_keys.pop(run.id, None)
            if self.history.run == run.id:
                self.history.reset(None)
        shutil.rmtree(self.dir(run_id), ignore_errors=True)
        if self.viewer:
            self.viewer.set_recordings(self.recorded())

    # ---- error estimate -----------------------------------------------------------------------
    def _run_facts(self, run: Run) -> tuple[float | None, dict | None]:
        if run.id not in self._facts:
            from sim.scene.load import scene_from_toml

            d = self.dir(run.id)
            try:
                edge = scene_from_toml((d / "scene.toml").read_text(),
                                       run.overrides).mesh.edge_length
            except (OSError, ValueError):
                edge = None
            try:
                result = json.loads((d / "result.json").read_text())
            except (OSError, ValueError):
                result = None
            self._facts[run.id] = (edge, result)
        return self._facts[run.id]

    def estimate(self, run: Run, finished: bool = False) -> dict | None:
        """A finished run's error estimate (the study row of its element and edge length) and
        cost; recomputed when a study report of its scene appears or changes. Reads files:
        never call it holding ``lock``. ``finished``: the run is finishing (its state is set
        after this)."""
        if run.state != "finished" and not finished:
            return None
        with self._estimate_lock:
            try:
                found = find_study(self.root, run.scene)
                key = (str(found[0]), found[0].stat().st_mtime_ns) if found else None
                if run.estimate is None or self._estimate_keys.get(run.id, "?") != key:
                    edge, result = self._run_facts(run)
                    run.estimate = study_estimate(self.root, run.scene, run.element, edge,
                                                  result, run.overrides)
                    self._estimate_keys[run.id] = key
            except Exception as exc:  # never let the estimate break a status request
                run.estimate = {"available": False, "reason": "error",
                                "text": f"no error estimate: {exc}", "notes": []}
            return run.estimate

    # ---- events from the solver -------------------------------------------------------------
    def _finish(self, run: Run, state: str, reason: str | None) -> None:
        """Under ``lock``: the run is over. The caller saves it (outside the lock)."""
        run.state, run.reason = state, reason
        run.pending.clear()  # what the solver did not do, it will not do for this run
        self._sent = {rid: r for rid, r in self._sent.items() if r != run.id}
        if run.id == self.active:
            self.active = None

    def _on_event(self, ev: dict) -> tuple[list, dict | None]:
        """Book one event into the run records, under the lock and nothing slow. Returns the
        viewer updates to make after the lock is released, and the frame to show, if any."""
        kind, later = ev["kind"], []
        if kind == "ready":
            if not self.ready.is_set():
                self.parameter_ranges = ev["parameters"]
                self.ready.set()
                if self.viewer:
                    later.append(lambda: self.viewer.add_parameters(self.parameter_ranges))
            return later, None
        if kind == "log":
            self.logs.append(ev["text"])
            return later, None
        if kind == "state" and ev["state"] == "finished":
            run = self.runs.get(ev.get("run") or "")
            if run is not None and run.id == self.active:
                self.estimate(run, finished=True)  # reads files: before taking the lock
        with self.lock:
            if kind == "reply":
                waiter = self._pending.get(ev.get("id"))
                if waiter is not None:
                    waiter["reply"] = ev
                    waiter["event"].set()
                sender = self.runs.get(self._sent.pop(ev.get("id"), ""))
                if sender is not None and ev["cmd"] in sender.pending:
                    sender.pending.remove(ev["cmd"])
            run = self.runs.get(ev.get("run") or "")
            if run is None or run.id != self.active:
                return later, None
            if kind == "state":
                run.frames.update(ev.get("frames") or {})
                if ev["state"] in ACTIVE:
                    run.state = ev["state"]
                else:
                    self._finish(run, ev["state"], ev.get("reason"))
                    later.append(lambda: self._save(run))
                    if self.viewer:
                        later.append(lambda: self.viewer.set_recordings(self.recorded()))
                if self.viewer:
                    status = (f"Run `{run.id}`  \n{run.state}, step {run.step}/{run.n_steps}"
                              f"  \n{run.reason or ''}")
                    later.append(lambda: self.viewer.set_status(status))
            elif kind == "meta":
                run.n_steps, run.counts, run.probes = ev["n_steps"], ev["counts"], ev["probes"]
                tools = ev.get("tools") or []
                run.tools = [t["name"] for t in tools]
                run.timing.update(ev.get("timing") or {})
                later.append(lambda: self._save(run))
                if self.viewer:
                    later.append(lambda: self.viewer.new_run(run.id, ev["faces"], tools,
                                                             run.element))
            elif kind == "step":
                run.records.append(ev["record"])
                run.step = ev["record"]["step"]
                run.frames.update(ev.get("frames") or {})
            elif kind == "parameter":
                entry = ev["entry"]
                run.parameter_log.append(entry)
                run.parameters[entry["name"]] = entry["value"]
                if self.viewer:
                    later.append(lambda: self.viewer.set_parameter_value(entry["name"],
                                                                         entry["value"]))
            elif kind == "frame":
                if "first_frame_s" not in run.timing:
                    run.timing["first_frame_s"] = time.time() - run.created
                elif ev["step"] == 1 and "first_step_s" not in run.timing:
                    run.timing["first_step_s"] = time.time() - run.created
                run.frames["received"] = run.frames.get("received", 0) + 1
                self.history.add(ev)
                return later, ev
            elif kind == "reply" and not ev["ok"] and ev.get("id") not in self._pending:
                run.reason = ev["error"]  # visible in the status; the run goes on
        return later, None

    def _fail_active(self, reason: str) -> None:
        """The server cannot follow the active run any more: fail it, and stop the solver
        (which closes the recording; its later events for this run are ignored)."""
        with self.lock:
            run = self.runs.get(self.active) if self.active else None
            if run is None:
                return
            self._finish(run, "failed", reason)
            self.worker.send("stop", reason=reason)
        self._save(run)

    def _fault(self, exc: BaseException, what: str) -> None:
        self.bridge_errors += 1
        self.bridge_error = f"{what}: {type(exc).__name__}: {exc}"
        print(f"q3t: {self.bridge_error}\n{traceback.format_exc()}", file=sys.stderr)

    def _handle(self, ev: dict) -> dict | None:
        """One event, guarded: returns the frame to show, if any."""
        try:
            later, shown = self._on_event(ev)
        except Exception as exc:
            what = f"the server could not handle the solver's {ev.get('kind')!r} event"
            self._fault(exc, what)
            try:
                self._fail_active(f"{what}: {exc}")
            except Exception as exc2:
                self._fault(exc2, "failing the run")
            return None
        for update in later:
            try:
                update()
            except Exception as exc:  # display and files only: the run goes on
                self._fault(exc, "viewer or file update")
                self._note(ev.get("run"), f"viewer: {exc}")
        return shown

    def _note(self, run_id: str | None, text: str) -> None:
        with self.lock:
            run = self.runs.get(run_id or "")
            if run is not None:
                run.reason = text

    def _worker_died(self, w: WorkerHandle) -> None:
        code = w.process.exitcode
        why = f"killed by signal {-code}" if code and code < 0 else f"exit code {code}"
        with self.lock:
            if w is not self.worker:  # already replaced (a build stopped by request)
                return
            run = self.runs.get(self.active) if self.active else None
        # the solver wrote the recording and could not close it: repair it before the run
        # reads as failed, so a download after that verifies
        note = self._repair(run) if run is not None else ""
        with self.lock:
            if self._stop.is_set() or w is not self.worker:
                return
            if run is not None and run.id == self.active:
                self._finish(run, "failed", f"solver process died ({why}){note}")
            self.worker = self._new_worker()
            self.restarts += 1
        w.close(timeout=0.1)
        if run is not None:
            self._result_if_missing(run)
            self._save(run)
            if self.viewer:
                self.viewer.set_recordings(self.recorded())

    def _drain(self, q, limit: int = 1000) -> list:
        out = []
        for _ in range(limit):
            try:
                out.append(q.get_nowait())
            except (queue.Empty, OSError, ValueError, EOFError):
                break
        return out

    def _bridge(self) -> None:
        self._newest, self._final, self._next_push = None, False, 0.0
        while not self._stop.is_set():
            self.heartbeat = time.monotonic()
            try:
                self._bridge_step()
            except Exception as exc:  # never let the bridge die; health reports the errors
                self._fault(exc, "bridge")
                time.sleep(0.05)

    def _bridge_step(self) -> None:
        self._close_retired()  # here, the one thread that reads their queues
        w = self.worker
        try:
            events = [w.events.get(timeout=0.05)] + self._drain(w.events)
        except (queue.Empty, OSError, ValueError, EOFError):
            events = []
        frames = self._drain(w.frames, 64)
        for ev in events + frames:
            shown = self._handle(ev)
            if shown is None:
                continue
            newest = self._newest
            same = newest is not None and newest["run"] == shown["run"]
            if same and shown["step"] < newest["step"]:
                continue  # an older frame from the bounded queue, after a newer one
            keep_final = self._final and same and shown["step"] == newest["step"]
            self._newest, self._final = shown, bool(shown.get("final")) or keep_final
        now = time.perf_counter()
        if self.viewer is None:
            self._newest = None  # nothing to show it on: a viewer added later starts afresh
        elif self._newest is not None and (self._final or now >= self._next_push):
            self._push(self._newest, self._final)
            # on a fixed grid of 1/push_hz, not "that long after the last push", so the rate
            # is push_hz and not less by the loop's jitter; never a burst after a pause
            period = 1.0 / self.settings.push_hz
            self._next_push = max(self._next_push + period, now)
            self._newest, self._final = None, False
        if not events and not w.alive() and not self._stop.is_set():
            self._worker_died(w)

    def _push(self, frame: dict, final: bool) -> None:
        run = self.runs.get(frame["run"])
        if run is None:
            return
        probes = ", ".join(f"{k} = {v:.4g}" for k, v in list(frame["probes"].items())[:3])
        status = (f"Run `{run.id}`  \n{run.state}, step {frame['step']}/{run.n_steps}, "
                  f"{frame['iterations']} Newton iterations  \n{probes}")
        try:
            self.viewer.show(frame, status, final=final)
        except Exception as exc:  # a viewer problem must never stop the bridge
            self._fault(exc, "viewer")
            self._note(run.id, f"viewer: {exc}")
            return
        with self.lock:
            run.frames["pushed"] = run.frames.get("pushed", 0) + 1

    # ---- viewer actions ---------------------------------------------------------------------
    def viewer_command(self, cmd: str) -> str:
        try:
            if self.active is None:
                if cmd != "resume":
                    return "No active run"
                return self.viewer_reset(None)
            return f"{cmd}: {self.command(self.active, cmd)['id']}"
        except (Conflict, NotFound) as exc:
            return str(exc)

    def viewer_reset(self, element: str | None) -> str:
        last = max(self.runs.values(), key=lambda r: r.created, default=None)
        scene = last.scene if last else self.settings.default_scene
        try:
            if self.active:
                self.command(self.active, "stop")
                deadline = time.time() + 10
                while self.active and time.time() < deadline:
                    time.sleep(0.05)
            run = self.start_run(scene, element or (last.element if last else None),
                                 last.overrides if last else None)
            return f"Started `{run.id}`"
        except (Conflict, NotFound, NotReady, SceneError, Invalid) as exc:
            return f"Cannot start: {exc}"

    def frame_at(self, run_id: str, step: int) -> dict:
        """A kept frame of the current (latest) run: the one at ``step`` or the nearest before."""
        self.get(run_id)
        frame = self.history.at(step) if self.history.run == run_id else None
        if frame is None:
            raise NotFound(f"no frames kept for run {run_id!r} (only the latest run's are)")
        return frame

    def viewer_scrub(self, step: int) -> tuple[dict | None, str]:
        """The frame to show for the time slider, or why none (a running run streams)."""
        run = self.runs.get(self.history.run or "")
        if run is None:
            return None, "No run to scrub"
        if run.state in ("starting", "building", "running"):
            return None, f"Run `{run.id}` is {run.state}: pause it to scrub"
        frame = self.history.at(step)
        if frame is None:
            return None, "No frames yet"
        return frame, (f"Run `{run.id}` ({run.state})  \nshowing step {frame['step']}/"
                       f"{run.n_steps} (kept every {self.history.stride})")

    def viewer_recording(self, run_id: str):
        """A recorded run for the viewer to replay: (``replay.Replay``, message) or (None, why
        not)."""
        from server import replay

        run = self.runs.get(run_id)
        if run is None:
            return None, f"No run `{run_id}`"
        if run.id == self.active:
            return None, f"Run `{run_id}` is {run.state}: its recording is still being written"
        try:
            rep = replay.load(self.dir(run.id) / "run.rrd")
        except Exception as exc:
            return None, f"Cannot read the recording of `{run_id}`: {exc}"
        if not rep.steps or rep.faces is None:
            return None, f"The recording of `{run_id}` holds no sheet mesh"
        return rep, (f"Recording of `{run_id}` ({run.state}): {len(rep.steps)} frames, steps "
                     f"{rep.steps[0]}-{rep.steps[-1]} (coloured by thickness, as recorded)")

    def viewer_set(self, name: str, value: float) -> str:
        if self.active is None:
            return "No active run"
        try:
            r = self.set_parameter(self.active, name, value)
            when = (f"from step {r['applies_from_step']}" if r["applied"]
                    else "from the next step")
            return f"{name} = {value:.4g} {when}"
        except (Conflict, Invalid, NotFound, NotReady) as exc:
            return str(exc)

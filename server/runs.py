"""Runs: the requests on them, the solver process that steps them and its restarts. This
module composes the parts: the run records and their folder (``server.records``), the bridge
thread booking the solver's events (``server.bridge``), the error estimates
(``server.estimate``) and the kept frames (``server.history``). Nothing here waits on a solve.

``RunManager.lock`` guards the run records and is held only for bookkeeping (a few dict and
list updates): the viewer's pushes, file writes, the error estimate and recording repairs run
outside it, so a status request never waits on them.
"""

from __future__ import annotations

import collections
import secrets
import threading
import time
from typing import TYPE_CHECKING

from server.bridge import Bridge
from server.estimate import EstimateCache
from server.events import Changes
from server.history import FrameHistory
from server.problems import Conflict, Invalid, NotFound, NotReady
from server.records import Run, RunFiles, repair_recording
from server.settings import Settings, check_run_id
from server.store import SceneStore
from server.worker import worker_main
from server.workerhandle import WorkerHandle, WorkerTarget
from sim.elements import get_element
from sim.model import size
from sim.scene.load import Scene, SceneError, scene_from_toml

if TYPE_CHECKING:  # imports viser
    from server.viewer import Viewer

# every live parameter multiplies a value of the scene: at this value the scene runs as written
AS_WRITTEN = 1.0


class RunManager:
    def __init__(self, settings: Settings, store: SceneStore,
                 worker_target: WorkerTarget = worker_main):
        self.settings, self.store = settings, store
        self.files = RunFiles(settings.runs_dir)
        self.estimates = EstimateCache(settings.runs_dir)
        self.history = FrameHistory(settings.history_frames, settings.history_bytes)
        # live parameters and their ranges come from the solver process once it has imported
        # the solver: the server never imports it, so the page is up in about a second
        self.parameter_ranges: dict = {}
        self.ready = threading.Event()
        self.lock = threading.RLock()
        self.changes = Changes()  # wakes the event streams of scripts (server.events)
        self.runs: dict[str, Run] = self.files.load()
        self.active: str | None = None
        # the run the page and the viewer show (one for every browser, until each has its own
        # view): a new run, else the newest
        self.selected: str | None = self._newest()
        # the scene the viewer previews instead (before any run): {"scene", "request" (the
        # solver's request id), "state" (building, shown, failed), "error"}; None: the run
        self.preview: dict | None = None
        self._showing = threading.Lock()
        self.waiters: dict[int, dict] = {}  # request id -> {"event", "reply"}
        self.sent: dict[int, str] = {}  # request id -> run id, until the solver replies
        self.logs: collections.deque = collections.deque(maxlen=50)  # the solver's log events
        self.viewer: Viewer | None = None  # set by the app when the viewer is on
        self._target = worker_target
        self.worker = self._new_worker()
        self._retired: list[WorkerHandle] = []  # ended by a stop during a build; the bridge closes
        self.restarts = 0
        self.closing = threading.Event()  # the server shuts down: no new solver process
        self.bridge = Bridge(self)

    # ---- life cycle -------------------------------------------------------------------------
    def _new_worker(self) -> WorkerHandle:
        s = self.settings
        return WorkerHandle(s.frame_queue, s.record_every, s.step_delay, self._target)

    def start(self) -> None:
        if self.viewer:
            self.viewer.set_runs(self.run_ids())
            self._show_selected()
        self.bridge.start()

    def close(self) -> None:
        """Shut down: the active run is stopped by the solver (result.json and a closed
        recording) when it answers within ``stop_timeout``; no new solver process starts."""
        with self.lock:
            run = self.runs.get(self.active) if self.active else None
        if run is not None and self.worker.alive() and self.bridge.running():
            self.worker.send("stop", reason="server shut down")
            deadline = time.monotonic() + self.settings.stop_timeout
            while self.active == run.id and time.monotonic() < deadline:
                time.sleep(0.02)
        self.closing.set()  # the bridge ends its loop
        self.bridge.join(2.0)
        self.close_retired()
        clean = self.worker.close()  # a solver still inside a step is asked, then killed
        note = self.repair(run) if run is not None and not clean else ""
        with self.lock:
            if self.active:
                self.finish(self.runs[self.active], "stopped", "server shut down" + note)
        if run is not None:
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
        bridge, worker = b.alive(), self.worker.alive()
        return {"ok": bridge and worker, "worker_alive": worker, "worker_pid": self.worker.pid,
                "worker_restarts": self.restarts, "bridge_alive": bridge,
                "repairing_recording": b.repairing,
                "bridge_errors": b.errors, "bridge_error": b.error,
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
            # a run saved before its status held every parameter: the others were as written
            out["parameters"] = self._start_values(out["parameters"])
        out["estimate"] = self.estimates.get(run)  # reads files: outside the lock
        return out

    def run_ids(self) -> list[str]:
        """Every run, newest first."""
        with self.lock:
            return [r.id for r in sorted(self.runs.values(), key=lambda r: -r.created)]

    def _newest(self) -> str | None:
        return max(self.runs.values(), key=lambda r: r.created).id if self.runs else None

    # ---- the selected run: what the page and the viewer show ----------------------------------
    def view(self) -> dict:
        preview = self.preview or {}
        return {"run": self.selected, "scene": preview.get("scene"),
                "preview": preview.get("state"), "preview_error": preview.get("error")}

    def select(self, run_id: str) -> dict:
        """Show ``run_id`` on the page (every browser's) and in the viewer."""
        with self.lock:
            self.selected = self.get(run_id).id
        self._show_selected()
        return self.view()

    def show_scene(self, scene: str, toml: str | None = None) -> dict:
        """Preview ``scene`` in the viewer before any run: its blank and tools at the start
        (``toml``: as the page shows it, edits not saved yet). Validated here (422 naming the
        field, 404 for an unknown scene); the solver process builds it between the steps of
        an active run, which goes on, and the viewer shows it when built. The selected run
        stays selected: selecting it again, or a new run, shows it."""
        if not self.viewer:
            raise Conflict("the viewer is off (the server runs without it): nothing to "
                           "preview on")
        text, _ = self._scene_text(scene, toml)
        _, overrides = self._checked(text, {})
        with self.lock:
            rid = self.worker.send("preview", scene=scene, scene_toml=text,
                                   overrides=overrides)
            self.preview = {"scene": scene, "request": rid, "state": "building"}
        self.viewer.preview_status(f"Preview of scene `{scene}`: building its model…")
        return self.view()

    def _show_selected(self) -> None:
        """The viewer shows the selected run, instead of any scene's preview: live while it is
        the latest, else its recording (loaded by the viewer in the background)."""
        if not self.viewer:
            return
        # in order: of two selections made at once, the viewer ends on the later one
        with self._showing:
            with self.lock:
                self.preview = None
                run = self.runs.get(self.selected or "")
                shown = None if run is None else (run.id, dict(run.parameters),
                                                    run.id == self.active, run.line())
            self.viewer.show_run(*(shown or (None, {}, False, "No run yet")))

    def show_preview(self, ev: dict) -> None:
        """The solver built the preview ``ev`` (its ``preview`` event): shown unless another
        scene or a run was chosen since (checked in the order of ``_show_selected``)."""
        with self._showing:
            with self.lock:
                p = self.preview
                if p is None or p["request"] != ev["request"]:
                    return
                p["state"], p["error"] = ("failed", ev["error"]) if "error" in ev \
                    else ("shown", None)
            if not self.viewer:
                return
            scene = ev["scene"]
            if "error" in ev:
                self.viewer.preview_status(f"Preview of scene `{scene}` failed: {ev['error']}")
                return
            self.viewer.show_preview(scene, ev["faces"], ev["tools"], ev["frame"],
                                     f"Preview of scene `{scene}`: its blank and tools at the "
                                     "start, before any run  \n(choose a run to show it)")

    def frame_at(self, run_id: str, step: int) -> dict:
        """A kept frame of the current (latest) run: the one at ``step`` or the nearest before."""
        self.get(run_id)
        frame = self.history.at(step) if self.history.run == run_id else None
        if frame is None:
            raise NotFound(f"no frames kept for run {run_id!r} (only the latest run's are)")
        return frame

    def start_run(self, scene: str, element: str | None = None, overrides: dict | None = None,
                  parameters: dict | None = None, paused: bool = False,
                  toml: str | None = None) -> Run:
        """Validate the run (scene, element, parameters, model size), then hand it to the
        solver process; refused with a reason naming the field before anything is written.
        ``toml``: the scene as the page shows it, edits not saved yet; it is validated as a
        saved scene is, and runs (kept as the run's scene.toml) instead of the saved file. The
        new run is the selected one."""
        text, edited = self._scene_text(scene, toml)
        overrides = dict(overrides or {})
        if element:
            overrides["shell.element"] = element
        spec, solver_overrides = self._checked(text, overrides)
        for name, value in (parameters or {}).items():
            self.check_parameter(name, value)
        with self.lock:
            if self.active:
                raise Conflict(f"run {self.active!r} is {self.runs[self.active].state}; "
                               "stop it first")
            stamp = time.strftime("%Y%m%d-%H%M%S")
            run = Run(f"{scene}-{spec.shell.element}-{stamp}-{secrets.token_hex(2)}", scene,
                      spec.shell.element, overrides, time.time(), edited=edited,
                      parameters=self._start_values(parameters or {}))
            out = self.files.create(run, text)
            self.runs[run.id], self.active, self.selected = run, run.id, run.id
            self.history.reset(run.id)
            self.worker.send("start", run=run.id, out=str(out), scene_toml=text,
                             overrides=solver_overrides, parameters=parameters or {},
                             paused=paused, record_every=self.settings.record_every)
        if self.viewer:
            self.viewer.set_runs(self.run_ids())
        self._show_selected()
        return run

    def _checked(self, text: str, overrides: dict) -> tuple[Scene, dict]:
        """The scene of ``text`` validated (SceneError naming the field -> 422), its element
        known, and its model within the server's memory limit, as the solver will read it (mesh
        files by their full paths): refused before any build. Returns the scene and the
        overrides the solver reads it with."""
        spec = self.store.validate(text, overrides)
        try:
            get_element(spec.shell.element)
        except ValueError as exc:  # names the known elements
            raise Invalid(f"shell.element: {exc}") from None
        solver_overrides = {**overrides, **self.store.solver_overrides(spec)}
        size.check(scene_from_toml(text, solver_overrides), self.settings.max_model_bytes,
                   "the server's --max-memory")
        return spec, solver_overrides

    def _scene_text(self, scene: str, toml: str | None) -> tuple[str, bool]:
        """The text a run of ``scene`` runs, and whether it is not the saved scene: ``toml``
        when it says something else than the saved file (compared as validated scenes, so the
        form's re-rendering of an unchanged scene is no edit), else the saved file itself (its
        comments kept)."""
        if toml is None:
            return self.store.text(scene), False
        edited = self.store.validate(toml)  # SceneError naming the field -> 422
        try:
            saved = self.store.text(scene)
            if self.store.validate(saved) == edited:
                return saved, False
        except (NotFound, SceneError):  # not saved yet, or the saved file is invalid
            pass
        return toml, True

    def _start_values(self, given: dict) -> dict:
        """Every live parameter's value at the start: as written unless ``given``. The solver's
        own values replace these once it has built the run (its ``meta``)."""
        return {**dict.fromkeys(self.parameter_ranges, AS_WRITTEN), **given}

    def command(self, run_id: str, cmd: str) -> dict:
        """pause, resume, step or stop the active run."""
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

    def check_parameter(self, name: str, value: object) -> float:
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

    def set_parameter(self, run_id: str, name: str, value: object) -> dict:
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

    def delete(self, run_id: str) -> None:
        with self.lock:
            run = self.get(run_id)
            if run.id == self.active:
                raise Conflict(f"run {run_id!r} is {run.state}; stop it first")
            del self.runs[run.id]
            if self.history.run == run.id:
                self.history.reset(None)
            moved = self.selected == run.id
            if moved:
                self.selected = self._newest()
        self.changes.touch()
        self.estimates.forget(run.id)
        self.files.delete(run.id)
        if self.viewer:
            self.viewer.set_runs(self.run_ids())
            if moved:
                self._show_selected()

    # ---- the run records: changed under ``lock`` ----------------------------------------------
    def _send(self, run: Run, cmd: str, **kw: object) -> int:
        """Under ``lock``: a command for the active ``run``, listed in its ``pending`` until
        the solver replies."""
        rid = self.worker.send(cmd, **kw)
        self.sent[rid] = run.id
        run.pending.append(cmd)
        return rid

    def finish(self, run: Run, state: str, reason: str | None) -> None:
        """Under ``lock``: the run is over. The caller saves it (outside the lock)."""
        run.state, run.reason = state, reason
        run.ended = time.time()
        run.pending.clear()  # what the solver did not do, it will not do for this run
        self.sent = {rid: r for rid, r in self.sent.items() if r != run.id}
        if run.id == self.active:
            self.active = None
        self.changes.touch()

    def run_ended(self, run: Run) -> None:
        """The viewer's line and controls for a run that is over (when it is shown)."""
        if self.viewer:
            with self.lock:
                line = run.line()
            self.viewer.run_status(run.id, line, active=False)

    def note(self, run_id: str | None, text: str) -> None:
        """Replace the run's reason (a problem that does not end it)."""
        with self.lock:
            run = self.runs.get(run_id or "")
            if run is not None:
                run.reason = text

    def fail_active(self, reason: str) -> None:
        """The server cannot follow the active run any more: fail it, and stop the solver
        (which closes the recording; its later events for this run are ignored)."""
        with self.lock:
            run = self.runs.get(self.active) if self.active else None
            if run is None:
                return
            self.finish(run, "failed", reason)
            self.worker.send("stop", reason=reason)
        self.save(run)

    def _result_if_missing(self, run: Run) -> None:
        """A run whose solver ended without writing result.json gets one from what the
        server knows: the reason and the step records."""
        with self.lock:
            reason, steps = run.reason or run.state, list(run.records)
        problem = self.files.result_if_missing(run.id, run.scene, run.element, reason, steps)
        if problem:
            self.note(run.id, f"{reason}; {problem}")

    # ---- the solver process: ended by a stop during a build, or dead --------------------------
    def _end_build(self, run: Run) -> WorkerHandle:
        """Under ``lock``: stop a run that is still building. The solver process reads commands
        only between steps, and a build is one long call (minutes for a large model), so the
        process is killed and a new one started: the stop takes effect at once, and the memory
        the build held is freed. Returns the old process's handle."""
        old = self.worker
        old.process.kill()
        self.worker = self._new_worker()
        self.restarts += 1
        self.finish(run, "stopped", "stopped during the build (its solver process was ended "
                                    "and a new one started)")
        return old

    def _after_build_ended(self, run: Run, old: WorkerHandle) -> None:
        """The files of a run whose build was stopped: result.json, its recording repaired if
        the build had finished after all and steps were recorded, run.json."""
        old.process.join(5.0)
        self._retired.append(old)
        self._result_if_missing(run)
        if self.files.recording(run.id).is_file():
            note = self.repair(run)
            if note:
                self.note(run.id, run.reason + note)
        self.save(run)
        self.run_ended(run)

    def close_retired(self) -> None:
        """Close the handles of processes ended by a stop during a build (the bridge calls
        this: it is the one thread that reads their queues)."""
        while self._retired:
            self._retired.pop().close(timeout=0.1)

    def worker_died(self, w: WorkerHandle) -> None:
        """The bridge found the solver process dead: fail its run (after repairing the
        recording, so a download after that verifies) and start a new process."""
        code = w.process.exitcode
        why = f"killed by signal {-code}" if code and code < 0 else f"exit code {code}"
        with self.lock:
            if w is not self.worker:  # already replaced (a build stopped by request)
                return
            run = self.runs.get(self.active) if self.active else None
        note = self.repair(run) if run is not None else ""
        with self.lock:
            if self.closing.is_set() or w is not self.worker:
                return
            if run is not None and run.id == self.active:
                self.finish(run, "failed", f"solver process died ({why}){note}")
            self.worker = self._new_worker()
            self.restarts += 1
        w.close(timeout=0.1)
        if run is not None:
            self._result_if_missing(run)
            self.save(run)
            self.run_ended(run)


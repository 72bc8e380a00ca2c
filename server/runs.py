"""Runs: their state, the solver process that steps them, and the bridge thread that carries
its events to the run records, the recording and the viewer. Nothing here waits on a solve."""

from __future__ import annotations

import json
import queue
import secrets
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from server.estimate import estimate as study_estimate
from server.estimate import find_study
from server.history import FrameHistory
from server.recording import Recorder
from server.settings import Settings, check_name
from server.store import SceneStore, atomic_write
from server.workerhandle import WorkerHandle
from sim.scene import SceneError

ACTIVE = {"starting", "building", "running", "paused"}


class Conflict(RuntimeError):
    """The request does not fit the run's state (409)."""


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
    records: list[dict] = field(default_factory=list)
    # finished runs: error estimate from a study of the scene, and the run's cost
    estimate: dict | None = None

    def summary(self) -> dict:
        d = asdict(self)
        del d["records"]
        return d


class RunManager:
    def __init__(self, settings: Settings, store: SceneStore):
        self.settings, self.store = settings, store
        self.root = settings.runs_dir
        self.root.mkdir(parents=True, exist_ok=True)
        # live parameters and their ranges come from the solver process once it has imported
        # the solver: the server never imports it, so the page is up in about a second
        self.parameter_ranges: dict = {}
        self.ready = threading.Event()
        self.lock = threading.RLock()
        self.runs: dict[str, Run] = self._load()
        self.active: str | None = None
        self.recorder: Recorder | None = None
        self.faces = None
        self.viewer = None
        self.history = FrameHistory(settings.history_frames, settings.history_bytes)
        self.worker = self._new_worker()
        self.restarts = 0
        self._stop = threading.Event()
        self.bridge = threading.Thread(target=self._bridge, name="q3t-bridge", daemon=True)
        self._facts: dict[str, tuple] = {}  # run id -> (edge length, result.json)
        self._estimate_keys: dict[str, tuple] = {}  # run id -> the study report it used

    # ---- life cycle -------------------------------------------------------------------------
    def _new_worker(self) -> WorkerHandle:
        s = self.settings
        return WorkerHandle(s.frame_queue, s.record_mesh_every, s.step_delay)

    def start(self) -> None:
        self.bridge.start()

    def close(self) -> None:
        self._stop.set()
        self.bridge.join(2.0)
        with self.lock:
            if self.active:
                self._finish(self.runs[self.active], "stopped", "server shut down")
        self.worker.close()

    def _load(self) -> dict[str, Run]:
        runs = {}
        for p in sorted(self.root.glob("*/run.json")):
            try:
                run = Run(**json.loads(p.read_text()))
            except (ValueError, TypeError):
                continue
            if run.state in ACTIVE:
                run.state, run.reason = "failed", "the server stopped during the run"
            runs[run.id] = run
        return runs

    def dir(self, run_id: str) -> Path:
        return self.root / check_name(run_id, "run id")

    def _save(self, run: Run) -> None:
        atomic_write(self.dir(run.id) / "run.json", json.dumps(asdict(run), indent=1))

    # ---- requests ---------------------------------------------------------------------------
    def get(self, run_id: str) -> Run:
        check_name(run_id, "run id")
        try:
            return self.runs[run_id]
        except KeyError:
            raise KeyError(f"no run {run_id!r}") from None

    def list(self) -> list[dict]:
        with self.lock:
            return [r.summary() for r in sorted(self.runs.values(), key=lambda r: -r.created)]

    def start_run(self, scene: str, element: str | None = None, overrides: dict | None = None,
                  parameters: dict | None = None, paused: bool = False) -> Run:
        text = self.store.text(scene)  # KeyError -> 404
        overrides = dict(overrides or {})
        if element:
            overrides["shell.element"] = element
        spec = self.store.validate(text, overrides)  # SceneError -> 422
        from sim.elements import get_element

        get_element(spec.shell.element)  # ValueError names the known elements
        for name, value in (parameters or {}).items():
            self.check_parameter(name, value)
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
            self._save(run)
            self.runs[run.id], self.active = run, run.id
            self.history.reset(run.id)
            self.recorder = Recorder(out / "run.rrd", run.id)
            self.worker.send("start", run=run.id, out=str(out), scene_toml=text,
                             overrides=overrides, parameters=parameters or {}, paused=paused)
        return run

    def command(self, run_id: str, cmd: str) -> Run:
        with self.lock:
            run = self.get(run_id)
            if run.id != self.active:
                raise Conflict(f"run {run_id!r} is {run.state}, not active")
            if cmd == "pause":
                run.state = "paused"  # at once, so a status read after the request agrees
            elif cmd == "resume" and run.state == "paused":
                run.state = "running"
            self.worker.send(cmd)
            return run

    def check_parameter(self, name: str, value) -> float:
        self.ready.wait(120)
        if name not in self.parameter_ranges:
            raise ValueError(f"{name}: unknown parameter; known: {sorted(self.parameter_ranges)}")
        lo, hi = self.parameter_ranges[name]
        if not isinstance(value, (int, float)) or not lo <= value <= hi:
            raise ValueError(f"{name}: {value!r} out of range [{lo}, {hi}]")
        return float(value)

    def set_parameter(self, run_id: str, name: str, value) -> dict:
        value = self.check_parameter(name, value)
        with self.lock:
            run = self.get(run_id)
            if run.id != self.active:
                raise Conflict(f"run {run_id!r} is {run.state}, not active")
            self.worker.send("set", name=name, value=value)
            return {"run": run.id, "name": name, "value": value,
                    "applies_from_step": run.step + 1}

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

    # ---- error estimate -----------------------------------------------------------------------
    def _run_facts(self, run: Run) -> tuple[float | None, dict | None]:
        if run.id not in self._facts:
            from sim.scene import scene_from_toml

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

    def estimate(self, run: Run) -> dict | None:
        """A finished run's error estimate (the study row of its element and edge length) and
        cost; recomputed when a study report of its scene appears or changes."""
        if run.state != "finished":
            return None
        try:
            found = find_study(self.root, run.scene)
            key = (str(found[0]), found[0].stat().st_mtime_ns) if found else None
            if run.estimate is None or self._estimate_keys.get(run.id, "?") != key:
                edge, result = self._run_facts(run)
                run.estimate = study_estimate(self.root, run.scene, run.element, edge, result,
                                              run.overrides)
                self._estimate_keys[run.id] = key
        except Exception as exc:  # never let the estimate break a status request
            run.estimate = {"available": False, "reason": "error",
                            "text": f"no error estimate: {exc}", "notes": []}
        return run.estimate

    # ---- events from the solver -------------------------------------------------------------
    def _finish(self, run: Run, state: str, reason: str | None) -> None:
        run.state, run.reason = state, reason
        if state == "finished":
            self.estimate(run)
        self._save(run)
        if run.id == self.active:
            self.active = None
            if self.recorder:
                self.recorder.close()
                self.recorder = None

    def _on_event(self, ev: dict) -> dict | None:
        """Update the run from one event; returns a frame to show, if any."""
        if ev["kind"] == "ready" and not self.ready.is_set():
            self.parameter_ranges = ev["parameters"]
            self.ready.set()
            if self.viewer:
                self.viewer.add_parameters(self.parameter_ranges)
        with self.lock:
            run = self.runs.get(ev.get("run") or "")
            if run is None or run.id != self.active:
                return None
            kind = ev["kind"]
            if kind == "state":
                if ev["state"] in ACTIVE:
                    run.state = ev["state"]
                else:
                    self._finish(run, ev["state"], ev.get("reason"))
                if self.viewer:
                    self.viewer.set_status(f"Run `{run.id}`  \n{run.state}, step {run.step}/"
                                           f"{run.n_steps}  \n{run.reason or ''}")
            elif kind == "meta":
                run.n_steps, run.counts, run.probes = ev["n_steps"], ev["counts"], ev["probes"]
                tools = ev.get("tools") or []
                run.tools = [t["name"] for t in tools]
                run.timing.update(ev.get("timing") or {})
                self.faces = ev["faces"]
                if self.recorder:
                    self.recorder.meta(ev["faces"], tools)
                if self.viewer:
                    self.viewer.new_run(run.id, ev["faces"], tools, run.element)
                self._save(run)
            elif kind == "step":
                run.records.append(ev["record"])
                run.step = ev["record"]["step"]
                if self.recorder:
                    self.recorder.step(ev["record"])
            elif kind == "parameter":
                run.parameter_log.append(ev["entry"])
                run.parameters[ev["entry"]["name"]] = ev["entry"]["value"]
                if self.recorder:
                    self.recorder.parameter(ev["entry"])
                if self.viewer:
                    self.viewer.set_parameter_value(ev["entry"]["name"], ev["entry"]["value"])
            elif kind == "frame":
                if "first_frame_s" not in run.timing:
                    run.timing["first_frame_s"] = time.time() - run.created
                elif ev["step"] == 1 and "first_step_s" not in run.timing:
                    run.timing["first_step_s"] = time.time() - run.created
                self.history.add(ev)
                if self.recorder:
                    self.recorder.frame(ev)
                return ev
            elif kind == "reply" and not ev["ok"]:
                run.reason = ev["error"]  # visible in the status; the run goes on
        return None

    def _worker_died(self) -> None:
        code = self.worker.process.exitcode
        why = f"killed by signal {-code}" if code and code < 0 else f"exit code {code}"
        with self.lock:
            if self.active:
                self._finish(self.runs[self.active], "failed", f"solver process died ({why})")
            old, self.worker = self.worker, self._new_worker()
            self.restarts += 1
        old.close(timeout=0.1)

    def _drain(self, q, limit: int = 1000) -> list:
        out = []
        for _ in range(limit):
            try:
                out.append(q.get_nowait())
            except (queue.Empty, OSError, ValueError, EOFError):
                break
        return out

    def _bridge(self) -> None:
        last_push, newest, final = 0.0, None, False
        while not self._stop.is_set():
            w = self.worker
            try:
                events = [w.events.get(timeout=0.05)] + self._drain(w.events)
            except (queue.Empty, OSError, ValueError, EOFError):
                events = []
            for ev in events:
                shown = self._on_event(ev)
                if shown is not None:
                    newest = shown
                    run = self.runs.get(shown["run"])
                    final = bool(run and run.n_steps == shown["step"])
            frames = self._drain(w.frames, 64)
            for f in frames:
                self.history.add(f)  # ignores frames of other runs
            if frames and (newest is None or frames[-1]["step"] > newest["step"]):
                newest, final = frames[-1], False
            now = time.perf_counter()
            if newest is not None and self.viewer and (
                    final or now - last_push >= 1.0 / self.settings.push_hz):
                self._push(newest, final)
                newest, last_push = None, now
            if not events and not w.alive():
                self._worker_died()

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
            run.reason = f"viewer: {exc}"

    # ---- viewer actions ---------------------------------------------------------------------
    def viewer_command(self, cmd: str) -> str:
        try:
            if self.active is None:
                if cmd != "resume":
                    return "No active run"
                return self.viewer_reset(None)
            return f"{cmd}: {self.command(self.active, cmd).id}"
        except (Conflict, KeyError) as exc:
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
        except (Conflict, KeyError, SceneError, ValueError) as exc:
            return f"Cannot start: {exc}"

    def frame_at(self, run_id: str, step: int) -> dict:
        """A kept frame of the current (latest) run: the one at ``step`` or the nearest before."""
        self.get(run_id)
        frame = self.history.at(step) if self.history.run == run_id else None
        if frame is None:
            raise KeyError(f"no frames kept for run {run_id!r} (only the latest run's are)")
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

    def viewer_set(self, name: str, value: float) -> str:
        if self.active is None:
            return "No active run"
        try:
            self.set_parameter(self.active, name, value)
            return f"{name} = {value:.4g} from the next step"
        except (Conflict, ValueError) as exc:
            return str(exc)

"""The solver process: owns one Simulation and steps the active run.

Commands come down ``commands`` as dicts with a request id; replies, states and step records go
up ``events`` (small, never dropped); frames go up the bounded ``frames`` queue with
``put_nowait`` and are dropped when the server is behind. Every ``keyframe_every`` steps (and at
the first and last step) the frame travels on ``events`` instead, so recordings never miss it.

The run's first messages are ``meta`` (sheet faces and the tool meshes, each sent once per run)
and the rest-state frame, both before the first step; later frames carry only positions, fields
and the tools' translations.
"""

from __future__ import annotations

import multiprocessing as mp
import queue
import time
import traceback
from dataclasses import asdict
from pathlib import Path

import numpy as np


def _frame_msg(run: str, sim) -> dict:
    f = sim.frame()
    return {"kind": "frame", "run": run, "step": f.step, "time": f.time,
            "positions": f.positions, "fields": {k: v.astype("float32") for k, v in
                                                 f.fields.items()},
            "tools": {k: np.asarray(v, np.float32) for k, v in sim.tool_poses().items()},
            "tool_rotations": {k: np.asarray(v, np.float32)  # (w, x, y, z)
                               for k, v in sim.tool_rotations().items()},
            "probes": f.probes, "iterations": f.iterations, "residual": f.residual}


def plane_size(positions: np.ndarray) -> float:
    """Side of the square that shows an unbounded tool (a plane): twice the sheet's extent."""
    extent = positions.max(0) - positions.min(0) if len(positions) else np.ones(3)
    return float(2.0 * max(float(np.max(extent)), 1e-3))


def tool_meshes(scene, size: float, cache: dict) -> list[dict]:
    """Display meshes of the scene's tools in their local frames (world = local + translation):
    ``[{name, kind, vertices (m, 3) float32, faces (k, 3) uint32}]``. Cached per shape."""
    from sim.model import tool_program
    from sim.tools.meshes import tool_mesh

    out = []
    for spec in scene.tools:
        key = (spec.shape.model_dump_json(), round(size, 9))
        if key not in cache:
            V, F = tool_mesh(tool_program(spec.shape), plane_size=size)
            cache[key] = (np.asarray(V, np.float32), np.asarray(F, np.uint32))
        V, F = cache[key]
        out.append({"name": spec.name, "kind": spec.shape.kind, "vertices": V, "faces": F})
    return out


class _Solver:
    def __init__(self, events: mp.Queue, frames: mp.Queue, keyframe_every: int,
                 step_delay: float):
        self.events, self.frames = events, frames
        self.keyframe_every, self.step_delay = max(1, keyframe_every), step_delay
        self.sim = None
        self.run: str | None = None
        self.out: Path | None = None
        self.paused = False
        self.pending_steps = 0
        self.mesh_cache: dict = {}  # tool meshes by shape: a repeated run skips the meshing

    def emit(self, kind: str, **kw) -> None:
        self.events.put({"kind": kind, "run": self.run, **kw})

    @property
    def stepping(self) -> bool:
        return self.sim is not None and (not self.paused or self.pending_steps > 0)

    def handle(self, msg: dict) -> None:
        cmd = msg["cmd"]
        try:
            getattr(self, f"cmd_{cmd}")(msg)
            self.events.put({"kind": "reply", "id": msg.get("id"), "ok": True, "run": self.run})
        except Exception as exc:  # a reply names the problem; the worker stays alive
            self.events.put({"kind": "reply", "id": msg.get("id"), "ok": False,
                             "error": str(exc), "run": self.run})

    def cmd_start(self, msg: dict) -> None:
        from sim.scene import scene_from_toml
        from sim.simulation import Simulation

        if self.sim is not None:
            self.finish("stopped", "replaced by a new run")
        self.run, self.out = msg["run"], Path(msg["out"])
        self.paused, self.pending_steps = bool(msg.get("paused")), 0
        self.emit("state", state="building")
        t0 = time.perf_counter()
        try:
            scene = scene_from_toml(msg["scene_toml"], msg.get("overrides") or {})
            self.sim = Simulation.from_scene(scene)
            for name, value in (msg.get("parameters") or {}).items():
                self.sim.set_parameter(name, value)
            t1 = time.perf_counter()
            rest = _frame_msg(self.run, self.sim)
        except Exception as exc:
            self.sim = None
            self.emit("state", state="failed", reason=f"build failed: {exc}")
            raise
        t2 = time.perf_counter()
        try:  # display only: a tool that cannot be meshed must not stop the run
            tools = tool_meshes(scene, plane_size(rest["positions"]), self.mesh_cache)
        except Exception:
            tools = []
            self.emit("log", text=f"tool meshes failed:\n{traceback.format_exc()}")
        t3 = time.perf_counter()
        self.emit("meta", faces=self.sim.display.faces, n_steps=self.sim.n_steps,
                  counts=self.sim.result()["counts"], element=scene.shell.element,
                  probes=[p.name for p in scene.probes], tools=tools,
                  timing={"build_s": t1 - t0, "rest_frame_s": t2 - t1,
                          "tool_meshes_s": t3 - t2})
        self.events.put(rest)  # the rest state, before the first step (which may take seconds)
        self.emit("state", state="paused" if self.paused else "running")

    def _need_run(self) -> None:
        if self.sim is None:
            raise RuntimeError("no active run")

    def cmd_pause(self, msg: dict) -> None:
        self._need_run()
        self.paused, self.pending_steps = True, 0
        self.emit("state", state="paused")

    def cmd_resume(self, msg: dict) -> None:
        self._need_run()
        self.paused = False
        self.emit("state", state="running")

    def cmd_step(self, msg: dict) -> None:
        self._need_run()
        self.paused = True
        self.pending_steps += 1

    def cmd_stop(self, msg: dict) -> None:
        self._need_run()
        self.finish("stopped", "stopped by request")

    def cmd_set(self, msg: dict) -> None:
        self._need_run()
        self.sim.set_parameter(msg["name"], msg["value"])
        self.emit("parameter", entry=self.sim.parameter_log[-1])

    def cmd_ping(self, msg: dict) -> None:
        pass

    def step(self) -> None:
        from sim.simulation import SolverFailure

        if self.pending_steps:
            self.pending_steps -= 1
        try:
            rec = self.sim.step()
        except SolverFailure as exc:
            self.finish("failed", str(exc))
            return
        self.emit("step", record=asdict(rec))
        msg = _frame_msg(self.run, self.sim)
        if rec.step % self.keyframe_every == 0 or self.sim.done:
            self.events.put(msg)
        else:
            try:
                self.frames.put_nowait(msg)
            except queue.Full:
                pass  # the viewer shows a newer frame soon; recordings use keyframes
        if self.sim.done:
            self.finish("finished")
        elif self.step_delay:
            time.sleep(self.step_delay)

    def finish(self, state: str, reason: str | None = None) -> None:
        try:
            self.sim.write(self.out)
        except Exception as exc:  # the state still goes up; the reason says what broke
            reason = f"{reason or state}; writing results failed: {exc}"
        self.emit("state", state=state, reason=reason)
        self.sim, self.paused, self.pending_steps = None, False, 0


def worker_main(commands: mp.Queue, events: mp.Queue, frames: mp.Queue, keyframe_every: int = 1,
                step_delay: float = 0.0) -> None:
    """Entry point of the spawned process. Exits on a ``shutdown`` command."""
    solver = _Solver(events, frames, keyframe_every, step_delay)
    parameters = {}
    try:  # import and compile here, so the server answers while this takes seconds
        from sim.simulation import Simulation

        parameters = dict(Simulation.PARAMETERS)
    except Exception:
        events.put({"kind": "log", "run": None, "text": traceback.format_exc()})
    events.put({"kind": "ready", "run": None, "parameters": parameters})
    while True:
        try:
            msg = commands.get_nowait() if solver.stepping else commands.get(timeout=0.2)
        except queue.Empty:
            msg = None
        if msg is not None:
            if msg["cmd"] == "shutdown":
                break
            solver.handle(msg)
            continue
        if solver.stepping:
            solver.step()
    events.close()
    frames.close()

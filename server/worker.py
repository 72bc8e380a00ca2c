"""The solver process: owns one Simulation, steps the active run and writes its recording.

Commands come down ``commands`` as dicts with a request id. Up ``events`` go the small messages,
never dropped: replies, states, step records, parameter changes, the run's ``meta`` (sheet faces
and tool meshes, once per run) and the few frames that must arrive - the rest state, the frame
of a paused run, the last frame of a run (``final``). Every other frame goes up the bounded
``frames`` queue with ``put_nowait``, and is dropped when the queue is full: a viewer slower than
the solver never makes frames pile up. The recording (``run.rrd``) is written here, from every
step, so it does not depend on what reaches the server: the sheet mesh every ``record_every``
steps and at the first and last step, scalars every step.

SIGINT is ignored (Ctrl-C in a terminal reaches the whole process group; the server decides what
happens to the run). If the server process dies, the run is finished as failed, its recording
closed (a complete, verifiable file) and the process exits.
"""

from __future__ import annotations

import hashlib
import itertools
import multiprocessing as mp
import queue
import signal
import time
import traceback
from dataclasses import asdict
from multiprocessing.queues import Queue
from multiprocessing.reduction import ForkingPickler
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import numpy as np

from sim.frames.punch import plotted

if TYPE_CHECKING:  # the solver is imported in the solver process only, when it starts
    from sim.scene.load import Scene
    from sim.stepping.simulation import Simulation

_ids = itertools.count(1)


def request_id() -> int:
    """A command's id, unique among every solver's (the replies' waiters are keyed by it), in
    the server process: local solver processes and Dask actors take the same ids."""
    return next(_ids)

# a multiprocessing queue; a queue.Queue when a test drives the solver in its own process
Channel = Queue | queue.Queue


def _frame_msg(run: str | None, sim: Simulation) -> dict:
    """The frame message of the current state. A frame holding a number that is not finite
    is an error: it must reach neither the recording nor the server (which colours by it)."""
    f = sim.frame()
    bad = [k for k, v in {"positions": f.positions, **f.fields}.items()
           if not np.isfinite(v).all()]
    if bad:
        raise ValueError(f"the frame of step {f.step} is not finite in {', '.join(bad)}")
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


def shape_files(shape: object) -> list[str]:
    """The paths of the files a shape reads (a mesh tool's, in CSG operands too)."""
    from sim.tools.shapes import CSG, FILE_KINDS

    if shape.kind in CSG:
        return [p for s in shape.shapes for p in shape_files(s)]
    return [str(shape.path)] if shape.kind in FILE_KINDS else []


def content_key(shape: object) -> tuple:
    """A shape by what it is: its fields and the content (SHA-256) of each file it reads, so a
    file replaced under the same name is a new shape, as in the mesh tools' own cache."""
    digests = []
    for path in shape_files(shape):
        try:
            digests.append(hashlib.sha256(Path(path).read_bytes()).hexdigest())
        except OSError:
            digests.append(None)  # the program's own read names the problem
    return shape.model_dump_json(), tuple(digests)


def tool_meshes(scene: Scene, size: float, cache: dict) -> list[dict]:
    """Display meshes of the scene's tools in their local frames (world = local + translation):
    ``[{name, kind, vertices (m, 3) float32, faces (k, 3) uint32}]``. Cached per shape, by
    content (:func:`content_key`)."""
    from sim.tools.shapes import tool_program
    from sim.tools.surface import tool_mesh

    out = []
    for spec in scene.tools:
        key = (content_key(spec.shape), round(size, 9))
        if key not in cache:
            V, F = tool_mesh(tool_program(spec.shape), plane_size=size)
            cache[key] = (np.asarray(V, np.float32), np.asarray(F, np.uint32))
        V, F = cache[key]
        out.append({"name": spec.name, "kind": spec.shape.kind, "vertices": V, "faces": F})
    return out


def preview(scene_toml: str, overrides: dict, cache: dict) -> dict:
    """The rest state of a scene's model: ``faces`` of its display surface, ``tools`` (as
    :func:`tool_meshes`) and ``frame``, the frame message of step 0 (tools at their start)."""
    from sim.scene.load import scene_from_toml
    from sim.stepping.simulation import Simulation

    scene = scene_from_toml(scene_toml, overrides)
    sim = Simulation.from_scene(scene)
    frame = _frame_msg(None, sim)
    return {"faces": sim.display.faces, "frame": frame,
            "tools": tool_meshes(scene, plane_size(frame["positions"]), cache)}


def thinning_limit(scene: Scene) -> float | None:
    """The material card's excessive-thinning limit (``flc.max_thinning``) in %, or None: the
    viewer's thinning bands start from it, as the summary's card flags from it."""
    flc = scene.material.flc
    return None if flc is None or flc.max_thinning is None else 100.0 * flc.max_thinning


class RecordingFailed(RuntimeError):
    pass


class Solver:
    """The run being stepped in this process: its simulation, recording and command
    handlers (``cmd_<name>``)."""

    def __init__(self, events: Channel, frames: Channel, record_every: int,
                 step_delay: float):
        self.events, self.frames = events, frames
        self.record_every, self.step_delay = max(1, record_every), step_delay
        self.sim: Simulation | None = None
        self.run: str | None = None
        self.out: Path | None = None
        self.recorder = None
        self.last_mesh = -1  # step of the last sheet mesh written to the recording
        self.paused = False
        # --step-delay: no step before this (time.monotonic()); commands are answered meanwhile,
        # so a Stop or a parameter change does not wait out the pause
        self.next_step_at = 0.0
        self.produced = self.dropped = 0  # frames of this run made / dropped (queue full)
        self.mesh_cache: dict = {}  # tool meshes by shape: a repeated run skips the meshing
        self.note: str | None = None  # a problem of the run's that does not end it

    def emit(self, kind: str, **kw: object) -> None:
        self.events.put({"kind": kind, "run": self.run, **kw})

    @property
    def stepping(self) -> bool:
        return self.sim is not None and not self.paused

    def handle(self, msg: dict) -> None:
        cmd = msg["cmd"]
        try:
            result = getattr(self, f"cmd_{cmd}")(msg)
            self.events.put({"kind": "reply", "id": msg.get("id"), "cmd": cmd, "ok": True,
                             "run": self.run, "result": result})
        except Exception as exc:  # a reply names the problem; the worker stays alive
            self.events.put({"kind": "reply", "id": msg.get("id"), "cmd": cmd, "ok": False,
                             "error": str(exc), "run": self.run})

    # ---- the recording: any error in it fails the run, naming it ------------------------------
    def record(self, method: str, *args: object, **kw: object) -> None:
        if self.recorder is None:
            return
        try:
            getattr(self.recorder, method)(*args, **kw)
        except Exception as exc:
            self.recorder = None  # a broken stream is not written to again
            raise RecordingFailed(f"recording {self.out / 'run.rrd'} failed: {exc}") from exc

    def record_frame(self, msg: dict, final: bool = False) -> None:
        step = msg["step"]
        mesh = step != self.last_mesh and (step % self.record_every == 0 or final)
        self.record("frame", msg, mesh=mesh)
        if mesh:
            self.last_mesh = step

    # ---- commands -----------------------------------------------------------------------------
    def cmd_start(self, msg: dict) -> None:
        """Build the run's model, open its recording, send its meta and rest frame. A build
        that fails ends the run as failed (with its result.json) and the reply says why."""
        if self.sim is not None:
            self.finish("stopped", "replaced by a new run")
        self.run, self.out = msg["run"], Path(msg["out"])
        self.paused = bool(msg.get("paused"))
        self.next_step_at = 0.0  # the last run's pause is not this one's
        self.produced = self.dropped = 0
        self.last_mesh = -1
        self.record_every = max(1, int(msg.get("record_every") or self.record_every))
        self.emit("state", state="building")
        scene, rest, timing = self._build(msg)
        t0 = time.perf_counter()
        self._open_recording(scene)  # after the build: a run stopped while building leaves none
        tools, self.note = self._tool_meshes(scene, rest)
        timing["tool_meshes_s"] = time.perf_counter() - t0
        try:
            self._send_meta(scene, tools, timing)
        except Exception as exc:  # without its meta the server shows nothing of the run
            self.emit("log", text=traceback.format_exc())
            self.finish("failed", f"sending the run's model to the server failed: "
                                  f"{type(exc).__name__}: {exc}")
            return
        self.events.put(rest)  # the rest state, before the first step (which may take seconds)
        try:
            self.record("meta", self.sim.display.faces, tools)
            for entry in self.sim.parameter_log:
                self.record("parameter", entry)
            self.record_frame(rest)
        except RecordingFailed as exc:
            self.finish("failed", str(exc))
            return
        self.emit("state", state="paused" if self.paused else "running")

    def _build(self, msg: dict) -> tuple[Scene, dict, dict]:
        """The run's simulation, with its live parameters set: its scene, its rest frame and
        the build's timing."""
        from sim.scene.load import scene_from_toml
        from sim.stepping.simulation import Simulation

        t0 = time.perf_counter()
        scene = None
        try:
            scene = scene_from_toml(msg["scene_toml"], msg.get("overrides") or {})
            self.sim = Simulation.from_scene(scene)
            for name, value in (msg.get("parameters") or {}).items():
                self.sim.set_parameter(name, value)
            self.sim.save_frames(self.out / "frames", self.record_every)  # for its exports
            t1 = time.perf_counter()
            rest = _frame_msg(self.run, self.sim)
        except Exception as exc:
            self.sim = None
            # a ValueError is the scene's (its message names the field); anything else a bug
            what = "" if isinstance(exc, ValueError) else f"{type(exc).__name__}: "
            self._unbuilt(scene, f"build failed: {what}{exc}")
            raise
        return scene, rest, {"build_s": t1 - t0, "rest_frame_s": time.perf_counter() - t1}

    def _open_recording(self, scene: Scene) -> None:
        from server.recording import Recorder

        try:
            self.recorder = None
            self.recorder = Recorder(self.out / "run.rrd", self.run)
        except Exception as exc:
            self.sim = None
            self._unbuilt(scene, f"recording failed: {exc}")
            raise

    def _send_meta(self, scene: Scene, tools: list[dict], timing: dict) -> None:
        """The run's ``meta`` event, pickled here first: a multiprocessing queue pickles in a
        thread of its own, which prints an error and drops a message it cannot pickle, and the
        run would go on with a blank viewer and no word on the page."""
        msg = {"kind": "meta", "run": self.run, "faces": self.sim.display.faces,
               "n_steps": self.sim.n_steps, "counts": self.sim.result()["counts"],
               "element": scene.shell.element, "probes": [p.name for p in scene.probes],
               "tools": tools, "timing": timing, "parameters": dict(self.sim.parameters),
               "scaled": self.sim.scaled(), "note": self.note,
               "thinning_limit": thinning_limit(scene),
               **plotted(scene, self.sim.tool_poses())}
        ForkingPickler.dumps(msg)
        self.events.put(msg)

    def _tool_meshes(self, scene: Scene, rest: dict) -> tuple[list[dict], str | None]:
        """Display only: a tool that cannot be meshed must not stop the run, but the page says
        why the viewer shows no tools (the note)."""
        try:
            return tool_meshes(scene, plane_size(rest["positions"]), self.mesh_cache), None
        except Exception as exc:
            self.emit("log", text=f"tool meshes failed:\n{traceback.format_exc()}")
            return [], ("the viewer shows no tools: meshing them failed "
                        f"({type(exc).__name__}: {exc})")

    def _unbuilt(self, scene: Scene | None, reason: str) -> None:
        """A run that ends before it has a model: its result.json says why, then its state."""
        from sim.frames import results

        try:
            results.write(self.out / "result.json", results.interrupted(
                scene.name if scene else None, scene.shell.element if scene else None, reason))
        except Exception as exc:
            reason += f"; writing results failed: {exc}"
        self.emit("state", state="failed", reason=reason)

    def _need_run(self) -> None:
        if self.sim is None:
            raise RuntimeError("no active run")

    def _pause(self) -> None:
        if not self.paused:
            self.paused = True
            self.emit("state", state="paused")
            # the viewer must show where the run stopped, even if that frame was dropped
            self.events.put({**_frame_msg(self.run, self.sim), "final": True})

    def cmd_pause(self, msg: dict) -> None:
        self._need_run()
        self._pause()

    def cmd_resume(self, msg: dict) -> None:
        self._need_run()
        self.paused = False
        self.emit("state", state="running")

    def cmd_step(self, msg: dict) -> None:
        """One step, then paused (a running run pauses after the step under way). The step is
        made here, so the reply says it is done."""
        self._need_run()
        if not self.paused:
            self.paused = True
            self.emit("state", state="paused")
        self.step(single=True)

    def cmd_stop(self, msg: dict) -> None:
        self._need_run()
        self.finish("stopped", msg.get("reason") or "stopped by request")

    def cmd_set(self, msg: dict) -> dict:
        self._need_run()
        self.sim.set_parameter(msg["name"], msg["value"])
        entry = self.sim.parameter_log[-1]
        self.emit("parameter", entry=entry, n_steps=self.sim.n_steps)  # tool_speed sets it
        try:
            self.record("parameter", entry)
        except RecordingFailed as exc:
            self.finish("failed", str(exc))
        return entry

    def cmd_ping(self, msg: dict) -> None:
        pass

    def cmd_preview(self, msg: dict) -> None:
        """A scene's rest state for the viewer, before any run: its model built apart from
        the active run's (which goes on), its rest frame and its tools at their start. The
        answer is a ``preview`` event (the sheet's faces, the tool meshes, the frame, or the
        error naming why it could not be built); the reply itself is always ok, so a scene that
        fails to build never marks the active run."""
        out = {"kind": "preview", "run": None, "request": msg["id"], "scene": msg["scene"]}
        try:
            out |= preview(msg["scene_toml"], msg.get("overrides") or {}, self.mesh_cache)
        except Exception as exc:
            what = "" if isinstance(exc, ValueError) else f"{type(exc).__name__}: "
            out["error"] = f"{what}{exc}"
        self.events.put(out)

    # ---- stepping -----------------------------------------------------------------------------
    def step(self, single: bool = False) -> None:
        """One step of the active run (``single``: of a paused run, whose frame must arrive).
        Whatever goes wrong fails the run with the reason (and its result.json); the process
        goes on to the next run."""
        try:
            self._step(single)
        except Exception as exc:
            self.emit("log", text=traceback.format_exc())
            self.finish("failed", f"{type(exc).__name__}: {exc}")

    def _step(self, single: bool) -> None:
        from sim.stepping.simulation import SolverFailure

        t0 = time.perf_counter()
        try:
            rec = self.sim.step()
        except SolverFailure as exc:  # its cut-backs' time is the run's too, as result.json's
            self.finish("failed", str(exc), failed_s=time.perf_counter() - t0)
            return
        wall = time.perf_counter() - t0
        msg = _frame_msg(self.run, self.sim)
        self.produced += 1
        # the pause that follows this step: none after the last, nor after a single Step
        delay = 0.0 if single or self.sim.done else self.step_delay
        self.emit("step", record=asdict(rec), wall_s=wall, delay_s=delay,
                  n_steps=self.sim.n_steps,
                  frames={"produced": self.produced, "dropped": self.dropped})
        try:
            self.record("step", asdict(rec))
            self.record_frame(msg, final=self.sim.done)
        except RecordingFailed as exc:
            self.finish("failed", str(exc), msg)
            return
        if self.sim.done:
            self.finish("finished", None, msg)
            return
        if single:
            self.events.put({**msg, "final": True})
        else:
            try:
                self.frames.put_nowait(msg)
            except queue.Full:
                self.dropped += 1  # the viewer shows a newer frame soon
        self.next_step_at = time.monotonic() + delay

    def _record_summary(self, entries: list[dict]) -> None:
        from sim.frames.summary import table

        self.record("summary", self.sim.step_index, self.sim.t, table(entries))

    def _close_recording(self) -> str | None:
        try:
            if self.recorder is not None:
                self.recorder.close()
        except Exception as exc:
            return f"closing the recording failed: {exc}"
        finally:
            self.recorder = None
        return None

    def finish(self, state: str, reason: str | None = None, last: dict | None = None,
               failed_s: float = 0.0) -> None:
        """End the run: its last frame (to the viewer and the recording), result.json, the
        closed recording, then the state (its reason the run's note when it has none);
        ``failed_s``: the wall time of a step that failed (the steps made sent theirs)."""
        reason, self.note = reason or self.note, None
        problems = []
        try:
            last = last or _frame_msg(self.run, self.sim)
            self.events.put({**last, "final": True})
            if self.recorder is not None and last["step"] != self.last_mesh:
                self.record_frame(last, final=True)  # unless step() recorded it already
        except Exception as exc:
            problems.append(str(exc))
        if state != "finished":  # result.json says why, as the status does
            self.sim.end(reason or state, stopped=state == "stopped")
        try:
            result = self.sim.write(self.out)
            self._record_summary(result["summary"])
        except RecordingFailed as exc:
            problems.append(str(exc))
        except Exception as exc:  # the state still goes up; the reason says what broke
            problems.append(f"writing results failed: {exc}")
        problems.append(self._close_recording())
        problems = [p for p in problems if p]
        if problems:
            state = "failed" if state == "finished" else state
            reason = "; ".join([reason or state, *problems])
        self.emit("state", state=state, reason=reason, wall_s=failed_s,
                  frames={"produced": self.produced, "dropped": self.dropped},
                  field_ranges=dict(self.sim.field_ranges))
        self.sim, self.paused = None, False


def worker_main(commands: Channel, events: Channel, frames: Channel, record_every: int = 10,
                step_delay: float = 0.0) -> None:
    """Entry point of the spawned process. Exits on a ``shutdown`` command, or when the server
    process is gone."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if serve(commands, events, frames, record_every, step_delay, mp.parent_process()):
        # orphaned: nobody reads the queues any more, do not wait to flush them
        events.cancel_join_thread()
        frames.cancel_join_thread()
    events.close()
    frames.close()


class Owner(Protocol):
    """Whoever reads the solver's events: the server process (``mp.parent_process()``), or
    the server's hold on a Dask actor (``server.solveractor``)."""

    def is_alive(self) -> bool: ...


def serve(commands: Channel, events: Channel, frames: Channel, record_every: int,
          step_delay: float, owner: Owner | None) -> bool:
    """The solver's life: say it is ready (with the live parameters), then answer commands
    and step until a ``shutdown`` (returns False) or the ``owner``'s end (returns True)."""
    solver = Solver(events, frames, record_every, step_delay)
    events.put({"kind": "ready", "run": None, "parameters": _parameters(events)})
    return _serve(solver, commands, owner)


def _parameters(events: Channel) -> dict:
    """The live parameters and their ranges. Imports and compiles the solver: here, in this
    process, so the server answers while this takes seconds."""
    try:
        from sim.stepping.simulation import Simulation

        return dict(Simulation.PARAMETERS)
    except Exception:
        events.put({"kind": "log", "run": None, "text": traceback.format_exc()})
        return {}


def _serve(solver: Solver, commands: Channel, owner: Owner | None) -> bool:
    """Answer commands and step the active run between them, until a ``shutdown`` (returns
    False) or the owner's end (returns True)."""
    while True:
        if owner is not None and not owner.is_alive():
            if solver.sim is not None:
                solver.finish("failed", "the server process died")
            return True
        wait = solver.next_step_at - time.monotonic() if solver.stepping else 0.2
        try:
            msg = commands.get(timeout=min(wait, 0.2)) if wait > 0 else commands.get_nowait()
        except queue.Empty:
            msg = None
        if msg is None:
            if solver.stepping and time.monotonic() >= solver.next_step_at:
                solver.step()
        elif msg["cmd"] == "shutdown":
            if solver.sim is not None:
                solver.finish("stopped", "server shut down")
            return False
        else:
            solver.handle(msg)

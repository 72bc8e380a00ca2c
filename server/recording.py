"""A run's rerun recording, written by the solver process: the sheet's triangles once
(static), its positions coloured by thickness, with the values of every frame field, every
``record_every`` steps (and at the first and last step), the tool meshes once (static,
``tools/<name>``) with their pose (``rr.Transform3D``: translation, and rotation for a tool
whose keyframes turn it) every step, and time series of every probe, energy, Newton
iterations, residual, max thinning (and max plastic strain where there is a plastic state)
and live parameters, and at the end the run's summary (sim.frames.summary) as a markdown
table, ``summary``. ``channels`` lists them from what the model built, so a recording has no
channel for a quantity the scene lacks.

Every step is flushed. A recording stream writes its footer only when it is closed, and
``rerun rrd verify`` refuses a file without one; so when the process that records is killed,
``repair`` rewrites the file (``rerun rrd merge``, which keeps every chunk that was flushed) -
the server does that when its solver process dies, and at start-up for the runs it finds
interrupted. When the server dies first, the solver process notices and closes the recording.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import rerun as rr

from server.colormap import MIN_SPAN, colorize, tool_colour, value_range
from server.replay import FIELD_PREFIX

SOLVER = ("energy", "iterations", "residual", "cutbacks")
# per-frame maxima of the frame fields that have one: a scalar series beside the coloured mesh
FIELD_MAXIMA = {"thinning_pct": "solver/max_thinning_pct",
                "eq_plastic_strain_pct": "solver/max_eq_plastic_strain_pct"}


def channels(outputs: dict) -> list[str]:
    """Entity paths of a run whose model built ``outputs`` (``Model.built["outputs"]``); a live
    parameter adds ``parameters/<name>`` once it is changed."""
    return ["sheet", *(f"tools/{t}" for t in outputs["tools"]),
            *(f"probes/{p}" for p in outputs["probes"]), *(f"solver/{n}" for n in SOLVER),
            *(FIELD_MAXIMA[f] for f in outputs["frame_fields"] if f in FIELD_MAXIMA),
            "summary"]


class Recorder:
    def __init__(self, path: Path, run_id: str):
        self.path = path
        self.rec = rr.RecordingStream("q3t-forming", recording_id=run_id)
        self.rec.save(str(path))
        self.faces: np.ndarray | None = None

    def _time(self, step: int, t: float) -> None:
        self.rec.set_time("step", sequence=int(step))
        self.rec.set_time("sim_time", duration=float(t))

    def meta(self, faces: np.ndarray, tools: list[dict] = ()) -> None:
        self.faces = np.asarray(faces, np.uint32)
        # the triangles never change: once, static, instead of with every mesh (at 80k vertices
        # they are 60 % of a frame's bytes); positions and colours are partial updates of it
        self.rec.log("sheet", rr.Mesh3D.from_fields(triangle_indices=self.faces), static=True)
        for i, t in enumerate(tools):
            rgb, alpha = tool_colour(i)
            self.rec.log(f"tools/{t['name']}", rr.Mesh3D(
                vertex_positions=t["vertices"], triangle_indices=t["faces"],
                albedo_factor=[*rgb, int(255 * alpha)]), static=True)
        self.rec.flush()

    def step(self, record: dict) -> None:
        self._time(record["step"], record["time"])
        for name, value in record["probes"].items():
            self.rec.log(f"probes/{name}", rr.Scalars(float(value)))
        for name in SOLVER:
            self.rec.log(f"solver/{name}", rr.Scalars(float(record[name])))
        self.rec.flush()

    def parameter(self, entry: dict) -> None:
        self.rec.set_time("step", sequence=int(entry["step"]))
        self.rec.log(f"parameters/{entry['name']}", rr.Scalars(float(entry["value"])))
        self.rec.flush()

    def frame(self, frame: dict, mesh: bool = True) -> None:
        """Max thinning and the tools' translations always; the sheet mesh when ``mesh``."""
        self._time(frame["step"], frame["time"])
        for name, path in FIELD_MAXIMA.items():
            if name in frame["fields"]:
                self.rec.log(path, rr.Scalars(float(np.max(frame["fields"][name]))))
        if mesh and self.faces is not None:
            h = frame["fields"]["thickness_mm"]
            colors = colorize(h, *value_range(h, MIN_SPAN["thickness_mm"]))
            # the field values beside the mesh (``field:<name>``): a replay colours them on the
            # viewer's scales; the colours are for rerun's own viewer
            values = {f"{FIELD_PREFIX}{k}": np.asarray(v, np.float32)
                      for k, v in frame["fields"].items()}
            self.rec.log("sheet", rr.Mesh3D.from_fields(vertex_positions=frame["positions"],
                                                        vertex_colors=colors),
                         rr.AnyValues(**values))
        rotations = frame.get("tool_rotations") or {}
        for name, pose in (frame.get("tools") or {}).items():
            q = rotations.get(name)  # (w, x, y, z); rerun takes (x, y, z, w)
            rot = rr.Quaternion(xyzw=np.roll(np.asarray(q, np.float32), -1)) if q is not None \
                else None
            self.rec.log(f"tools/{name}", rr.Transform3D(
                translation=np.asarray(pose, np.float32), quaternion=rot))
        self.rec.flush()

    def summary(self, step: int, t: float, table: str) -> None:
        """The run's summary (sim.frames.summary.table) at its last step."""
        self._time(step, t)
        self.rec.log("summary", rr.TextDocument(table, media_type=rr.MediaType.MARKDOWN))
        self.rec.flush()

    def close(self) -> None:
        self.rec.flush()
        self.rec.disconnect()  # writes the footer


def read_steps(path: Path) -> list[dict]:
    """The step records the recording holds (what ``step`` wrote: time, probes and the
    solver's numbers), for a run whose result.json was never written. A step whose solver
    numbers are not all there (the writer was killed within it) is left out."""
    from rerun.chunk import RrdReader

    steps: dict[int, dict] = {}
    for chunk in RrdReader(str(path)).stream():
        kind, _, name = str(chunk.entity_path).lstrip("/").partition("/")
        if kind != "probes" and not (kind == "solver" and name in SOLVER):
            continue
        rb = chunk.to_record_batch()
        for k, t, v in zip(rb.column("step").to_pylist(), rb.column("sim_time").to_pylist(),
                           rb.column("Scalars:scalars").to_pylist(), strict=True):
            rec = steps.setdefault(k, {"step": k, "time": t.total_seconds(), "probes": {}})
            (rec["probes"] if kind == "probes" else rec)[name] = v[0]
    out = [r for _, r in sorted(steps.items()) if all(n in r for n in SOLVER)]
    for r in out:
        r["iterations"], r["cutbacks"] = int(r["iterations"]), int(r["cutbacks"])
    return out


def rerun_cli() -> str:
    exe = Path(sys.executable).with_name("rerun")
    return str(exe) if exe.exists() else (shutil.which("rerun") or "rerun")


def repair(path: Path, timeout: float = 120.0) -> str:
    """Rewrite the recording of a run whose recording process was killed (no footer), keeping
    every chunk it flushed. Returns what was done ("repaired", "empty", "missing"); raises
    RuntimeError when rerun cannot read it. The original is replaced only by a complete file."""
    if not path.is_file():
        return "missing"
    tmp = path.with_name(f".{path.name}.repair.tmp")
    tmp.unlink(missing_ok=True)
    if path.stat().st_size == 0:  # killed before its first write: an empty, valid recording
        rec = rr.RecordingStream("q3t-forming", recording_id=path.parent.name)
        rec.save(str(tmp))
        rec.disconnect()
        os.replace(tmp, path)
        return "empty"
    env = {**os.environ, "RUST_LOG": "warn"}
    try:
        r = subprocess.run([rerun_cli(), "rrd", "merge", "--continue-on-error", str(path), "-o",
                            str(tmp)], capture_output=True, text=True, timeout=timeout, env=env)
        if r.returncode != 0 or not tmp.is_file():
            raise RuntimeError(f"rerun rrd merge failed: {r.stderr.strip()[-300:]}")
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return "repaired"

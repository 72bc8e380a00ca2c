"""A run's rerun recording: the sheet mesh coloured by thickness every keyframe, the tool meshes
once (static, ``tools/<name>``) with their translation (``rr.Transform3D``) every keyframe, and
time series of every probe, energy, Newton iterations, residual, max thinning and live
parameters.

Each logged step is flushed, so a killed run still leaves a readable ``run.rrd``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr

from server.colormap import MIN_SPAN, colorize, tool_colour, value_range


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
        for name in ("energy", "iterations", "residual", "cutbacks"):
            self.rec.log(f"solver/{name}", rr.Scalars(float(record[name])))
        self.rec.flush()

    def parameter(self, entry: dict) -> None:
        self.rec.set_time("step", sequence=int(entry["step"]))
        self.rec.log(f"parameters/{entry['name']}", rr.Scalars(float(entry["value"])))
        self.rec.flush()

    def frame(self, frame: dict) -> None:
        self._time(frame["step"], frame["time"])
        thinning = frame["fields"].get("thinning_pct")
        if thinning is not None:
            self.rec.log("solver/max_thinning_pct", rr.Scalars(float(np.max(thinning))))
        if self.faces is not None:
            h = frame["fields"]["thickness_mm"]
            colors = colorize(h, *value_range(h, MIN_SPAN["thickness_mm"]))
            self.rec.log("sheet", rr.Mesh3D(vertex_positions=frame["positions"],
                                            triangle_indices=self.faces, vertex_colors=colors))
        rotations = frame.get("tool_rotations") or {}
        for name, pose in (frame.get("tools") or {}).items():
            q = rotations.get(name)  # (w, x, y, z); rerun takes (x, y, z, w)
            rot = rr.Quaternion(xyzw=np.roll(np.asarray(q, np.float32), -1)) if q is not None \
                else None
            self.rec.log(f"tools/{name}", rr.Transform3D(
                translation=np.asarray(pose, np.float32), quaternion=rot))
        self.rec.flush()

    def close(self) -> None:
        self.rec.flush()
        self.rec.disconnect()

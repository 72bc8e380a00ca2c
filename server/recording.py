"""A run's rerun recording: the sheet mesh coloured by thickness every keyframe, the tool meshes
once (static, ``tools/<name>``) with their translation (``rr.Transform3D``) every keyframe, and
time series of every probe, energy, Newton iterations, residual, max thinning (and max plastic
strain where there is a plastic state) and live parameters. ``channels`` lists them from what
the model built, so a recording has no channel for a quantity the scene lacks.

Each logged step is flushed, so a killed run still leaves a readable ``run.rrd``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr

from server.colormap import MIN_SPAN, colorize, tool_colour, value_range

SOLVER = ("energy", "iterations", "residual", "cutbacks")
# per-frame maxima of the frame fields that have one: a scalar series beside the coloured mesh
FIELD_MAXIMA = {"thinning_pct": "solver/max_thinning_pct",
                "eq_plastic_strain": "solver/max_eq_plastic_strain"}


def channels(outputs: dict) -> list[str]:
    """Entity paths of a run whose model built ``outputs`` (``Model.built["outputs"]``); a live
    parameter adds ``parameters/<name>`` once it is changed."""
    return ["sheet", *(f"tools/{t}" for t in outputs["tools"]),
            *(f"probes/{p}" for p in outputs["probes"]), *(f"solver/{n}" for n in SOLVER),
            *(FIELD_MAXIMA[f] for f in outputs["frame_fields"] if f in FIELD_MAXIMA)]


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
        for name in SOLVER:
            self.rec.log(f"solver/{name}", rr.Scalars(float(record[name])))
        self.rec.flush()

    def parameter(self, entry: dict) -> None:
        self.rec.set_time("step", sequence=int(entry["step"]))
        self.rec.log(f"parameters/{entry['name']}", rr.Scalars(float(entry["value"])))
        self.rec.flush()

    def frame(self, frame: dict) -> None:
        self._time(frame["step"], frame["time"])
        for name, path in FIELD_MAXIMA.items():
            if name in frame["fields"]:
                self.rec.log(path, rr.Scalars(float(np.max(frame["fields"][name]))))
        if self.faces is not None:
            h = frame["fields"]["thickness_mm"]
            colors = colorize(h, *value_range(h, MIN_SPAN["thickness_mm"]))
            self.rec.log("sheet", rr.Mesh3D(vertex_positions=frame["positions"],
                                            triangle_indices=self.faces, vertex_colors=colors))
        for name, pose in (frame.get("tools") or {}).items():
            self.rec.log(f"tools/{name}", rr.Transform3D(translation=np.asarray(pose, np.float32)))
        self.rec.flush()

    def close(self) -> None:
        self.rec.flush()
        self.rec.disconnect()

"""Reading a run's recording (run.rrd) back: a probe's series, the steps that hold the sheet."""

from __future__ import annotations

from pathlib import Path

from rerun.chunk import RrdReader


def series(path: Path, entity: str) -> dict[int, float]:
    out = {}
    for chunk in RrdReader(str(path)).stream():
        if str(chunk.entity_path) == entity:
            rb = chunk.to_record_batch()
            for step, v in zip(rb.column("step").to_pylist(),
                               rb.column("Scalars:scalars").to_pylist(), strict=True):
                out[step] = v[0]
    return out


def sheet_steps(path: Path) -> list[int]:
    """The steps at which the recording holds sheet positions."""
    steps = []
    for chunk in RrdReader(str(path)).stream():
        rb = chunk.to_record_batch()
        if str(chunk.entity_path) == "/sheet" and "Mesh3D:vertex_positions" in rb.schema.names:
            pos = rb.column("Mesh3D:vertex_positions")
            steps += [s for i, s in enumerate(rb.column("step").to_pylist())
                      if s is not None and pos[i].is_valid]
    return sorted(steps)

"""The frames a run saves as it goes, for its time series (``q3t export --format vtu``): in
the run's folder, ``frames/mesh.npz`` once (what never changes) and ``frames/step-NNNNNN.npz``
every ``every`` steps (step 0 included) and at the run's last state, each written to a
temporary name first, so a killed run leaves only whole files.

A frame is small: the skins' corner positions and the result fields (sim.frames.fields
``output_fields``), float32 - a picture of the run, not a restart file (final.npz keeps the
last state in full)."""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import numpy as np

from sim.frames import fields

if TYPE_CHECKING:
    from sim.model.build import Model

FOLDER = "frames"
MESH = "mesh.npz"
FRAME = re.compile(r"step-(\d{6,})\.npz")


class Run(Protocol):
    """What a frame reads of a run (sim.stepping.simulation.Simulation)."""

    model: Model
    x: np.ndarray
    h0: np.ndarray
    t: float
    step_index: int


def skins(model: Model) -> np.ndarray:
    """The top and the bottom skin node of every mid-surface vertex, ``(2, n_v)``."""
    sh = model.shell
    return np.stack([sh.skin_nodes(True), sh.skin_nodes(False)])


def save_npz(path: Path, **arrays: np.ndarray) -> None:
    """``np.savez_compressed`` to a hidden temporary name, then renamed: never half-written."""
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **arrays)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


class FrameSeries:
    """Saves a run's frames into ``folder``: its current state at once, then every ``every``
    steps, and its last state when ``observe(last=True)``."""

    def __init__(self, folder: Path, every: int, run: Run):
        if every < 1:
            raise ValueError(f"frames every {every} steps: must be at least 1")
        self.folder, self.every = folder, every
        self.saved: int | None = None  # the last step saved
        self.skins = skins(run.model)
        folder.mkdir(parents=True, exist_ok=True)
        m = run.model
        # rest in float32 as the frames' positions: a frame at rest has no displacement
        save_npz(folder / MESH, faces=m.shell.mesh.faces, skins=self.skins,
                 rest=m.shell.rest[self.skins].astype(np.float32), rest_thickness=run.h0)
        self.observe(run)

    def observe(self, run: Run, last: bool = False) -> None:
        """Save the run's state if its step is due (or ``last``) and not saved yet."""
        k = run.step_index
        if k == self.saved or not (last or k % self.every == 0):
            return
        out = fields.output_fields(run.model, run.x, run.h0)
        save_npz(self.folder / f"step-{k:06d}.npz", step=np.int64(k), time=np.float64(run.t),
                 positions=run.x[self.skins].astype(np.float32),
                 **{name: v.astype(np.float32) for name, v in out.items()})
        self.saved = k


def steps(folder: Path) -> list[tuple[int, Path]]:
    """The frames saved in ``folder`` (a run's ``frames/``), by step."""
    if not folder.is_dir():
        return []
    found = ((FRAME.fullmatch(p.name), p) for p in folder.iterdir())
    return sorted((int(m[1]), p) for m, p in found if m)

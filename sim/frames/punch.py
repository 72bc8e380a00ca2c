"""A punch's force against its stroke, from the step reports of its tool: the run summary's
peak force and the page's force-stroke plot read it from here. Light on purpose: the server
reads it of a live run's records without importing the solver."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from sim.scene.load import Scene


def punch_history(rows: list[tuple[int, dict]], start: np.ndarray) -> dict:
    """A punch's history from its step reports ``rows`` [(step, {fx, fy, fz, x, y, z})] and
    its start translation: ``steps``, ``force`` resisting its motion (N), ``stroke`` (m) and
    ``lateral`` (N, (k, 3)), the force's part perpendicular to the stroke (side thrust), at
    each, and ``direction``, the unit direction of its largest excursion from the start. A
    punch that never moves: the force's size, no stroke, lateral force or direction. Shapes:
    (k,) but ``lateral``."""
    steps = np.array([s for s, _ in rows], int)
    F = np.array([[r["fx"], r["fy"], r["fz"]] for _, r in rows], float).reshape(-1, 3)
    T = np.array([[r["x"], r["y"], r["z"]] for _, r in rows], float).reshape(-1, 3) - start
    reach = np.linalg.norm(T, axis=1)
    if not len(rows) or reach.max() == 0.0:
        return {"steps": steps, "force": np.linalg.norm(F, axis=1), "stroke": None,
                "lateral": None, "direction": None}
    d = T[int(np.argmax(reach))] / reach.max()
    return {"steps": steps, "force": -F @ d, "stroke": T @ d,
            "lateral": F - np.outer(F @ d, d), "direction": d}


def plotted(scene: Scene, starts: dict[str, np.ndarray]) -> dict:
    """What a run's plots need that its step records do not say: each punch's start
    translation ``starts[name]`` (its stroke is read from there) and each probe's kind (which
    says its unit). The service's run.json and a sweep's case folders keep it."""
    from sim.scene.shapes import tool_role

    punches = {t.name: [float(c) for c in starts[t.name]] for t in scene.tools
               if tool_role(t) == "punch" and t.name in starts}
    return {"punches": punches, "probe_kinds": {p.name: p.kind for p in scene.probes}}

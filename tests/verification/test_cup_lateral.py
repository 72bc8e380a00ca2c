"""The cup's lateral punch force (issue 17, docs/elements-ans.md "The cup's lateral force"):
an axisymmetric draw pushes the punch straight down, so whatever pushes it sideways is an
asymmetric state, the mesh's or a wave's."""

import numpy as np
import pytest

from sim.scene.load import load_scene
from sim.stepping.simulation import Simulation

pytestmark = pytest.mark.fast


def test_outline_blank_pushes_the_punch_sideways_by_under_2_percent():
    """The outline cup as shipped (2 mm, q3t_ans, 0.5 mm of stroke per step), its first 5 mm:
    the sheet wrapping the punch's nose radius, where the lateral force of the stroke's first
    half arises (the full stroke's table in docs/elements-ans.md). Issue 17's bound is 2 % of
    the peak punch force; here of the largest force of these steps, which is under half the
    full stroke's peak, so the bound is stricter than the issue's. Measured: 1.1 % (81 N at
    3 mm of stroke, against 7.6 kN at 5 mm)."""
    sim = Simulation.from_scene(load_scene("scenes/cup_drawing_outline.toml", {
        "stepping.steps": 10, "tools.0.velocity": [0.0, 0.0, -0.005]}))
    assert sim.run(), sim.failure
    p = {k: np.array([r.probes[k] for r in sim.records]) for k in sim.records[0].probes}
    assert p["holder_height"].min() > 0.0004  # on the flange, not on its blocks
    lateral = np.hypot(p["punch_force_x"], p["punch_force_y"])
    assert lateral.max() < 0.02 * p["punch_force"].max()

"""The cup's lateral punch force (issue 17, docs/elements-ans.md "The cup's lateral force"):
an axisymmetric draw pushes the punch straight down, so whatever pushes it sideways is an
asymmetric state, the mesh's or a wave's. Read from the run summary (sim.frames.summary), the
numbers `q3t run cup_drawing_outline` prints, checked against the punch's force probes."""

import numpy as np
import pytest

from sim.scene.load import load_scene
from sim.stepping.simulation import Simulation
from tests.support.scenes import probe_series

pytestmark = pytest.mark.slow

SCENE = "scenes/cup_drawing_outline.toml"
STEPS = 24  # of the shipped 50: past the peak punch force (step 22), the holder still holding


def test_outline_blank_pushes_the_punch_sideways_by_under_2_percent_to_the_peak():
    """The outline cup as shipped (2 mm, q3t_ans), its steps up to just past the peak punch
    force, while the blank holder still holds the flange: issue 17's bound, the lateral force
    under 2 % of the peak punch force, holds there on this blank and not on the structured
    disk, whose aligned rings push the punch along +x (elements-ans.md gives both runs). The
    later steps, after the holder rests on its blocks, do not meet it at 2 mm on any blank
    (elements-ans.md): they are left out, not loosened (the whole stroke is a long run; the
    summary's split at the holder's stop is tested on the coarse cup, tests/scenes/
    test_summary.py). Read from the run summary, checked against the punch's force probes."""
    shipped = load_scene(SCENE)
    stroke_per_step = np.asarray(shipped.tools[0].velocity) / shipped.stepping.steps
    sim = Simulation.from_scene(load_scene(SCENE, {
        "stepping.steps": STEPS, "tools.0.velocity": (stroke_per_step * STEPS).tolist()}))
    assert sim.run(), sim.failure
    s = {e["name"]: e for e in sim.result()["summary"]}
    p = probe_series(sim)
    peak = p["punch_force"].max()
    assert p["punch_force"].argmax() < STEPS - 1  # the peak is inside the window
    assert s["peak_punch_force"]["value"] == pytest.approx(peak, rel=1e-12)
    # on the flange, not on its distance blocks (rest 0.5 mm above, blocks 0.1 mm below that)
    assert p["holder_height"].min() > 0.0004
    lateral = np.hypot(p["punch_force_x"], p["punch_force_y"])  # the punch moves along -z
    assert s["peak_lateral_punch_force"]["value"] == pytest.approx(lateral.max(), rel=1e-12)
    assert lateral.max() < 0.02 * peak
    at = s["lateral_punch_force_share"]["at"]
    assert at["steps_over_2_percent"] == 0
    assert "peak_lateral_punch_force_holding" not in s  # no split: the holder held throughout

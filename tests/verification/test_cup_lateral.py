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
PEAK_BEFORE = 24  # the peak punch force comes at step 22 of the shipped 50, the holder holding


def test_outline_blank_pushes_the_punch_sideways_by_under_2_percent_while_the_holder_holds():
    """The outline cup as shipped (2 mm, q3t_ans, 50 steps): while the blank holder holds the
    flange, past the peak punch force, issue 17's bound, the lateral force under 2 % of the
    peak punch force, holds on this blank and not on the structured disk, whose aligned rings
    push the punch along +x (elements-ans.md gives both runs). After the holder rests on its
    blocks the rim is ironed unevenly through the gap and it is not met at 2 mm on any blank
    (elements-ans.md): the summary splits the stroke there, and the bound is asserted on the
    first part only, not loosened for the second."""
    sim = Simulation.from_scene(load_scene(SCENE))
    assert sim.run(), sim.failure
    s = {e["name"]: e for e in sim.result()["summary"]}
    p = probe_series(sim)
    steps = np.array([r.step for r in sim.records])
    peak = p["punch_force"].max()
    assert s["peak_punch_force"]["value"] == pytest.approx(peak, rel=1e-12)
    assert s["peak_punch_force"]["at"]["step"] < PEAK_BEFORE
    # the holder on its distance blocks: rest 0.5 mm above the die, blocks 0.1 mm below that
    on_stop = p["holder_height"] <= 0.0004 + 1e-9
    rests = steps[on_stop.argmax()]
    assert on_stop.any() and PEAK_BEFORE < rests and on_stop[steps >= rests].all()
    lateral = np.hypot(p["punch_force_x"], p["punch_force_y"])  # the punch moves along -z
    holding = s["peak_lateral_punch_force_holding"]
    assert holding["value"] == pytest.approx(lateral[steps < rests].max(), rel=1e-12)
    assert holding["value"] < 0.02 * peak
    after = s["peak_lateral_punch_force_holder_on_stop"]
    assert after["value"] == pytest.approx(lateral[steps >= rests].max(), rel=1e-12)
    assert after["at"]["step"] >= rests > holding["at"]["step"]
    over = lateral > 0.02 * peak
    at = s["lateral_punch_force_share"]["at"]
    assert at["steps_over_2_percent"] == over.sum() and at["first_step_over"] == steps[over][0]

"""The step's predicted start (Simulation._attempt): the last increment continued, within what
the scene allows."""

import numpy as np

import sim.stepping.simulation as simulation
from sim.stepping.simulation import Simulation
from tests.support import ROOT
from tests.support.scenes import coarse


def test_a_blank_holder_on_its_stop_is_not_predicted_past_it(monkeypatch):
    """In the 2 mm cup the rim leaves the blank holder at step 32: the holder drops 0.3 mm onto
    its stop. Continued past the stop, its spring (100x the contact stiffness of all its
    nodes) started step 33 at 2e6 times the force level, and Newton took 21 iterations there
    (10 with the holder kept on the stop)."""
    sim = Simulation.from_scene(coarse(ROOT / "scenes" / "cup_drawing.toml"))
    holder = next(t for t in sim.tools if t.vdof is not None)
    assert holder.stop is not None
    sim.x[holder.vdof, 2] = holder.stop  # landed in the last increment, from 0.3 mm above
    sim._last_increment = np.zeros_like(sim.x)
    sim._last_increment[holder.vdof, 2] = -3e-4
    starts = []

    def record(problem, x0, *args, **kw):
        starts.append(x0.copy())
        raise RuntimeError("predicted start recorded")

    monkeypatch.setattr(simulation, "minimise", record)
    try:
        sim._attempt(sim.t + 1.0 / sim.model.scene.stepping.steps, 1.0)
    except RuntimeError:
        pass
    assert starts and starts[0][holder.vdof, 2] == holder.stop

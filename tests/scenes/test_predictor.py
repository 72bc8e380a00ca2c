"""The step's predicted start (Simulation._attempt): the last increment continued, within what
the scene allows."""

import numpy as np
import pytest

import sim.stepping.simulation as simulation
from sim.stepping.simulation import Simulation
from tests.support import ROOT
from tests.support.scenes import coarse


def _start(sim, monkeypatch, dt, t_new=None):
    """The predicted start of the next attempt of ``dt`` to ``t_new`` (default ``t + dt``;
    Newton not run)."""
    starts = []

    def record(problem, x0, *args, **kw):
        starts.append(x0.copy())
        raise RuntimeError("predicted start recorded")

    monkeypatch.setattr(simulation, "minimise", record)
    try:
        sim._attempt(sim.t + dt if t_new is None else t_new, dt)
    except RuntimeError:
        pass
    assert starts, "Newton was not reached"
    return starts[0]


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
    t_new = sim.t + 1.0 / sim.model.scene.stepping.steps
    assert _start(sim, monkeypatch, 1.0, t_new)[holder.vdof, 2] == holder.stop


def test_a_blank_holder_predicted_above_the_sheet_starts_where_its_contact_carries_it(
        monkeypatch):
    """A blank holder whose continued motion leaves it above the predicted sheet is put where
    its contact carries its force: with k_floor alone in its Hessian, Newton's first
    correction had sent it far into the sheet (the 2 mm cup's second step: 10 -> 8
    iterations, square_cup's 17 -> 14). In contact, the predicted height stands; with nothing
    under it down to its stop, it starts on the stop."""
    from sim.terms.contact_kernels import penalty_contact

    sim = Simulation.from_scene(coarse(ROOT / "scenes" / "cup_drawing.toml"))
    holder = next(t for t in sim.tools if t.vdof is not None)
    dt = 1.0 / sim.model.scene.stepping.steps
    sim._last_increment, sim._last_dt = np.zeros_like(sim.x), dt
    sim._last_increment[holder.vdof, 2] = 2e-4  # risen a fifth of the thickness
    x0 = _start(sim, monkeypatch, dt)
    u = x0[holder.vdof, 2]
    assert u < sim.x[holder.vdof, 2] + 2e-4
    gp = penalty_contact(x0[holder.nodes], holder.prog, holder.R_now, holder.translation(x0),
                         holder.k, holder.delta, c2=True)[1]
    # bisected to the doubles' spacing at the height (1e-20 m): the residual left is that
    # times the contact stiffness, far below 1e-9 of the force
    assert abs(gp[:, 2].sum() - holder.force) <= 1e-9 * holder.force
    sim._last_increment[holder.vdof, 2] = -2e-5  # sinking into the flange: stands
    assert _start(sim, monkeypatch, dt)[holder.vdof, 2] == sim.x[holder.vdof, 2] - 2e-5
    sim.x[: sim.model.shell.n_nodes, 2] -= 0.01  # the sheet has left the holder
    sim._last_increment[holder.vdof, 2] = 0.0
    assert _start(sim, monkeypatch, dt)[holder.vdof, 2] == holder.stop


def test_a_prediction_that_inverts_an_element_starts_from_the_last_state():
    """A last increment continued so far that it turns elements inside out: Newton finds the
    start inverted in its first evaluation, and the step starts again from the last
    converged state (the target positions of the prescribed DoFs applied), converging
    there."""
    sim = Simulation.from_scene(coarse(ROOT / "scenes" / "cup_drawing.toml"))
    sim.step()
    starts = []
    minimise = simulation.minimise

    def recorded(problem, x0, *args, **kw):
        starts.append(x0.copy())
        return minimise(problem, x0, *args, **kw)

    free = ~sim.model.problem.fixed
    rng = np.random.default_rng(0)
    sim._last_increment = np.where(free, rng.normal(scale=1e-2, size=sim.x.shape), 0.0)
    last = sim.x.copy()
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(simulation, "minimise", recorded)
        rec = sim.step()
    assert sim.failure is None and rec.iterations > 0
    assert len(starts) == 2  # the inverted prediction, then the last state
    assert np.array_equal(starts[1][free], last[free])

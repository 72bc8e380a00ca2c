"""The paper's cantilever (Fig. 5, 8) as numbers: Euler-Bernoulli at nu = 0, and Poisson
locking of linear prisms at nu = 0.49 against Q3T and the quadratic reference."""

import functools

import numpy as np
import pytest

from sim.scene import load_scene
from sim.simulation import Simulation

E, RHO, L, H = 1e11, 1000.0, 0.7, 0.007
# Self-weight tip deflection of the beam: q L^4 / (8 E I), q = rho g b h, I = b h^3 / 12.
# E is chosen so the tip moves 0.1 % of L: geometric nonlinearity is below 1e-5 there.
W_EB = 1.5 * RHO * 9.81 * L**4 / (E * H * H)


@functools.cache
def tip(element: str, nu: float, edge: float = 0.0046667) -> float:
    sim = Simulation.from_scene(load_scene("scenes/cantilever.toml", {
        "material.E": E, "material.nu": nu, "material.density": RHO, "shell.element": element,
        "stepping.steps": 1, "mesh.edge_length": edge}))
    assert sim.run(), sim.failure
    return -sim.records[-1].probes["tip_deflection"]


@pytest.mark.slow
def test_quadratic_matches_euler_bernoulli_at_nu_zero():
    # 3 % is the bound; shear deformation adds 0.8 (h/L)^2 = 1e-4, and the mesh
    # (4,500 triangles, 84k DoFs) is converged to better than 0.1 % for quadratic prisms.
    assert abs(tip("quadratic", 0.0) / W_EB - 1) < 0.03


@pytest.mark.slow
def test_q3t_close_to_reference_and_linear_locks_at_nu_049():
    ref = tip("quadratic", 0.49)
    q3t = tip("q3t", 0.49)
    lin = tip("linear", 0.49)
    assert abs(q3t / ref - 1) < 0.05  # issue bound, measured 4.9 %
    assert ref / lin >= 1.5  # Poisson locking: measured 1.59x too stiff


@pytest.mark.slow
def test_refinement_linear_converges_to_a_stiffer_answer():
    """Refining in-plane (one layer, as in Fig. 8) does not cure linear prisms: their error
    against the quadratic reference stays above 30 % while Q3T's shrinks below 5 %."""
    ref = tip("quadratic", 0.49)
    edges = [0.0175, 0.00875, 0.0046667, 0.0035]  # measured lin/ref 0.33, 0.53, 0.63, 0.65
    lin = np.array([tip("linear", 0.49, e) for e in edges]) / ref
    q3t = np.array([tip("q3t", 0.49, e) for e in edges]) / ref
    assert np.all(lin < 0.7)
    assert abs(lin[-1] - lin[-2]) < 0.05  # levelling off, at the wrong (stiffer) answer
    assert np.all(np.diff(q3t) > 0)  # Q3T approaches the reference monotonically
    assert abs(1 - q3t[-1]) < 0.05 and abs(1 - q3t[-1]) < abs(1 - q3t[0])

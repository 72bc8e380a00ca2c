"""The paper's cantilever (Fig. 5, 8) as numbers: Euler-Bernoulli at nu = 0, and Poisson
locking of linear prisms at nu = 0.49 against Q3T and the quadratic reference."""

import functools

import numpy as np
import pytest

from sim.apps.study_report import richardson
from sim.scene.load import load_scene
from sim.stepping.simulation import Simulation

E, RHO, L, H = 1e11, 1000.0, 0.7, 0.007
# Self-weight tip deflection of the beam: q L^4 / (8 E I), q = rho g b h, I = b h^3 / 12.
# E is chosen so the tip moves 0.1 % of L: geometric nonlinearity is below 1e-5 there.
W_EB = 1.5 * RHO * 9.81 * L**4 / (E * H * H)


@functools.cache
def tip(element: str, nu: float, edge: float = 0.0046667,
        quadrature: tuple[int, int] | None = None) -> float:
    o = {"material.E": E, "material.nu": nu, "material.density": RHO, "shell.element": element,
         "stepping.steps": 1, "mesh.edge_length": edge}
    if quadrature:
        o["shell.quadrature"] = list(quadrature)
    sim = Simulation.from_scene(load_scene("scenes/cantilever.toml", o))
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
    # issue bound 5 %, on the scene's own mesh (150 x 15 cells, 4,500 triangles: the paper's
    # beam size); measured q3t / ref = 0.9514, a margin of 0.14 %
    assert abs(q3t / ref - 1) < 0.05
    assert ref / lin >= 1.5  # Poisson locking: measured 1.59x too stiff


@pytest.mark.slow
def test_refinement_linear_converges_to_a_stiffer_answer():
    """Refining in-plane (one layer, as in Fig. 8) does not cure linear prisms: extrapolated to
    zero edge length, their tip deflection stays far below the quadratic reference (Poisson
    locking through the thickness), while Q3T's limit is the reference."""
    ref = tip("quadratic", 0.49)
    edges = np.array([0.0175, 0.00875, 0.0046667, 0.0035])
    # measured lin/ref 0.330, 0.532, 0.628, 0.650; q3t/ref 0.645, 0.853, 0.951, 0.973
    lin = np.array([tip("linear", 0.49, e) for e in edges]) / ref
    q3t = np.array([tip("q3t", 0.49, e) for e in edges]) / ref
    assert np.all(np.diff(lin) > 0) and np.all(np.diff(q3t) > 0)  # monotone: a limit to fit
    lin_inf, lin_r = richardson(edges[1:], lin[1:])
    q3t_inf, q3t_r = richardson(edges[1:], q3t[1:])
    # measured rates 1.53 (linear) and 1.57 (Q3T), near the h^2 of linear in-plane
    # interpolation; a rate outside 1-3 would mean the fit is noise
    assert 1.0 < lin_r < 3.0 and 1.0 < q3t_r < 3.0
    # measured limits: linear 0.688 (1.45x too stiff), Q3T 1.010. The fit through the three
    # coarser levels instead (pre-asymptotic, rate 0.96) gives 0.745 and 1.07; 0.75 still means
    # at least 1.33x too stiff. Q3T's 2 % covers the fit error and the reference's own mesh
    # error (quadratic at 3.5 mm against 4.67 mm: +0.13 %)
    assert lin_inf < 0.75
    assert abs(q3t_inf - 1) < 0.02


@pytest.mark.slow
def test_mode_free_rule_locks():
    """The rules without spurious modes (tests/unit/test_elements.py) lock in transverse shear: on
    the cantilever at nu = 0.49 and 8.75 mm, Q3T's 3 x 3 rule gives 0.63 of the reference
    deflection against 0.85 for the paper's 1 x 3, and linear's 3 x 2 0.39 against 0.53
    (docs/verification.md, 'Quadrature and spurious modes')."""
    ref = tip("quadratic", 0.49)
    h = 0.00875
    paper_q3t, full_q3t = tip("q3t", 0.49, h, (1, 3)) / ref, tip("q3t", 0.49, h, (3, 3)) / ref
    paper_lin, full_lin = tip("linear", 0.49, h, (1, 2)) / ref, tip("linear", 0.49, h, (3, 2)) / ref
    # measured 0.853 / 0.628 and 0.532 / 0.388: the fuller rule costs over 20 % of the answer
    assert full_q3t < 0.8 * paper_q3t and full_lin < 0.8 * paper_lin

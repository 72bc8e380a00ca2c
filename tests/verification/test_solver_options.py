"""Solver options and loads that each need their own proof: point loads against beam theory,
the SciPy fallback against PARDISO, both Hessian projections, per-scene quadrature, and a
cut-back that rescues a step."""

import numpy as np
import pytest

from sim.scene.load import load_scene
from sim.stepping.simulation import Simulation

pytestmark = pytest.mark.fast  # seconds: make test-fast runs it

E, L, B, H = 1e11, 0.7, 0.07, 0.007


def cantilever(**o) -> Simulation:
    base = {"mesh.edge_length": 0.035, "stepping.steps": 1}
    return Simulation.from_scene(load_scene("scenes/cantilever.toml", {**base, **o}))


def solved(**o) -> Simulation:
    sim = cantilever(**o)
    assert sim.run(), sim.failure
    return sim


def test_point_load_tip_deflection_matches_euler_bernoulli():
    """Tip load P on the quadratic cantilever at nu = 0: w = P L^3 / (3 E I). Shear adds
    3 E I / (kappa G A L^2) = 6e-5 and the mesh (320 triangles) is converged to 1e-4
    (measured 1.00003); 0.5 % also leaves room for the load's local indentation."""
    P = 1.0
    sim = solved(**{"material.E": E, "material.nu": 0.0, "shell.element": "quadratic",
                    "mesh.edge_length": 0.0175,
                    "loads": [{"kind": "point", "vector": [0, 0, -P], "point": [L, B / 2, 0]}]})
    w_eb = P * L**3 / (3 * E * B * H**3 / 12)
    assert -sim.records[-1].probes["tip_deflection"] / w_eb == pytest.approx(1.0, abs=5e-3)
    assert sim.records[-1].probes["clamp_reaction_z"] == pytest.approx(P, rel=1e-6)


def test_scipy_fallback_matches_pardiso():
    """Same Newton path, different factorisation: both solves are refined to 1e-10 of the
    right-hand side (sim.solve.problem.solve_refined), so the answers agree far below Newton's rtol
    (measured 8e-14 relative)."""
    sims = {}
    for name in ("pardiso", "scipy"):
        try:
            sims[name] = solved(**{"material.E": 1e9, "solver.linear_solver": name})
        except (ImportError, OSError, RuntimeError) as exc:  # no MKL on this machine
            pytest.skip(f"{name} unavailable: {exc}")
    assert sims["pardiso"].model.built["linear_solver"] == "pardiso"
    assert sims["scipy"].model.built["linear_solver"] == "scipy"
    u = {k: s.x - s.model.x0 for k, s in sims.items()}
    assert np.abs(u["pardiso"] - u["scipy"]).max() < 1e-8 * np.abs(u["scipy"]).max()


@pytest.mark.parametrize("element", ["linear", "q3t"])
def test_hessian_projections_reach_the_same_answer(element):
    """The projection changes Newton's path, not its fixed point: 'qp', 'element', 'none' and
    'auto' reach the same sag (1.4 % of the length for linear, 4.7 % for Q3T). Newton's exits
    leave each answer uncertain by its residual floor (atol, about 6e-7 N here, times a
    compliance of 0.1 m/N) or by the correction exit (residual under 1e-3 of its reference):
    measured spread 1.8e-6 (linear) and 1.8e-5 (Q3T) relative; 1e-4 is that with a margin."""
    tips = {}
    for proj in ("qp", "element", "none", "auto"):
        sim = solved(**{"material.E": 1e9, "shell.element": element, "stepping.steps": 4,
                        "solver.hessian_projection": proj})
        tips[proj] = sim.records[-1].probes["tip_deflection"]
    ref = tips["auto"]
    assert abs(ref) > 0.005
    for proj, v in tips.items():
        assert v == pytest.approx(ref, rel=1e-4), proj


def test_scene_quadrature_changes_the_rule():
    """shell.quadrature replaces the element's default rule (and changes the answer: the
    3 x 3 rule locks, tests/verification/test_cantilever.py); thickness_points only the thickness
    part."""
    default = cantilever()
    full = cantilever(**{"shell.quadrature": [3, 3]})
    thick = cantilever(**{"shell.thickness_points": 5})
    assert default.result()["quadrature"] == [1, 3]
    assert full.result()["quadrature"] == [3, 3]
    assert thick.result()["quadrature"] == [1, 5]
    assert len(full.model.elasticity.rule.weights) == 9
    assert full.model.elasticity.dNdX.shape[1] == 9
    tips = []
    for sim in (default, full):
        assert sim.run(), sim.failure
        tips.append(sim.records[-1].probes["tip_deflection"])
    assert abs(tips[1]) < 0.9 * abs(tips[0])  # measured 0.25 at this coarse mesh


def test_cut_back_rescues_a_step():
    """A 40 % sag in one step: Newton fails on the full increment, the halved ones converge,
    and the answer is the one a run of 8 steps reaches (measured 1.7e-8 relative apart, 3
    cut-backs; 1e-6 covers Newton's exits as in the projection test)."""
    # Newton capped at 30 iterations: within the default cap (200) it takes the full step
    o = {"material.E": 1e8, "shell.element": "q3t", "solver.max_iterations": 30}
    with pytest.raises(AssertionError):
        solved(**o, **{"stepping.max_cutbacks": 0})  # the full step alone fails
    one = solved(**o)
    rec = one.records[-1]
    assert rec.cutbacks >= 1 and one.result()["converged"]
    eight = solved(**o, **{"stepping.steps": 8})
    assert sum(r.cutbacks for r in eight.records) == 0
    assert rec.probes["tip_deflection"] == pytest.approx(
        eight.records[-1].probes["tip_deflection"], rel=1e-6)
    assert abs(rec.probes["tip_deflection"]) > 0.25

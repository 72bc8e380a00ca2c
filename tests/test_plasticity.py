"""Elastoplastic sheets through the whole solver: uniaxial tension and simple shear against the
1-D hardening law, isochoric flow, finite differences of the plastic incremental energy, the
classical springback formula, and the paper's claim that linear prisms retain less plasticity."""

import numpy as np
import pytest
from scipy.optimize import brentq

from sim.materials.plasticity import yield_stress
from sim.scene import load_scene, scene_from_dict
from sim.simulation import Simulation

E, NU = 200e9, 0.3
MU = E / (2 * (1 + NU))
HARDENING = {
    "linear": ({"law": "linear", "modulus": 2e9}, 1, lambda Y0: np.array([Y0, 2e9])),
    "voce": ({"law": "voce", "saturation": 400e6, "rate": 20.0}, 3,
             lambda Y0: np.array([Y0, 400e6, 20.0])),
}


def block(hardening: dict, bcs: list, regions: list, steps: int, element="q3t") -> Simulation:
    """A 10 x 10 x 2 mm block of one prism layer (a single cell: 2 elements)."""
    raw = {"name": "block", "mesh": {"kind": "rectangle", "size": [0.01, 0.01],
                                     "edge_length": 0.01},
           "shell": {"thickness": 0.002, "element": element},
           "material": {"model": "plastic", "E": E, "nu": NU, "yield_stress": 200e6,
                        "hardening": hardening},
           "regions": regions, "bcs": bcs, "stepping": {"steps": steps},
           "probes": [{"name": "rx", "kind": "reaction", "region": "right", "component": "x"}]
           if any(r["name"] == "right" for r in regions) else []}
    return Simulation.from_scene(scene_from_dict(raw))


def plane(name, point, normal):
    return {"name": name, "plane": {"point": point, "normal": normal}}


@pytest.mark.parametrize("law", sorted(HARDENING))
def test_uniaxial_tension_follows_the_hardening_law(law):
    spec, law_id, hp_of = HARDENING[law]
    stretch = 0.05
    sim = block(spec, [
        {"region": "left", "components": "x"},
        {"region": "front", "components": "y"},
        {"region": "left", "components": "z", "layers": "bottom"},
        {"region": "front", "components": "z", "layers": "bottom"},
        {"region": "right", "components": "x", "displacement": [stretch * 0.01, 0, 0]},
    ], [plane("left", [0, 0, 0], [1, 0, 0]), plane("right", [0.01, 0, 0], [1, 0, 0]),
        plane("front", [0, 0, 0], [0, 1, 0])], steps=10)
    hp = hp_of(200e6)
    for _ in range(10):
        rec = sim.step()
        x = sim.x
        eps = np.log(1 + stretch * rec.time)  # axial log strain, homogeneous
        # independent 1-D integration: Hencky elasticity is linear in log strain, so in
        # uniaxial Kirchhoff stress tau: eps = tau / E + ep and tau = Y(ep) once yielding
        tau_1d = E * eps if E * eps <= 200e6 else brentq(
            lambda t, eps=eps: t - yield_stress(law_id, hp, eps - t / E)[0], 1e6, 1e10)
        width = x[:, 1].max() - x[:, 1].min()
        thick = x[:, 2].max() - x[:, 2].min()
        J = (1 + stretch * rec.time) * width / 0.01 * thick / 0.002
        tau = rec.probes["rx"] / (width * thick) * J  # the grip pulls the block along +x
        # 1 % is the bound; the state is homogeneous, so the only errors are Newton's
        # (rtol 1e-8) and the reaction summed over the face (exact for constant stress)
        assert abs(tau / tau_1d - 1) < 0.01, (rec.time, tau, tau_1d)
    ep = sim.model.elasticity.ep
    assert ep.min() > 0.02 and np.ptp(ep) < 1e-6 * ep.max()  # yielded, homogeneously
    det = np.linalg.det(sim.model.elasticity.fp_inv)
    assert np.abs(det - 1).max() < 1e-10  # isochoric flow: det Fp = 1


def test_simple_shear_equivalent_stress_follows_the_law():
    """Homogeneous simple shear x = X + gamma Y e_x prescribed on every node. Small-strain 1-D
    reference: sqrt(3) tau_xy = Y(ep), ep = (gamma - tau_xy / mu) / sqrt(3); at gamma <= 0.03 the
    finite-strain difference is O(gamma^2) < 0.1 %."""
    spec, law_id, hp_of = HARDENING["linear"]
    gamma = 0.03
    raw_bcs = []
    sim = block(spec, raw_bcs, [], steps=6)
    m = sim.model
    m.fixed[:] = True
    m.problem.set_fixed(m.fixed)
    m.prescribed[:, 0] = gamma * m.shell.rest[:, 1]
    hp = hp_of(200e6)
    for _ in range(6):
        rec = sim.step()
        g = gamma * rec.time
        t_xy = MU * g if np.sqrt(3) * MU * g <= 200e6 else brentq(
            lambda t, g=g: np.sqrt(3) * t - yield_stress(law_id, hp, (g - t / MU) / np.sqrt(3))[0],
            1e6, 1e10)
        ep_1d = max(0.0, (g - t_xy / MU) / np.sqrt(3))
        vm = m.elasticity.von_mises(sim.x)
        assert abs(vm.mean() / (np.sqrt(3) * t_xy) - 1) < 0.01
        if ep_1d > 1e-3:
            assert abs(m.elasticity.ep.mean() / ep_1d - 1) < 0.01


def test_plastic_energy_finite_differences():
    """Gradient and Hessian of the incremental potential at elastic, yielding and hardening
    states, through the element kernel (exact Hessian, no projection)."""
    from tests.test_energy_terms import _fd_check

    spec, _, _ = HARDENING["linear"]
    sim = block(spec, [{"region": "left"}], [plane("left", [0, 0, 0], [1, 0, 0])], steps=1)
    el = sim.model.elasticity
    el.project = 0
    rest = sim.model.shell.rest
    rng = np.random.default_rng(2)
    # committed state from a plastic stretch, then three probe states around it
    el.commit(rest * np.array([1.01, 1.0, 1.0]))
    assert el.ep.max() > 0
    pat = sim.model.pattern
    for amp in (0.0, 0.004, 0.02):  # elastic unloading, near yield, deep in hardening
        x = rest * np.array([1.01 + amp, 1.0, 1.0]) + 1e-6 * rng.standard_normal(rest.shape)

        def grad(y):
            g = np.zeros_like(y)
            el.add_gradient(y, g)
            return g

        def hv(y, v):
            d = np.zeros(pat.nnz)
            el.add_hessian(y, d)
            return (pat.matrix(d) @ v.ravel()).reshape(v.shape)

        _fd_check(el.energy, grad, hv, x, 1e-5)


E_B, NU_B, Y_B, T_B = 200e9, 0.33, 16e6, 0.005


@pytest.mark.parametrize("element", ["q3t", "quadratic"])
@pytest.mark.parametrize("X", [0.05, 0.2])
def test_springback_matches_the_classical_formula(element, X):
    """Elastic-perfectly-plastic strip bent to radius R and released: R / R_after =
    4 X^3 - 3 X + 1, X = sigma_y R / (E t), with the plane-strain substitutions
    E -> E / (1 - nu^2) and sigma_y -> 2 sigma_y / sqrt(3) (von Mises in plane strain).
    Measured: Q3T 1.1 % / 1.8 %, quadratic 0.9 % / 1.3 % off; the issue's bound is 3 %."""
    Ep, Yp = E_B / (1 - NU_B**2), 2 * Y_B / np.sqrt(3)
    R = X * Ep * T_B / Yp
    sim = Simulation.from_scene(load_scene("scenes/plastic_bending.toml", {
        "shell.element": element, "bcs.3.bend.angle": 0.1 / R}))
    assert sim.run(), sim.failure
    k = [r.probes["curvature"] for r in sim.records]
    assert abs((k[-1] / k[-2]) / (4 * X**3 - 3 * X + 1) - 1) < 0.03


def test_linear_prisms_retain_less_plastic_deformation():
    """The paper's Fig. 6 claim as a number: after release on plastic_bending the linear prism
    keeps under a fifth of Q3T's residual curvature (measured 0.037 vs 0.955 1/m)."""
    res = {}
    for el in ("linear", "q3t"):
        sim = Simulation.from_scene(load_scene("scenes/plastic_bending.toml",
                                               {"shell.element": el}))
        assert sim.run(), sim.failure
        res[el] = sim.records[-1].probes["curvature"]
    assert res["linear"] < 0.2 * res["q3t"]


def test_elastic_scene_has_no_plastic_state():
    sim = Simulation.from_scene(load_scene("scenes/cantilever.toml",
                                           {"mesh.edge_length": 0.035}))
    assert sim.model.elasticity.ep.size == 0 and not sim.model.built["plastic_state"]
    assert "eq_plastic_strain" not in sim.frame().fields

"""Elastoplastic sheets through the whole solver: uniaxial tension and simple shear against the
1-D hardening laws, isochoric flow, finite differences of the plastic incremental energy, the
classical springback formula on a converged mesh, the paper's claim that linear prisms retain
less plasticity, and the roll-back of the plastic state on a cut-back."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import brentq

from sim.elements import ELEMENTS, ROUTINE
from sim.frames.fields import curvature_xz, mid_surface
from sim.materials.plasticity import net_plastic_strain
from sim.scene.load import load_scene, scene_from_dict
from sim.stepping.simulation import Simulation
from tests.support.fd import fd_check_term

pytestmark = pytest.mark.fast  # seconds: make test-fast runs it

E, NU, Y0 = 200e9, 0.3, 200e6
MU = E / (2 * (1 + NU))
SWIFT_K, SWIFT_N = 500e6, 0.2
SWIFT_E0 = (Y0 / SWIFT_K) ** (1 / SWIFT_N)  # the scene derives e0 so that Y(0) = Y0
# scene spec and the 1-D law written out independently of sim.materials.plasticity
LAWS = {
    "perfect": ({"law": "perfect"}, lambda ep: Y0),
    "linear": ({"law": "linear", "modulus": 2e9}, lambda ep: Y0 + 2e9 * ep),
    "swift": ({"law": "swift", "K": SWIFT_K, "n": SWIFT_N},
              lambda ep: SWIFT_K * (SWIFT_E0 + ep) ** SWIFT_N),
    "voce": ({"law": "voce", "saturation": 400e6, "rate": 20.0},
             lambda ep: 400e6 - (400e6 - Y0) * np.exp(-20.0 * ep)),
}


def block(hardening: dict, bcs: list, regions: list, steps: int, element="q3t",
          edge=0.01) -> Simulation:
    """A 10 x 10 x 2 mm block of one prism layer (edge 10 mm: a single cell, 2 elements)."""
    raw = {"name": "block", "mesh": {"kind": "rectangle", "size": [0.01, 0.01],
                                     "edge_length": edge},
           "shell": {"thickness": 0.002, "element": element},
           "material": {"model": "plastic", "E": E, "nu": NU, "yield_stress": Y0,
                        "hardening": hardening},
           "regions": regions, "bcs": bcs, "stepping": {"steps": steps},
           "probes": [{"name": "rx", "kind": "reaction", "region": "right", "component": "x"}]
           if any(r["name"] == "right" for r in regions) else []}
    return Simulation.from_scene(scene_from_dict(raw))


def plane(name, point, normal):
    return {"name": name, "plane": {"point": point, "normal": normal}}


def assert_isochoric(el):
    # det Fp = 1 to round-off: Fp^-1 is a product of exp(-deps_p) factors with tr deps_p = 0 to
    # ~1e-16 each, so det drifts by ~1e-16 per committed step; 1e-10 is the bound
    assert np.abs(np.linalg.det(el.fp_inv) - 1).max() < 1e-10


@pytest.mark.parametrize("law", sorted(LAWS))
def test_uniaxial_tension_follows_the_hardening_law(law):
    spec, Y = LAWS[law]
    stretch = 0.05
    sim = block(spec, [
        {"region": "left", "components": "x"},
        {"region": "front", "components": "y"},
        {"region": "left", "components": "z", "layers": "bottom"},
        {"region": "front", "components": "z", "layers": "bottom"},
        {"region": "right", "components": "x", "displacement": [stretch * 0.01, 0, 0]},
    ], [plane("left", [0, 0, 0], [1, 0, 0]), plane("right", [0.01, 0, 0], [1, 0, 0]),
        plane("front", [0, 0, 0], [0, 1, 0])], steps=10)
    for _ in range(10):
        rec = sim.step()
        assert rec.iterations > 0
        x = sim.x
        eps = np.log(1 + stretch * rec.time)  # axial log strain, homogeneous
        # independent 1-D integration: Hencky elasticity is linear in log strain, so in
        # uniaxial Kirchhoff stress tau: eps = tau / E + ep and tau = Y(ep) once yielding
        tau_1d = E * eps if E * eps <= Y0 else brentq(
            lambda t, eps=eps: t - Y(eps - t / E), Y0, E * eps, xtol=1e-6)
        width = x[:, 1].max() - x[:, 1].min()
        thick = x[:, 2].max() - x[:, 2].min()
        J = (1 + stretch * rec.time) * width / 0.01 * thick / 0.002
        tau = rec.probes["rx"] / (width * thick) * J  # the grip pulls the block along +x
        # 1 % is the bound; the state is homogeneous, so the only errors are Newton's
        # (rtol 1e-8) and the reaction summed over the face (exact for constant stress):
        # measured below 1e-11 for every law
        assert abs(tau / tau_1d - 1) < 0.01, (rec.time, tau, tau_1d)
    ep = sim.model.elasticity.ep
    assert ep.min() > 0.02 and np.ptp(ep) < 1e-6 * ep.max()  # yielded, homogeneously
    assert_isochoric(sim.model.elasticity)


@pytest.mark.parametrize("law", sorted(LAWS))
def test_simple_shear_follows_the_hardening_law(law):
    """In-plane simple shear x = X + gamma Y prescribed (x and y) on the block's lateral faces
    only, with z held on their bottom edge; the skins and the interior nodes (9 columns of a
    4 x 4 cell block, every layer) are unknowns Newton solves for. Prescribing just the two
    faces y = 0 and y = 10 mm would not give a homogeneous state: the free faces x = 0 and
    x = 10 mm carry no shear traction, so the stress would fall off towards them.
    Small-strain 1-D reference: sqrt(3) tau_xy = Y(ep), gamma = tau_xy / mu + sqrt(3) ep; at
    gamma <= 0.03 the finite-strain corrections are O(gamma^2) ~ 1e-3 relative."""
    spec, Y = LAWS[law]
    gamma = 0.03
    sim = block(spec, [], [], steps=6, edge=0.0025)
    m = sim.model
    rest = m.shell.rest
    lateral = np.zeros(len(rest), bool)
    lateral[m.column_nodes(_boundary_mask(m))] = True
    m.fixed[lateral, :2] = True
    m.fixed[lateral & (rest[:, 2] < rest[:, 2].min() + 1e-12), 2] = True
    m.problem.set_fixed(m.fixed)
    m.prescribed[:, 0] = gamma * rest[:, 1]
    assert (~m.fixed[:, :2]).all(1).sum() >= 9 * m.shell.element.q + 9  # interior columns
    interior = ~lateral
    for _ in range(6):
        rec = sim.step()
        # the free nodes start at rest and Newton moves them through the first, already plastic
        # step (7-9 iterations); later steps may start on the solution, since the predictor
        # continues the last increment and the homogeneous path is linear in time
        assert rec.iterations > 0 or rec.step > 1
        g = gamma * rec.time
        # the interior found the homogeneous shear (the patch-test property of the elements)
        np.testing.assert_allclose(sim.x[interior, 0] - rest[interior, 0],
                                   g * rest[interior, 1], rtol=0, atol=1e-3 * g * 0.01)
        t_xy = MU * g if np.sqrt(3) * MU * g <= Y0 else brentq(
            lambda t, g=g: np.sqrt(3) * t - Y((g - t / MU) / np.sqrt(3)), Y0 / np.sqrt(3),
            MU * g, xtol=1e-6)
        ep_1d = max(0.0, (g - t_xy / MU) / np.sqrt(3))
        vm = m.elasticity.von_mises(sim.x)
        # the 1 %; the finite-strain terms and the held z of the bottom edge are far
        # smaller (measured: von Mises within 1.1e-6, ep within 5.6e-6 for every law)
        assert abs(vm.mean() / (np.sqrt(3) * t_xy) - 1) < 0.01, (g, vm.mean(), t_xy)
        assert np.ptp(vm) < 0.01 * vm.mean()  # homogeneous
        if ep_1d > 1e-3:
            assert abs(m.elasticity.ep.mean() / ep_1d - 1) < 0.01
    assert m.elasticity.ep.min() > 0.01  # every point yielded
    assert_isochoric(m.elasticity)


def _boundary_mask(model):
    from sim.geometry.trimesh import boundary_edges

    mask = np.zeros(model.shell.n_plane, bool)
    mask[np.unique(boundary_edges(model.shell.mesh.faces))] = True
    return mask


def _yielding(el, x):
    """Quadrature points (n_elem, n_qp) that would flow plastically at state x (a trial commit
    on a copy of the state, restored afterwards)."""
    fp, ep = el.fp_inv.copy(), el.ep.copy()
    el.commit(x)
    out = el.ep > ep
    el.fp_inv[:], el.ep[:] = fp, ep
    return out


@pytest.mark.parametrize("element", ROUTINE)
@pytest.mark.parametrize("law", sorted(LAWS))
def test_plastic_energy_finite_differences(law, element):
    """Gradient and Hessian of the incremental potential through the element kernel (exact
    Hessian, no projection) around a committed plastic state (Fp != I): elastic unloading (no
    point yields), onset of re-yielding and deep plastic flow (every point yields)."""
    sim = block(LAWS[law][0], [{"region": "left"}], [plane("left", [0, 0, 0], [1, 0, 0])],
                steps=1, element=element)
    el = sim.model.elasticity
    el.project = 0
    rest = sim.model.shell.rest
    rng, fd_rng = np.random.default_rng(2), np.random.default_rng(7)
    el.commit(rest * np.array([1.01, 1.0, 1.0]))  # stretch 1 %: yields (Y0 / E = 0.1 %)
    assert el.ep.min() > 0 and np.abs(el.fp_inv - np.eye(3)).max() > 1e-3
    pat = sim.model.pattern
    # from the committed state (q = Y) the deviatoric stress falls by 2 mu |d eps_xx| on
    # unloading: -1e-3 lowers it to 0.23 Y (elastic), +2e-4 re-yields, +0.02 flows far
    for amp, expect in ((-1e-3, "none"), (2e-4, "all"), (0.02, "all")):
        # noise of 1e-8 m (strain 1e-6) separates the principal stretches without moving any
        # point across the yield surface
        x = rest * np.array([1.01 + amp, 1.0, 1.0]) + 1e-8 * rng.standard_normal(rest.shape)
        flows = _yielding(el, x)
        assert flows.all() if expect == "all" else not flows.any(), (amp, flows.mean())

        # step h = 1e-6 * 1e-3 m (strain ~1e-7): 1e3 times inside the nearest yield-surface
        # margin, while the log strains' absolute round-off (~1e-16, from the eigenvalues of
        # F^T F) stays ~1e-9 of the energy difference (a 1e-11 m step left only 1e-5 of it)
        fd_check_term(el, pat, x, 1e-3, fd_rng)


E_B, NU_B, Y_B, T_B = 200e9, 0.33, 16e6, 0.005
EP_B, YP_B = E_B / (1 - NU_B**2), 2 * Y_B / np.sqrt(3)  # plane-strain modulus and yield


def bent_strip(element, X, edge, tp=20, length=0.04, quadrature=None):
    """plastic_bending as a strip of one cell across (plane strain makes the width irrelevant)
    and ``length`` long, bent by a pure end moment to the radius of the given X = sigma_y R /
    (E t) (plane-strain values), then released. Returns (sim, loaded curvature, curvatures of
    four equal segments under load, axial end force under load)."""
    R = X * EP_B * T_B / YP_B
    o = {"shell.element": element, "mesh.size": [length, edge], "mesh.edge_length": edge,
         "bcs.3.bend.length": length, "bcs.3.bend.angle": length / R,
         "regions.2.plane.point": [length, 0.0, 0.0]}
    scene = load_scene("scenes/plastic_bending.toml", o)
    shell = {"thickness_points": tp} if quadrature is None else {"thickness_points": None,
                                                                 "quadrature": quadrature}
    scene = scene.model_copy(update={"shell": scene.shell.model_copy(update=shell)})
    sim = Simulation.from_scene(scene)
    m = sim.model
    for _ in range(scene.stepping.steps):
        sim.step()
    V = m.shell.mesh.vertices
    mid = mid_surface(m, sim.x)
    segments = [curvature_xz(mid[(V[:, 0] >= a - 1e-9) & (V[:, 0] <= a + length / 4 + 1e-9)])
                for a in np.linspace(0, length, 5)[:-1]]
    g = np.zeros_like(sim.x)
    m.elasticity.add_gradient(sim.x, g)
    axial = g[m.column_nodes(m.regions["end"]), 0].sum()
    k_load = sim.records[-1].probes["curvature"]
    assert sim.run(), sim.failure  # the release stage
    return sim, k_load, np.array(segments), axial


def springback_ratio(X: float) -> float:
    return 4 * X**3 - 3 * X + 1


# (coarse edge, fine edge) per element: Q3T converges in-plane more slowly than the quadratic
# prism, whose result does not change from 5 to 1.25 mm (pure bending is in its space)
EDGES = {"q3t": (0.0025, 0.00125), "quadratic": (0.005, 0.0025)}


@pytest.mark.parametrize("element", ["q3t", "quadratic"])
@pytest.mark.parametrize("X", [0.1, 0.2])
def test_springback_matches_the_classical_formula(element, X):
    """Elastic-perfectly-plastic strip bent by a pure moment and released: R / R_after =
    4 X^3 - 3 X + 1, X = sigma_y R / (E t), with the plane-strain substitutions
    E -> E / (1 - nu^2) and sigma_y -> 2 sigma_y / sqrt(3) (von Mises in plane strain), R the
    measured loaded radius. The bound is the issue's 3 %; the result is shown converged in the
    mesh and in the thickness rule, in pure bending (no axial force) of uniform curvature.

    X = 0.1 and 0.2 (moment 98.7 % and 94.7 % of the plastic moment). Below, the section is
    nearly a hinge: at X = 0.05 (99.7 %) its tangent bending stiffness is (2X)^3 = 1e-3 of the
    elastic one, so a 1e-4 difference of moment capacity between elements (a Gauss point just
    inside or outside the elastic core) moves the curvature by 10 % and the loaded shape is
    no longer the uniform arc the formula describes (docs/verification.md, Plasticity).
    Measured (formula error on the fine mesh, tp = 20): Q3T -0.1 % / -1.2 %, quadratic -0.1 % /
    -1.2 % at X = 0.1 / 0.2; the quartic prism gives -0.1 % at X = 0.2, so the -1.2 % is the
    thickness strain being only linear through the thickness in both, not the plasticity."""
    coarse, fine = EDGES[element]
    n_inplane = ELEMENTS[element].default_quadrature[0]
    runs = {"base": bent_strip(element, X, coarse),
            "mesh": bent_strip(element, X, fine),
            "thickness": bent_strip(element, X, coarse, quadrature=(n_inplane, 40))}
    ratios = {}
    for name, (sim, k_load, _, axial) in runs.items():
        k_after = sim.records[-1].probes["curvature"]
        Xm = YP_B / (EP_B * T_B * k_load)  # from the measured loaded curvature
        ratios[name] = k_after / k_load
        assert abs(ratios[name] / springback_ratio(Xm) - 1) < 0.03, (name, ratios[name], Xm)
        # pure bending: the axial force is below 1e-3 of the fully plastic one (Y t width),
        # so it lowers the plastic moment by less than 1e-6 (M_p(N) = M_p (1 - (N/N_p)^2))
        width = np.ptp(sim.model.shell.rest[:, 1])
        assert abs(axial) < 1e-3 * YP_B * T_B * width, (name, axial)
        assert_isochoric(sim.model.elasticity)
    # uniform curvature on the fine mesh: a spread d of the local curvature moves the local X
    # by d and the formula by at most |dlnK/dlnX| d <= 1.2 d at X <= 0.2, so 0.5 % keeps it
    # within 0.6 % (measured: <= 0.13 %)
    _, _, segments, _ = runs["mesh"]
    assert np.ptp(segments) < 0.005 * segments.mean(), segments
    # converged: halving the edge or doubling the thickness points (20 -> 40) changes the
    # ratio by less than 0.5 % (measured <= 0.26 % and <= 0.1 %), so the converged result is
    # within ~0.5 % of the one checked above and the 3 % bound is met with margin
    for name in ("mesh", "thickness"):
        assert abs(ratios[name] / ratios["base"] - 1) < 0.005, (name, ratios)


@pytest.mark.parametrize("element", sorted(ELEMENTS))
def test_bending_flow_is_isochoric_for_every_element(element):
    """det Fp = 1 where the principal axes turn with the section (bending and release), for
    every registered element."""
    # X = 0.2 with 9 section points: the +-0.32 t/2 points lie in the elastic core (+-0.4 t/2),
    # so the section keeps a bending stiffness (with fewer, Newton meets a hinge)
    sim, *_ = bent_strip(element, 0.2, 0.005, tp=9, length=0.01)
    el = sim.model.elasticity
    assert el.ep.max() > 3e-5  # the skins flowed (~1.5x the plane-strain yield strain 8e-5)
    assert_isochoric(el)


def test_linear_prisms_retain_less_plastic_deformation():
    """The paper's Fig. 6 claim as numbers on plastic_bending. 'Plastic deformation' is the net
    plastic strain the sheet keeps (sqrt(2/3) |ln U_p|, Fp = R_p U_p), and its effect, the
    residual curvature. The accumulated eq. plastic strain is not that measure: linear prisms
    accumulate more (measured 1.98e-3 against Q3T's 1.73e-3) because they yield back on
    release. Measured: residual curvature 0.037 vs 0.99 1/m, mean net plastic strain 1.6e-4
    vs 1.7e-3."""
    res = {}
    for el in ("linear", "q3t"):
        sim = Simulation.from_scene(load_scene("scenes/plastic_bending.toml",
                                               {"shell.element": el}))
        assert sim.run(), sim.failure
        e = sim.model.elasticity
        res[el] = (sim.records[-1].probes["curvature"], net_plastic_strain(e.fp_inv).mean(),
                   e.ep.mean())
        assert_isochoric(e)
    (k_lin, net_lin, ep_lin), (k_q3t, net_q3t, ep_q3t) = res["linear"], res["q3t"]
    assert k_lin < 0.2 * k_q3t
    assert net_lin < 0.2 * net_q3t
    # Q3T keeps what it accumulated (monotone bending, elastic release); linear prisms lose
    # most of theirs to reverse flow
    assert net_q3t > 0.99 * ep_q3t and net_lin < 0.2 * ep_lin


def test_cutback_rolls_back_the_plastic_state():
    """A step whose first attempt fails (Newton capped at one iteration by a spy) is retried
    at half the increment from exactly the committed state: Fp^-1 and ep bit-identical."""
    sim = Simulation.from_scene(load_scene("scenes/plastic_bending.toml"))
    el = sim.model.elasticity
    sim.step()
    assert el.ep.max() > 0  # a plastic state to roll back to
    before = (el.fp_inv.copy(), el.ep.copy())
    starts, results = [], []
    attempt = sim._attempt

    def spy(t_new, dt):
        starts.append((el.fp_inv.copy(), el.ep.copy()))
        if len(starts) > 1:
            return attempt(t_new, dt)
        settings = sim.model.settings
        sim.model.settings = replace(settings, max_iterations=1)
        try:
            res = attempt(t_new, dt)
        finally:
            sim.model.settings = settings
        results.append(res)
        return res

    sim._attempt = spy
    rec = sim.step()
    assert not results[0].converged and results[0].iterations == 1
    assert rec.cutbacks == 1 and len(starts) >= 3  # two half steps after the failed one
    for a, b in zip(before, starts[1], strict=True):
        assert np.array_equal(a, b)
    assert not np.array_equal(before[1], el.ep)  # and the retried half steps did flow


def test_elastic_scene_has_no_plastic_state():
    sim = Simulation.from_scene(load_scene("scenes/cantilever.toml",
                                           {"mesh.edge_length": 0.035}))
    assert sim.model.elasticity.ep.size == 0 and not sim.model.built["plastic_state"]
    assert "eq_plastic_strain_pct" not in sim.frame().fields


def test_result_files_carry_the_plastic_fields(tmp_path):
    """final.npz has per-vertex and per-element eq. plastic strain (accumulated and net), von
    Mises stress, thickness and thinning; result.json their min / mean / max. It keeps what a
    later stage goes on from (q3t splitring): the scene and the committed plastic state."""
    import json

    sim = Simulation.from_scene(load_scene("scenes/plastic_bending.toml"))
    assert sim.run(), sim.failure
    sim.write(tmp_path)
    npz = np.load(tmp_path / "final.npz")
    m = sim.model
    n_v, n_e = m.shell.n_vertices, len(m.shell.conn)
    for name in ("eq_plastic_strain", "net_plastic_strain", "von_mises", "thickness",
                 "thinning_pct"):
        assert npz[name].shape == (n_v,) and npz[f"{name}_elem"].shape == (n_e,)
        assert np.all(np.isfinite(npz[name]))
    el = m.elasticity
    np.testing.assert_array_equal(npz["eq_plastic_strain_elem"], el.ep.mean(1))
    np.testing.assert_array_equal(npz["von_mises_elem"], el.von_mises(sim.x).mean(1))
    np.testing.assert_allclose(npz["thinning_pct"], 100 * (1 - npz["thickness"]
                                                           / npz["rest_thickness"]))
    np.testing.assert_array_equal(npz["fp_inv"], el.fp_inv)
    np.testing.assert_array_equal(npz["ep"], el.ep)
    assert scene_from_dict(json.loads(str(npz["scene"]))) == m.scene
    fields = json.loads((tmp_path / "result.json").read_text())["fields"]
    assert fields["eq_plastic_strain"]["max"] == pytest.approx(npz["eq_plastic_strain"].max())
    assert fields["von_mises"]["mean"] == pytest.approx(npz["von_mises"].mean())
    # an elastic scene reports no plastic fields
    el_sim = Simulation.from_scene(load_scene("scenes/cantilever.toml",
                                              {"mesh.edge_length": 0.035}))
    assert "eq_plastic_strain" not in el_sim.result()["fields"]


def test_plastic_bench_yields_half_the_points(monkeypatch):
    """`q3t bench --cases plastic` at a coarse size: the Swift sheet is partly yielded (its
    yield stress is the median von Mises stress) and the ratios against both elastic sheets are
    reported."""
    from sim.apps import bench

    monkeypatch.setitem(bench.CASES["beam"], "spacing", 0.035)
    rows = bench.plastic(repeat=2)
    assert [r["case"] for r in rows] == ["beam_neo_hookean", "beam_hencky", "beam_plastic"]
    assert len({r["dofs"] for r in rows}) == 1  # the same size
    p = rows[-1]
    assert 0.3 < p["yielding_fraction"] < 0.7
    for k in ("iteration_ratio_vs_hencky", "iteration_ratio_vs_neo_hookean",
              "assembly_ratio_vs_hencky", "assembly_ratio_vs_neo_hookean"):
        assert np.isfinite(p[k]) and p[k] > 0

"""The inputs of the shell obstacle course: a surface load of fixed direction, the small-strain
(linear_elastic) term, the curved patches' nodes on their exact surface, and bad input."""

import numpy as np
import pytest

from sim.elements import ROUTINE
from sim.scene.load import SceneError, load_scene
from sim.stepping.simulation import Simulation
from tests.support.fd import fd_check_term

RNG = np.random.default_rng(17)


def _model(path: str, o: dict):
    return Simulation.from_scene(load_scene(path, o)).model


@pytest.mark.parametrize("element", ROUTINE)
def test_surface_load_sums_to_load_times_area(element):
    """On a flat plate the mid-surface's rest area is exact, so the nodal forces sum to the
    load times the area to round-off, with the direction kept (not along the normal)."""
    m = _model("scenes/cantilever.toml", {
        "mesh.edge_length": 0.035, "shell.element": element,
        "loads": [{"kind": "surface", "vector": [30.0, 0.0, -90.0]}]})
    assert np.allclose(m.external.f.sum(0), np.array([30.0, 0, -90.0]) * 0.7 * 0.07,
                       rtol=1e-12)


def test_surface_load_on_a_curved_patch_takes_the_curved_area():
    """The roof's weight per area times its area, 25 x 25 x 40 degrees: the curved quadratic
    mesh integrates the exact cylinder (its edges are arcs to O(h^3) in position, so its area
    is off by O(h^4)); the flat chords miss it by the faceting's O(h^2)."""
    area = 25.0 * 25.0 * np.radians(40)
    o = {"shell.element": "quadratic", "mesh.cells": 4}
    curved = _model("scenes/scordelis_lo.toml", o).external.f.sum(0)[2] / -90.0
    flat = _model("scenes/scordelis_lo.toml", {**o, "mesh.curved": False}).external.f.sum(0)
    flat = flat[2] / -90.0
    # faceting at 10 degrees per cell: 1 - sin(x)/x = 1.3e-3 of the area; the arcs: < 1e-5
    assert abs(curved / area - 1) < 1e-5 < 1e-3 < abs(flat / area - 1)


@pytest.mark.parametrize("element", ROUTINE)
def test_small_strain_term_fd_and_energy(element):
    """The linear_elastic term: gradient and Hessian by finite differences; its energy the
    finite-strain energy's second-order term, W(X + s u) / s^2 as s -> 0 (every element, its
    assumed strains included); and for an element whose strain is the displacement field's,
    sum_q w detJ (mu eps:eps + lam/2 tr(eps)^2), eps = sym grad u, computed here from the
    element's shape-function gradients."""
    m = _model("scenes/cantilever.toml", {"mesh.edge_length": 0.035, "shell.element": element,
                                          "material.model": "linear_elastic"})
    term = next(t for t in m.terms if t.name == "small_strain_elasticity")
    u = 1e-3 * RNG.standard_normal(m.shell.rest.shape)
    x = m.shell.rest + u

    fd_check_term(term, m.pattern, x, 1e-3, RNG)
    el = m.elasticity
    # W(X + s u) / s^2 = 1/2 u K u + O(s): Richardson on s = 1e-3, 1e-4 leaves O(s^2) and the
    # energy's round-off (measured 3e-8 and 6e-8 for Q3T and q3t_ans)
    e1, e2 = (el.energy(m.shell.rest + s * u) / s**2 for s in (1e-3, 1e-4))
    assert abs((10 * e2 - e1) / 9 / term.energy(x) - 1) < 1e-6
    if m.shell.element.assumed_strain:  # its strain is not sym grad u
        return
    H = np.einsum("ead,eqaj->eqdj", u[m.shell.conn], el.dNdX)
    eps = 0.5 * (H + np.swapaxes(H, -1, -2))
    E, nu = 1.0e9, 0.49
    mu, lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
    tr = np.trace(eps, axis1=-2, axis2=-1)
    W = mu * np.einsum("eqij,eqij->eq", eps, eps) + 0.5 * lam * tr**2
    # the same sum in another order: round-off of the 1e5-term sum, far below 1e-9
    assert np.isclose(term.energy(x), float(np.sum(el.wdetJ * W)), rtol=1e-9)


@pytest.mark.parametrize("scene", ["scordelis_lo", "pinched_hemisphere"])
def test_curved_nodes_lie_on_the_surface(scene):
    """Every node of the quadratic element's mid-surface lies on the exact cylinder or sphere
    (to round-off), and its skins at half the thickness from it; flat chords do not."""
    sc = load_scene(f"scenes/{scene}.toml", {"shell.element": "quadratic", "mesh.cells": 4})
    R, h = sc.mesh.radius, sc.shell.thickness

    def radii(sh):
        X = sh.plane_mid if scene == "pinched_hemisphere" else sh.plane_mid[:, 1:]
        return np.linalg.norm(X, axis=1)

    def skin(sh):
        top = sh.rest[sh.layer_nodes(sh.element.q)]
        return np.linalg.norm(top if scene == "pinched_hemisphere" else top[:, 1:], axis=1)

    sh = _model(f"scenes/{scene}.toml", {"shell.element": "quadratic", "mesh.cells": 4}).shell
    assert np.allclose(radii(sh), R, rtol=1e-14) and np.allclose(skin(sh), R + h / 2,
                                                                  rtol=1e-14)
    flat = _model(f"scenes/{scene}.toml", {"shell.element": "quadratic", "mesh.cells": 4,
                                           "mesh.curved": False}).shell
    assert radii(flat).min() < R * (1 - 1e-3)  # chords of 10-22.5 degrees sag by 1e-3..2e-2


BAD = [
    ("scenes/pinched_hemisphere.toml", "mesh.hole", -0.1),
    ("scenes/pinched_hemisphere.toml", "mesh.hole", 1.6),
    ("scenes/pinched_hemisphere.toml", "mesh.cells", 0),
    ("scenes/scordelis_lo.toml", "mesh.angle", 0.0),
    ("scenes/scordelis_lo.toml", "mesh.radius", -25.0),
    ("scenes/scordelis_lo.toml", "loads.0.vector", [0.0, 0.0, 1e20]),
    ("scenes/scordelis_lo.toml", "study.published.value", "big"),
    ("scenes/twisted_beam_inplane.toml", "mesh.twist", 3.2),
    ("scenes/twisted_beam_inplane.toml", "mesh.cells", 0),
    ("scenes/straight_beam_inplane.toml", "mesh.aspect", 0.0),
    ("scenes/straight_beam_inplane.toml", "mesh.aspect", 101.0),
]


@pytest.mark.parametrize("path,key,value", BAD, ids=[f"{b[1]}={b[2]}" for b in BAD])
def test_bad_course_input_names_the_field(path, key, value):
    with pytest.raises(SceneError, match=key.replace(".", r"\.")):
        load_scene(path, {key: value})


def test_a_strip_turns_its_width_by_the_twist_and_refines_both_ways():
    """The twisted beam's mid-surface: the width along y at the root and along z at the tip (a
    90 degree twist), every vertex on the helicoid (its distance from the x axis is its place
    across the width, its angle twist x / length), MacNeal and Harder's 12 x 2 cells at 12 and
    twice as many both ways at 24; the triangles face +z at the root."""
    from sim.geometry import trimesh as meshes
    from sim.model.sheet import build_mesh

    spec = load_scene("scenes/twisted_beam_inplane.toml").mesh
    for cells, across in ((12, 2), (24, 4), (48, 8)):
        assert spec.model_copy(update={"cells": cells}).across == across
    m = build_mesh(spec)
    V = m.vertices
    assert V.shape == (13 * 3, 3) and m.faces.shape == (2 * 12 * 2, 3)
    root, tip = V[np.isclose(V[:, 0], 0.0)], V[np.isclose(V[:, 0], 12.0)]
    assert np.allclose(root[:, 2], 0.0) and np.ptp(root[:, 1]) == pytest.approx(1.1)
    assert np.allclose(tip[:, 1], 0.0, atol=1e-15) and np.ptp(tip[:, 2]) == pytest.approx(1.1)
    a = np.arctan2(V[:, 2], V[:, 1])
    s = np.hypot(V[:, 1], V[:, 2])
    on = s > 1e-12  # the axis itself has no angle
    turned = np.mod(a[on] - np.pi / 2 * V[on, 0] / 12.0 + np.pi / 2, np.pi) - np.pi / 2
    assert np.allclose(turned, 0.0, atol=1e-12)
    assert set(np.round(s, 12)) == {0.0, 0.55}
    assert np.all(meshes.vertex_normals(m)[np.isclose(V[:, 0], 0.0), 2] > 0.99)
    # no twist: a flat strip in z = 0, as the straight beam and the plate have it
    flat = build_mesh(load_scene("scenes/straight_beam_inplane.toml").mesh)
    assert np.all(flat.vertices[:, 2] == 0.0) and flat.faces.shape == (12, 3)


def test_a_tip_traction_sums_to_the_unit_force():
    """The beams' tip tractions are 1 / (width x thickness): a unit force. On the straight
    beam the rim faces are the tip's face exactly; on the twisted one they are made along
    the columns' averaged normals, not quite square to the warped tip, and sum to 0.9988 at
    12 cells, 0.9997 at 24 (measured; the coarse ratios are that much low)."""
    for scene, cells, tol in (("straight_beam_inplane", 6, 1e-12),
                              ("twisted_beam_inplane", 12, 2e-3),
                              ("twisted_beam_inplane", 24, 5e-4)):
        m = _model(f"scenes/{scene}.toml", {"shell.element": "q3t_ans", "mesh.cells": cells})
        f = m.external.f.sum(0)
        assert abs(np.linalg.norm(f) - 1.0) < tol, (scene, cells, f)


def test_a_strip_of_too_many_cells_across_or_too_few_along_names_the_field():
    with pytest.raises(SceneError, match=r"mesh: aspect: 13653 cells across"):
        load_scene("scenes/straight_beam_inplane.toml", {"mesh.cells": 4096, "mesh.aspect": 100})
    # 90 degrees in one cell would fold its triangles over (they then face opposite ways)
    with pytest.raises(SceneError, match=r"mesh: cells: 1 cells turn by 90 degrees"):
        load_scene("scenes/twisted_beam_inplane.toml", {"mesh.cells": 1})
    load_scene("scenes/twisted_beam_inplane.toml", {"mesh.cells": 2})  # 45 degrees each


def test_study_levels_follow_the_mesh_kind():
    with pytest.raises(SceneError, match=r"study\.cells"):
        load_scene("scenes/convergence.toml", {"study.cells": [4, 8]})
    with pytest.raises(SceneError, match=r"study\.edge_lengths"):
        load_scene("scenes/scordelis_lo.toml", {"study.edge_lengths": [1.0]})


def test_small_strain_is_only_elastic():
    with pytest.raises(SceneError, match="yield_stress"):
        load_scene("scenes/cantilever.toml", {"material.model": "linear_elastic",
                                              "material.yield_stress": 1e8})


def test_every_load_kind_tells_the_page_what_load_scale_multiplies():
    """The page's load slider shows each load's magnitude in its unit; a surface load is one
    of them (its missing unit once broke the viewer's frames of the roof)."""
    sim = Simulation.from_scene(load_scene("scenes/scordelis_lo.toml", {
        "mesh.cells": 2, "loads": [
            {"kind": "surface", "vector": [0.0, 0.0, -90.0]},
            {"kind": "pressure", "value": -5.0},
            {"kind": "point", "vector": [3.0, 4.0, 0.0], "point": [0.0, 0.0, 25.0]}]}))
    assert sim.scaled()["load_scale"] == [
        {"what": "surface 0", "unit": "Pa", "value": 90.0},
        {"what": "pressure 1", "unit": "Pa", "value": -5.0},
        {"what": "point 2", "unit": "N", "value": 5.0}]


def test_a_patch_run_gets_an_estimate_not_an_error(tmp_path):
    """The service's error estimate of a finished run reads its edge length from the run's
    scene: a patch refined by cells has none, which is no estimate, not an error."""
    from server.estimate import EstimateCache
    from server.records import Run

    d = tmp_path / "roof-1"
    d.mkdir()
    (d / "scene.toml").write_text(open("scenes/scordelis_lo.toml").read())
    run = Run("roof-1", "scordelis_lo", "q3t", {}, 0.0, state="finished")
    est = EstimateCache(tmp_path).get(run)
    assert est["reason"] != "error" and "no study" in est["text"], est

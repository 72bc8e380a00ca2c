"""Tools from triangle meshes (sim.tools.meshtool, the GRID primitive of sim.tools.grid): the
smoothed distance's derivatives, its accuracy against the analytic tool it tessellates, the
cache, and the meshes it refuses.

The test tool is a small punch (radius 6 mm, nose rounding 3 mm, 10 mm tall) tessellated with
chords within 20 um of the surface and sampled at 0.5 mm: a few seconds."""

import numpy as np
import pytest
import trimesh

from sim.tools import meshtool
from sim.tools.builders import moved, punch
from sim.tools.evaluate import sdf_distance, sdf_eval, sdf_world
from sim.tools.meshtool import MeshOptions, MeshToolError, mesh_program, read_surface
from sim.tools.pose import rotation
from sim.tools.program import parse, validate
from sim.tools.surface import chordal_mesh, tool_mesh

CHORD = 2e-5
PUNCH = punch(0.006, 0.01, 0.003)


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("Q3T_CACHE", str(tmp_path / "cache"))
    meshtool._program.cache_clear()


@pytest.fixture(scope="module")
def punch_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("mesh") / "punch.stl"
    trimesh.Trimesh(*chordal_mesh(PUNCH, CHORD)).export(path)
    return path


@pytest.fixture(scope="module")
def grid_punch(punch_file, tmp_path_factory):
    import os
    os.environ["Q3T_CACHE"] = str(tmp_path_factory.mktemp("cache"))
    try:
        return meshtool._program(str(punch_file), meshtool._digest(punch_file), MeshOptions())
    finally:
        del os.environ["Q3T_CACHE"]


def _near(prog, n, lo, hi, seed=7):
    """Points whose analytic distance lies in [lo, hi] (m): where contact happens."""
    rng = np.random.default_rng(seed)
    X = rng.uniform([-0.008, -0.008, -0.002], [0.008, 0.008, 0.012], (20 * n, 3))
    d = sdf_distance(prog, X)
    return X[(d > lo) & (d < hi)][:n]


def test_distance_within_the_chord_of_the_analytic_tool(grid_punch):
    """The mesh's chords lie inside the convex punch by up to CHORD, but its vertices lie on
    the punch, and the samples are the distance to the surface through them (the facets' sag
    put back), so what is left is the tricubic spline's own error: largest where a 3 mm
    rounding meets the side or a flat (the curvature jumps within a spacing of 0.5 mm),
    measured 3.8 um, median 0.6 um (sampling the facets: 17 um, median 7.8 um). Bound 5 um,
    median 1 um."""
    X = _near(PUNCH, 2000, -1e-4, 1e-3)
    d0, g0, _ = sdf_eval(PUNCH, X)
    d1, g1, _ = sdf_eval(grid_punch, X)
    assert np.abs(d1 - d0).max() < 5e-6 and np.median(np.abs(d1 - d0)) < 1e-6
    # the smoothed normal follows the surface's to within the facets' angle (2 acos(1 - c / r)
    # = 0.23 rad on the 3 mm rounding at 20 um) -- it is smoother than the facets, not exact
    assert np.linalg.norm(g1 - g0, axis=1).max() < 0.12


def test_fd_gradient_and_hessian_of_the_spline(grid_punch):
    """The B-spline is C2 and piecewise polynomial (cells of 0.5 mm): central differences with
    h = 1e-7 m have truncation error h^2 |s'''| ~ 1e-14 / (0.5e-3)^3 * |d| ~ 1e-4 relative...
    far below the tolerance; round-off eps |g| / h = 2e-9 1/m. Hessian entries are O(1 / r) =
    300 1/m at most; tolerance 1e-6 on g and 1e-3 1/m + 1e-5 |H| on H, as tests/unit/test_sdf."""
    X = _near(PUNCH, 300, -2e-4, 1e-3)
    d, g, H = sdf_eval(grid_punch, X)
    h = 1e-7
    for i in range(3):
        e = np.zeros(3)
        e[i] = h
        dp, gp, _ = sdf_eval(grid_punch, X + e)
        dm, gm, _ = sdf_eval(grid_punch, X - e)
        np.testing.assert_allclose(g[:, i], (dp - dm) / (2 * h), atol=1e-6, rtol=0)
        err = np.abs(H[:, :, i] - (gp - gm) / (2 * h))
        assert (err <= 1e-3 + 1e-5 * np.abs(H[:, :, i])).all(), err.max()


def test_placed_like_any_shape(grid_punch):
    """A frame moves the grid like a primitive: g = R g_local, H = R H_local R^T."""
    R = rotation([1.0, -0.5, 0.2], 0.8)
    t = np.array([0.01, -0.02, 0.003])
    X = _near(PUNCH, 50, -1e-4, 1e-3)
    d, g, H = sdf_eval(grid_punch, X)
    W = X @ R.T + t
    dw, gw, Hw = sdf_eval(moved(grid_punch, R, t), W)
    np.testing.assert_allclose(dw, d, atol=1e-12)
    np.testing.assert_allclose(gw, g @ R.T, atol=1e-10)
    dp, gp, Hp = sdf_world(grid_punch, R, t, W)
    np.testing.assert_allclose(Hp, np.einsum("ij,njk,lk->nil", R, H, R), atol=1e-6)


def test_far_points_keep_the_sign_and_push_out(grid_punch):
    """Beyond the sampled band (deep inside, far outside, outside the grid's box) the value is
    a stand-in, but it has the analytic sign and points away from the tool."""
    X = np.array([[0.0, 0.0, 0.005], [0.0, 0.0, -0.02], [0.3, 0.1, 0.0], [0.0, 0.012, 0.005]])
    d0 = sdf_distance(PUNCH, X)
    d, g, H = sdf_eval(grid_punch, X)
    assert np.all(np.sign(d) == np.sign(d0)) and np.isfinite(H).all()
    assert g[1, 2] < 0 and g[2, 0] > 0 and g[3, 1] > 0


def test_display_mesh_and_bounds(grid_punch):
    node = parse(grid_punch)
    # the punch's box [-6, 6]^2 x [0, 10] mm with one brick (3 mm) of far field around it
    assert node[0] == "grid"
    V, _ = chordal_mesh(PUNCH, CHORD)
    assert np.all(node[1] <= V.min(0) - 0.0029) and np.all(node[2] >= V.max(0) + 0.0029)
    V, F = tool_mesh(grid_punch)
    # closed as marching tetrahedra built it: where the level set passes through a display
    # grid node the vertices on that node's edges coincide, and merging them (trimesh's
    # default processing) would pinch the surface there
    assert trimesh.Trimesh(V, F, process=False).is_watertight
    assert np.abs(sdf_distance(PUNCH, V)).max() < 1e-4  # a 64-cell display grid's facets


def test_program_validation_refuses_a_bad_grid(grid_punch):
    validate(grid_punch)
    bad = grid_punch.copy()
    bad[2 + 2 + 10] = 1e9  # the first table entry names a brick that is not stored
    with pytest.raises(ValueError, match="GRID"):
        validate(bad)
    bad = grid_punch.copy()
    bad[2 + 2 + 8] += 1  # one more brick than stored
    with pytest.raises(ValueError, match="GRID record \\(sizes\\)"):
        validate(bad)


def _refuse(*args):
    raise RuntimeError("sampled again")


def test_cached_by_content(punch_file, tmp_path, monkeypatch):
    """A second preparation of the same file reads the cache: no sampling."""
    first = mesh_program(punch_file, MeshOptions(spacing=1e-3))
    assert len(list((tmp_path / "cache" / "meshtools").glob("*.npy"))) == 1
    meshtool._program.cache_clear()
    monkeypatch.setattr(meshtool, "grid_params", _refuse)
    np.testing.assert_array_equal(mesh_program(punch_file, MeshOptions(spacing=1e-3)), first)
    other = tmp_path / "moved.stl"
    m = trimesh.load(punch_file)
    m.apply_translation([0.001, 0, 0])
    m.export(other)
    with pytest.raises(RuntimeError, match="sampled again"):
        mesh_program(other, MeshOptions(spacing=1e-3))  # another content: another entry


def test_open_surface_takes_its_side(tmp_path):
    """An open, consistently wound patch: the tool lies behind its normals (flip: in front)."""
    V = np.array([[-0.01, -0.01, 0], [0.01, -0.01, 0], [0.01, 0.01, 0], [-0.01, 0.01, 0.0]])
    F = np.array([[0, 1, 2], [0, 2, 3]])
    path = tmp_path / "patch.obj"
    trimesh.Trimesh(V, F).export(path)
    X = np.array([[0.0, 0.0, 0.001], [0.002, 0.001, -0.0005]])
    for flip, sign in ((False, 1.0), (True, -1.0)):
        d, g, _ = sdf_eval(mesh_program(path, MeshOptions(open=True, flip=flip)), X)
        np.testing.assert_allclose(d, sign * np.array([0.001, -0.0005]), atol=1e-9)
        np.testing.assert_allclose(g[:, 2], sign, atol=1e-9)
    with pytest.raises(MeshToolError, match="open: 4 boundary edges"):
        read_surface(path, MeshOptions())


def _write(tmp_path, name, V, F):
    path = tmp_path / name
    trimesh.Trimesh(V, F, process=False).export(path)
    return path


def _bad_meshes(tmp_path):
    box = trimesh.creation.box([0.02, 0.02, 0.02])
    two = trimesh.util.concatenate([box, box.copy().apply_translation([0.01, 0.0, 0.0])])
    flat = box.copy()
    V, F = np.asarray(flat.vertices), np.asarray(flat.faces)
    a, b, c = F[0]
    V = np.vstack([V, 0.5 * (V[a] + V[b])])  # a point on an edge: [a, b, n] has no area
    n = len(V) - 1
    F = np.vstack([F[1:], [[a, b, n], [a, n, c], [n, b, c]]])
    text = tmp_path / "notes.stl"
    text.write_text("this is not a mesh\n")
    return {
        "not a mesh": (text, 1.0, "not a readable mesh|no triangles"),
        "open": (_write(tmp_path, "open.stl", box.vertices, box.faces[2:]), 1.0, "open: "),
        "self-intersecting": (_write(tmp_path, "two.stl", two.vertices, two.faces), 1.0,
                              "self-intersecting"),
        "degenerate": (_write(tmp_path, "flat.obj", V, F), 1.0, "degenerate"),
        "absurd size": (_write(tmp_path, "huge.stl", box.vertices, box.faces), 1000.0,
                        "absurd size"),
    }


@pytest.mark.parametrize("case", ["not a mesh", "open", "self-intersecting", "degenerate",
                                  "absurd size"])
def test_bad_meshes_are_refused_naming_the_problem(tmp_path, case):
    path, scale, match = _bad_meshes(tmp_path)[case]
    with pytest.raises(MeshToolError, match=match):
        read_surface(path, MeshOptions(scale=scale))


def _zero_set_error(V, F, spacing, P):
    """The prepared tool's distance at points P on the surface it was tessellated from."""
    from sim.tools.program import OP_GRID, program, record

    return sdf_distance(program(record(OP_GRID, meshtool.grid_params(V, F, spacing)[0])), P)


def _facets_only(monkeypatch):
    monkeypatch.setattr(meshtool, "facet_sag", lambda V, F: np.zeros((len(F), 3)))


def test_the_surface_through_the_vertices_of_a_sphere_and_a_cylinder(monkeypatch):
    """General tessellations (trimesh's icosphere, r = 10 mm, 5,120 triangles; its cylinder,
    r = 10 mm, 128 sections, caps at sharp edges), not our chordal meshes: the prepared
    distance at points on the analytic surface. Sampled at the flat facets it is the facets'
    sag, up to 11 um (sphere) and 3 um (cylinder); with the sag put back what is left is the
    tricubic spline's own error on a curved distance at h = 0.5 mm (measured 0.07 and 0.04 um).
    Bound 0.2 um, and at least 20x better than the facets' (the cylinder's band stays 2 h from
    the sharp rims, which the spline rounds)."""
    rng = np.random.default_rng(3)
    u = rng.normal(size=(2000, 3))
    sphere = 0.01 * u / np.linalg.norm(u, axis=1)[:, None]
    t, z = rng.uniform(0.0, 2.0 * np.pi, 2000), rng.uniform(-0.008, 0.008, 2000)
    side = np.stack([0.01 * np.cos(t), 0.01 * np.sin(t), z], 1)
    cases = [(trimesh.creation.icosphere(4, radius=0.01), sphere),
             (trimesh.creation.cylinder(radius=0.01, height=0.02, sections=128), side)]
    through = [np.abs(_zero_set_error(m.vertices, m.faces, 5e-4, P)).max() for m, P in cases]
    _facets_only(monkeypatch)
    facets = [np.abs(_zero_set_error(m.vertices, m.faces, 5e-4, P)).max() for m, P in cases]
    assert facets[0] > 5e-6 and facets[1] > 1e-6  # what there is to put back
    for good, bad in zip(through, facets, strict=True):
        assert good < 2e-7 and good < bad / 20, (through, facets)


def test_flat_faces_and_sharp_edges_are_unchanged(monkeypatch):
    """A box (flat faces, 90-degree edges, subdivided: 48 triangles) gets no sag: its grid is
    the facets' to the bit. The blank holder's tessellation (a flat face meeting a 1 mm
    rounding tangentially) keeps its flat face exactly flat: no sag on any triangle of it."""
    box = trimesh.creation.box([0.01, 0.02, 0.03]).subdivide()
    assert not meshtool.facet_sag(box.vertices, box.faces).any()
    through = meshtool.grid_params(box.vertices, box.faces, 1e-3)[0]
    from sim.tools.builders import blank_holder

    V, F = chordal_mesh(blank_holder(0.0227, 0.045, 0.01, 0.001), 1e-5)
    on_face = np.all(np.abs(V[F][:, :, 2] - V[:, 2].min()) < 1e-12, axis=1)
    sag = meshtool.facet_sag(V, F)
    assert on_face.sum() > 100 and not sag[on_face].any()
    assert np.abs(sag[~on_face]).max() > 1e-6  # the rounding's facets do get their sag
    _facets_only(monkeypatch)
    np.testing.assert_array_equal(meshtool.grid_params(box.vertices, box.faces, 1e-3)[0], through)

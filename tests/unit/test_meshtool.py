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
    """The mesh's chords lie inside the convex punch by up to CHORD; the spline of the mesh's
    distance then smooths its facets (edges of about 1 mm, a few spacings wide), which moves it
    by a fraction of that. Bound: CHORD plus 5 um (the spline's O(h^4) error is far below)."""
    X = _near(PUNCH, 2000, -1e-4, 1e-3)
    d0, g0, _ = sdf_eval(PUNCH, X)
    d1, g1, _ = sdf_eval(grid_punch, X)
    assert np.abs(d1 - d0).max() < CHORD + 5e-6
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
    assert trimesh.Trimesh(V, F).is_watertight
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

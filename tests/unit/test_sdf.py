"""Tool SDF programs (sim.tools: program, evaluate, builders) and their display meshes (surface).

Length scale of the tools below: 1e-2 .. 1e-1 m, smallest rounding radius 2 mm.
Finite differences are central with step FD_H = 1e-7 m:
* d -> g: truncation h^2 / 6 |d'''| with |d'''| <~ 1 / L^2 for points at L >~ 0.1 mm from a
  centre of curvature gives < 1e-7; round-off eps |d| / h ~ 2e-16 * 0.1 / 1e-7 = 2e-10.
  Tolerance 1e-6 on the (unit) gradient.
* g -> H: truncation h^2 / 6 |g'''| ~ h^2 / L^3 relative to |H| ~ 1 / L gives h^2 / L^2
  (< 1e-6 for L > 0.1 mm), round-off eps |g| / h = 2e-9 1/m. Tolerance 1e-3 1/m + 1e-5 |H|.
Random points land within h of a feature-region boundary (where H jumps) with probability
~1e-6 per point; the seeds are fixed.
"""

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from sim.tools.builders import (
    blank_holder,
    box,
    die_ring,
    extruded_polygon,
    intersect,
    moved,
    plane,
    punch,
    revolved,
    rounded_box,
    star,
    star_die,
    subtract,
    union,
)
from sim.tools.evaluate import sdf_distance, sdf_eval, sdf_world, sdf_world_distance
from sim.tools.polygon import rounded_polygon
from sim.tools.pose import rotation, to_local, to_world_derivatives, transform
from sim.tools.program import parse, validate
from sim.tools.surface import tool_mesh

FD_H = 1e-7
RNG_SEED = 1234


def _tools():
    return {
        "plane": plane([0.01, -0.02, 0.005], [0.3, -0.2, 1.0]),
        "box": box([0.04, 0.03, 0.02], center=[0.01, 0.0, -0.005]),
        "rounded_box": rounded_box([0.04, 0.03, 0.02], 0.006),
        "punch": punch(0.04, 0.06, 0.006),
        "die_ring": die_ring(0.043, 0.09, 0.03, 0.005),
        "blank_holder": blank_holder(0.045, 0.09, 0.02, 0.002),
        "revolved": revolved(0.01, 0.05, -0.02, 0.03, 0.004),
        "polygon": extruded_polygon(
            [[0.0, 0.0], [0.06, 0.0], [0.06, 0.04], [0.03, 0.015], [0.0, 0.04]],
            -0.01, 0.02, 0.004, 0.002),
        "polygon_reflex": extruded_polygon(
            [[0.0, 0.0], [0.06, 0.0], [0.06, 0.04], [0.03, 0.015], [0.0, 0.04]],
            -0.01, 0.02, 0.004, 0.002, reflex_radius=0.005),
        "star": star(5, 0.05, 0.025, 0.04, corner_radius=0.004, edge_radius=0.003),
        "star_die": star_die(5, 0.05, 0.025, 0.03, 0.005, corner_radius=0.003),
        "union_smooth": union(punch(0.03, 0.05, 0.004),
                              rounded_box([0.02, 0.02, 0.01], 0.003, [0.03, 0, 0.05]),
                              blend=0.006),
        "subtract_smooth": subtract(rounded_box([0.05, 0.05, 0.015], 0.004),
                                    punch(0.025, 0.05, 0.004), blend=0.004),
        "intersect": intersect(box([0.04, 0.04, 0.04]), revolved(0, 0.05, -1, 1)),
        "moved": moved(star(4, 0.04, 0.02, 0.03, 0.004, 0.002),
                       rotation([1.0, 2.0, 0.5], 0.7), [0.01, -0.02, 0.03]),
    }


TOOLS = _tools()


def _sample(prog, n_surface=150, n_box=100, seed=RNG_SEED):
    """Points near the surface (mesh vertices jittered in 3-D: faces, edges, corners, inside
    and outside) and random points in the bounding box."""
    rng = np.random.default_rng(seed)
    V, _ = tool_mesh(prog, n_segments=24, n_arc=6, resolution=24, plane_size=0.1)
    V = V[rng.choice(len(V), size=min(n_surface, len(V)), replace=False)]
    P = V + rng.normal(scale=2e-3, size=V.shape)
    lo, hi = V.min(0) - 0.01, V.max(0) + 0.01
    return np.concatenate([P, rng.uniform(lo, hi, size=(n_box, 3))])


def _fd(fun, X, h=FD_H):
    d0, g0, H0 = fun(X)
    g_fd = np.empty_like(g0)
    H_fd = np.empty_like(H0)
    for i in range(3):
        e = np.zeros(3)
        e[i] = h
        dp, gp, _ = fun(X + e)
        dm, gm, _ = fun(X - e)
        g_fd[:, i] = (dp - dm) / (2 * h)
        H_fd[:, :, i] = (gp - gm) / (2 * h)
    return d0, g0, H0, g_fd, H_fd


def _assert_fd(fun, X):
    d, g, H, g_fd, H_fd = _fd(fun, X)
    assert np.all(np.isfinite(d)) and np.all(np.isfinite(g)) and np.all(np.isfinite(H))
    np.testing.assert_allclose(g, g_fd, atol=1e-6, rtol=0)
    err = np.abs(H - H_fd).max(axis=(1, 2))
    tol = 1e-3 + 1e-5 * np.abs(H).max(axis=(1, 2))
    assert np.all(err <= tol), (np.max(err / tol), X[np.argmax(err / tol)])
    np.testing.assert_allclose(H, np.transpose(H, (0, 2, 1)), atol=1e-9)
    return d, g, H


@pytest.mark.parametrize("name", list(TOOLS))
def test_fd_gradient_and_hessian(name):
    prog = TOOLS[name]
    X = _sample(prog)
    d, g, H = _assert_fd(lambda Y: sdf_eval(prog, Y), X)
    if name != "plane":
        assert (d > 0).sum() > 20 and (d < 0).sum() > 20  # both sides covered
    if name not in ("plane", "box"):
        # curved regions (rounded edges, corners, fillets) are covered too
        assert (np.abs(H).max(axis=(1, 2)) > 1.0).sum() > 20
    # the value-only kernel agrees with the full one
    np.testing.assert_array_equal(sdf_distance(prog, X), d)


@pytest.mark.parametrize("name", ["rounded_box", "punch", "star_die", "union_smooth"])
def test_fd_through_world_pose(name):
    prog = TOOLS[name]
    R = rotation([0.3, -1.0, 0.4], 1.1)
    t = np.array([0.02, -0.01, 0.05])
    X = transform(_sample(prog, seed=7), R, t)
    d, g, H = _assert_fd(lambda Y: sdf_world(prog, R, t, Y), X)
    dl, gl, Hl = sdf_eval(prog, to_local(X, R, t))
    np.testing.assert_allclose(d, dl, atol=1e-15)
    gw, Hw = to_world_derivatives(gl, Hl, R)
    np.testing.assert_allclose(g, gw, atol=1e-13)
    np.testing.assert_allclose(H, Hw, atol=1e-9 * (1 + np.abs(H).max()))
    np.testing.assert_array_equal(sdf_world_distance(prog, R, t, X), d)


@pytest.mark.parametrize("name", [n for n in TOOLS if n not in
                                  ("union_smooth", "subtract_smooth")])
def test_unit_gradient_for_exact_primitives(name):
    # exact distances (and hard min/max of them) have |g| = 1 everywhere, medial axis included
    prog = TOOLS[name]
    _, g, _ = sdf_eval(prog, _sample(prog, seed=3))
    np.testing.assert_allclose(np.linalg.norm(g, axis=1), 1.0, atol=1e-12)


def _revolve_points(rho, z, theta):
    return np.stack([rho * np.cos(theta), rho * np.sin(theta), z], axis=1)


def test_exact_punch_nose_torus_and_faces():
    R, height, re = 0.04, 0.06, 0.006
    prog = punch(R, height, re)
    rng = np.random.default_rng(0)
    n = 200
    phi = rng.uniform(-0.5 * np.pi, 0.0, n)  # outer-lower quadrant of the nose torus
    delta = rng.uniform(-0.9 * re, 3 * re, n)
    theta = rng.uniform(0, 2 * np.pi, n)
    X = _revolve_points(R - re + (re + delta) * np.cos(phi), re + (re + delta) * np.sin(phi),
                        theta)
    d, g, _ = sdf_eval(prog, X)
    np.testing.assert_allclose(d, delta, atol=1e-15)
    e_r = np.stack([np.cos(theta), np.sin(theta), 0 * theta], axis=1)
    g_exp = np.cos(phi)[:, None] * e_r + np.sin(phi)[:, None] * np.array([0, 0, 1.0])
    np.testing.assert_allclose(g, g_exp, atol=1e-12)
    # flat nose face, below (outside) and just above (inside) it
    rho = rng.uniform(0, R - re, n)
    dz = rng.uniform(-0.02, 0.9 * re, n)
    d, g, H = sdf_eval(prog, _revolve_points(rho, dz, theta))
    np.testing.assert_allclose(d, -dz, atol=1e-15)
    np.testing.assert_allclose(g, np.tile([0, 0, -1.0], (n, 1)), atol=0)
    # cylindrical wall at mid height
    delta = rng.uniform(-0.01, 0.02, n)
    d, _, H = sdf_eval(prog, _revolve_points(R + delta, np.full(n, 0.5 * height), theta))
    np.testing.assert_allclose(d, delta, atol=1e-15)
    # Hessian of the wall distance = e_theta e_theta^T / rho
    e_t = np.stack([-np.sin(theta), np.cos(theta), 0 * theta], axis=1)
    np.testing.assert_allclose(H, e_t[:, :, None] * e_t[:, None, :] / (R + delta)[:, None, None],
                               rtol=1e-12, atol=1e-9)


def test_exact_die_shoulder():
    Ro, Rout, h, r = 0.043, 0.09, 0.03, 0.005
    prog = die_ring(Ro, Rout, h, r)
    rng = np.random.default_rng(1)
    n = 200
    phi = rng.uniform(0.5 * np.pi, np.pi, n)  # inner-upper quadrant: the shoulder
    delta = rng.uniform(-0.9 * r, 3 * r, n)
    theta = rng.uniform(0, 2 * np.pi, n)
    X = _revolve_points(Ro + r + (r + delta) * np.cos(phi), -r + (r + delta) * np.sin(phi),
                        theta)
    d, g, H = sdf_eval(prog, X)
    np.testing.assert_allclose(d, delta, atol=1e-15)
    # opening wall and top face
    d, _, _ = sdf_eval(prog, _revolve_points(np.full(n, Ro - 0.004), np.full(n, -0.015),
                                             theta))
    np.testing.assert_allclose(d, 0.004, atol=1e-15)
    d, _, _ = sdf_eval(prog, _revolve_points(np.full(n, 0.07), np.full(n, 0.003), theta))
    np.testing.assert_allclose(d, 0.003, atol=1e-15)


def test_exact_box_corners_edges_faces():
    h = np.array([0.04, 0.03, 0.02])
    c = np.array([0.01, -0.02, 0.005])
    rng = np.random.default_rng(2)
    n = 100
    v = rng.uniform(0.05, 1, (n, 3)) * rng.choice([-1.0, 1.0], (n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    delta = rng.uniform(0, 0.02, n)
    # sharp box: outside a corner the distance is to the corner point
    corner = np.sign(v) * h
    d, _, _ = sdf_eval(box(h, c), c + corner + np.abs(v) * np.sign(v) * delta[:, None])
    np.testing.assert_allclose(d, delta, atol=1e-15)
    # rounded box: sphere octant around (h - r) at every corner, including inside
    r = 0.008
    delta = rng.uniform(-0.9 * r, 0.02, n)
    X = c + np.sign(v) * (h - r) + v * (r + delta)[:, None]
    d, g, _ = sdf_eval(rounded_box(h, r, c), X)
    np.testing.assert_allclose(d, delta, atol=1e-15)
    np.testing.assert_allclose(g, v, atol=1e-12)
    # inside, closest to the z faces
    X = c + np.stack([rng.uniform(-0.01, 0.01, n), rng.uniform(-0.01, 0.01, n),
                      rng.uniform(-0.015, 0.015, n)], axis=1)
    d, _, _ = sdf_eval(box(h, c), X)
    np.testing.assert_allclose(d, np.abs(X[:, 2] - c[2]) - h[2], atol=1e-15)


def test_exact_star_die_shoulder_and_punch_tip():
    n_pts, ro, ri, height, rs, rc = 5, 0.05, 0.025, 0.03, 0.005, 0.003
    prog = star_die(n_pts, ro, ri, height, rs, corner_radius=rc)
    C = parse(prog)[6]  # rounded outline of the opening: edges b_k -> a_{k+1}
    rng = np.random.default_rng(3)
    n = 200
    k = rng.integers(0, len(C), n)
    a, b = C[k, 6:8], C[(k + 1) % len(C), 4:6]
    e = (b - a) / np.linalg.norm(b - a, axis=1, keepdims=True)
    nrm = np.stack([e[:, 1], -e[:, 0]], axis=1)
    foot = a + rng.uniform(0.3, 0.7, n)[:, None] * (b - a)  # middle of an edge
    phi = rng.uniform(0.5 * np.pi, np.pi, n)
    delta = rng.uniform(-0.5 * rs, 0.5 * rs, n)
    w = rs + (rs + delta) * np.cos(phi)  # distance to the outline
    z = -rs + (rs + delta) * np.sin(phi)
    X = np.concatenate([foot + w[:, None] * nrm, z[:, None]], axis=1)
    d, _, _ = sdf_eval(prog, X)
    np.testing.assert_allclose(d, delta, atol=1e-15)
    # the wall next to a valley: an arc of radius max(rc, rs) about a centre in the plate
    v = C[1]
    assert v[3] == -1.0 and v[2] == rs
    ang = np.arctan2(*(0.5 * (v[4:6] + v[6:8]) - v[:2])[::-1]) + rng.uniform(-0.1, 0.1, n)
    delta = rng.uniform(-0.5 * rs, 0.5 * rs, n)  # > 0: in the opening, towards the centre
    X = np.stack([v[0] + (rs + delta) * np.cos(ang), v[1] + (rs + delta) * np.sin(ang),
                  np.full(n, -0.5 * height)], axis=1)
    d, _, _ = sdf_eval(prog, X)
    np.testing.assert_allclose(d, delta, atol=1e-15)
    # rounded star tip of a star punch: arc of radius rc about the inner tip vertex
    prog = star(n_pts, ro, ri, 0.04, corner_radius=rc)
    tip = parse(prog)[6][0]  # vertex 0 is a tip (angle 0)
    ang = rng.uniform(-0.2, 0.2, n)
    delta = rng.uniform(-0.5 * rc, 0.01, n)
    X = np.stack([tip[0] + (rc + delta) * np.cos(ang), tip[1] + (rc + delta) * np.sin(ang),
                  np.full(n, 0.02)], axis=1)
    d, _, _ = sdf_eval(prog, X)
    np.testing.assert_allclose(d, delta, atol=1e-15)


@pytest.mark.parametrize("name", ["punch", "die_ring", "star", "star_die", "rounded_box"])
def test_distance_matches_dense_surface_sampling(name):
    # independent check against 2e5 points sampled on a fine display mesh: for points outside,
    # d <= distance to any surface sample (up to the chord sag of the mesh, < 7e-6 m for
    # 256 segments at R = 90 mm) and d >= that distance minus the sample spacing (area
    # <~ 0.05 m^2 / 2e5 samples -> spacing <~ 1 mm)
    prog = TOOLS[name]
    mesh = trimesh.Trimesh(*tool_mesh(prog, n_segments=256, n_arc=32))
    S, _ = trimesh.sample.sample_surface(mesh, 200_000, seed=5)
    rng = np.random.default_rng(4)
    lo, hi = mesh.vertices.min(0) - 0.02, mesh.vertices.max(0) + 0.02
    X = rng.uniform(lo, hi, (400, 3))
    d = sdf_distance(prog, X)
    dv, _ = cKDTree(np.concatenate([S, mesh.vertices])).query(X)
    out = d > 0
    assert out.sum() > 100
    assert np.all(d[out] <= dv[out] + 1e-5)
    assert np.all(dv[out] - d[out] < 2e-3)


def test_smooth_union_bounds_and_hard_min_outside_blend():
    a, b = punch(0.03, 0.05, 0.004), rounded_box([0.02, 0.02, 0.01], 0.003, [0.03, 0, 0.05])
    k = 0.006
    X = _sample(union(a, b), seed=11)
    da, db = sdf_distance(a, X), sdf_distance(b, X)
    ds = sdf_distance(union(a, b, blend=k), X)
    dh = sdf_distance(union(a, b), X)
    np.testing.assert_array_equal(dh, np.minimum(da, db))
    assert np.all(ds <= dh + 1e-18) and np.all(ds >= dh - k / 6 - 1e-15)
    far = np.abs(da - db) >= k
    np.testing.assert_array_equal(ds[far], dh[far])
    # subtract and intersect are the hard max
    np.testing.assert_array_equal(sdf_distance(subtract(a, b), X), np.maximum(da, -db))
    np.testing.assert_array_equal(sdf_distance(intersect(a, b), X), np.maximum(da, db))


def test_medial_axis_values_are_finite():
    X = np.zeros((1, 3))
    cases = [
        (box([0.02, 0.02, 0.02]), np.zeros((1, 3))),  # centre: all six faces tie
        (punch(0.02, 0.1, 0.003), np.array([[0, 0, 0.05]])),  # on the axis, wall closest
        (die_ring(0.02, 0.05, 0.02, 0.003), np.array([[0, 0, -0.01]])),  # ring axis
        (revolved(0.0, 0.02, -0.01, 0.01, 0.0), np.array([[0.0, 0.0, 0.02]])),
        (star(5, 0.05, 0.025, 0.02), np.array([[0.05, 0.0, 0.01]])),  # on a tip vertex
        (star(5, 0.05, 0.025, 0.02), np.array([[0.0, 0.0, 0.01]])),  # star centre
        (union(box([0.01] * 3, [-0.02, 0, 0]), box([0.01] * 3, [0.02, 0, 0])), X),
    ]
    for prog, P in cases:
        d, g, H = sdf_eval(prog, P)
        assert np.all(np.isfinite(d)) and np.all(np.isfinite(g)) and np.all(np.isfinite(H))
        np.testing.assert_allclose(np.linalg.norm(g, axis=1), 1.0, atol=1e-12)
    # under the punch nose on the axis the Hessian is the smooth limit (0 on a flat face)
    d, g, H = sdf_eval(punch(0.02, 0.1, 0.003), np.array([[0.0, 0.0, -0.01]]))
    assert d[0] == pytest.approx(0.01) and np.all(H == 0.0)


def test_program_validation():
    p = punch(0.02, 0.05, 0.003)
    validate(p)
    bad = p.copy()
    bad[0] = 1.0
    with pytest.raises(ValueError):
        validate(bad)
    with pytest.raises(ValueError):
        sdf_eval(bad, np.zeros((1, 3)))
    with pytest.raises(ValueError):
        validate(p[:-1])
    with pytest.raises(ValueError):
        punch(0.02, 0.05, 0.03)  # edge radius larger than half the height
    with pytest.raises(ValueError):
        extruded_polygon([[0, 0], [1, 0], [0, 1]], 0, 1, 0.01, 0.02)  # edge > corner
    with pytest.raises(ValueError):
        star_die(5, 0.05, 0.025, 0.03, 0.005, width=0.008)  # narrower than 2 shoulders
    with pytest.raises(ValueError):
        star(5, 0.05, 0.025, 0.03, corner_radius=0.025)  # > inradius 22 mm: inverts
    tree = parse(moved(union(p, box([1, 1, 1]), 0.1), None, [0, 0, 1]))
    assert tree[0] == "frame" and tree[3][0] == "union" and tree[3][1] == 0.1
    # clockwise polygons are reoriented
    cw = extruded_polygon([[0, 0], [0, 1], [1, 1], [1, 0]], 0, 1)
    ccw = extruded_polygon([[0, 0], [1, 0], [1, 1], [0, 1]], 0, 1)
    X = np.random.default_rng(0).uniform(-1, 2, (50, 3))
    np.testing.assert_allclose(sdf_distance(cw, X), sdf_distance(ccw, X), atol=1e-15)


# ----------------------------------------------------------------------------------------------
# meshes
# ----------------------------------------------------------------------------------------------

CLOSED = [n for n in TOOLS if n != "plane"]


@pytest.mark.parametrize("name", list(TOOLS))
def test_mesh_on_zero_level_set_and_watertight(name):
    prog = TOOLS[name]
    V, F = tool_mesh(prog, plane_size=0.2, resolution=40)
    assert V.dtype == np.float64 and F.dtype == np.int64 and V.shape[1] == F.shape[1] == 3
    size = np.ptp(V, axis=0).max()
    d = sdf_distance(prog, V)
    # explicit meshes put vertices on the analytic surface: only float round-off (~1e-16 of
    # the size) is left. Implicit (CSG) meshes are Newton-projected (quadratic convergence
    # from an O(cell^2) start) to well below 1e-10 of the size.
    assert np.abs(d).max() <= 1e-10 * size
    mesh = trimesh.Trimesh(V, F)
    if name in CLOSED:
        assert mesh.is_watertight and mesh.is_winding_consistent
        assert mesh.volume > 0  # outward normals
        # normals agree with the SDF gradient at face centroids (display shading)
        _, g, _ = sdf_eval(prog, mesh.triangles_center)
        assert np.mean(np.einsum("ij,ij->i", g, mesh.face_normals) > 0.5) > 0.99
    else:
        assert not mesh.is_watertight  # a plane is shown as an open square


def test_mesh_volume_of_punch_matches_pappus():
    R, H, r = 0.04, 0.06, 0.006
    V, F = tool_mesh(punch(R, H, r), n_segments=720, n_arc=64)
    # profile = rectangle [0, R] x [0, H] minus two corner spandrels at rho = R
    moment_s = r * r * (R - r / 2) - np.pi * r * r * (R - r) / 4 - r**3 / 3
    exact = 2 * np.pi * (H * R * R / 2 - 2 * moment_s)
    # inscribed polygons (720 around, 64 per quarter arc) lose ~ (2 pi / 720)^2 / 6 ~ 1.3e-5
    assert trimesh.Trimesh(V, F).volume == pytest.approx(exact, rel=3e-5)


def test_mesh_world_pose_and_methods():
    prog = TOOLS["punch"]
    R = rotation([0, 1, 0], 0.4)
    t = np.array([0.1, 0.0, 0.2])
    V, F = tool_mesh(prog, R, t)
    np.testing.assert_allclose(sdf_world_distance(prog, R, t, V), 0.0, atol=1e-15)
    Vi, Fi = tool_mesh(prog, method="implicit", resolution=32)
    assert trimesh.Trimesh(Vi, Fi).is_watertight
    assert np.abs(sdf_distance(prog, Vi)).max() < 1e-12
    with pytest.raises(ValueError):
        tool_mesh(TOOLS["union_smooth"], method="explicit")


def test_mesh_of_wide_star_die_falls_back_to_implicit():
    # 80 mm around the star: the mitred outer outline would fold (beyond ~62 mm the edges
    # next to the valleys vanish), the SDF does not
    prog = star_die(5, 0.05, 0.025, 0.02, 0.004, width=0.08)
    with pytest.raises(ValueError):
        tool_mesh(prog, method="explicit")
    V, F = tool_mesh(prog, resolution=40)
    mesh = trimesh.Trimesh(V, F)
    assert mesh.is_watertight and mesh.volume > 0
    assert np.abs(sdf_distance(prog, V)).max() <= 1e-10 * np.ptp(V, axis=0).max()


def test_star_die_valleys_are_c1():
    """The cookie cutter's die: its valleys (reflex corners of the opening, where the band
    comes closest) are rounded arcs, so the gradient is continuous across their bisectors.
    With sharp valleys it jumped from (-0.746, -0.666) to (-0.864, -0.504) there."""
    prog = star_die(5, 0.04, 0.03, 0.02, 0.001, corner_radius=0.002)
    C = parse(prog)[6]
    valleys = C[C[:, 3] < 0]
    assert len(valleys) == 5 and np.all(valleys[:, 2] == 0.002)
    mid = 0.5 * (valleys[:, 4:6] + valleys[:, 6:8]) - valleys[:, :2]
    e = mid / np.linalg.norm(mid, axis=1, keepdims=True)  # from the centre to the arc middle
    tang = np.stack([-e[:, 1], e[:, 0]], axis=1)
    for gap in (1e-4, 1e-3):  # in the air, 0.1 and 1 mm from the valley, mid-height
        P = valleys[:, :2] + (valleys[:, 2:3] + gap) * e
        jumps = []
        for h in (1e-6, 1e-9):
            sides = [np.column_stack([P + sgn * h * tang, np.full(5, -0.01)]) for sgn in (1, -1)]
            (d1, g1, H1), (d2, g2, _) = (sdf_eval(prog, X) for X in sides)
            # reflex arc about a centre in the plate: d = |p - c| - rc
            np.testing.assert_allclose(d1, np.hypot(0.002 + gap, h) - 0.002, atol=1e-15)
            jump = np.linalg.norm(g1 - g2, axis=1)
            # C1: the jump is the curvature times 2h (|H| = 1 / (2 mm + gap)), no step
            assert np.all(jump <= 2 * h * np.linalg.norm(H1, 2, axis=(1, 2)) * (1 + 1e-6) + 1e-12)
            jumps.append(jump.max())
        assert jumps[1] < 1e-5
    # FD of gradient and Hessian around the valleys: the air in front of them, the wall, the
    # shoulder and the plate (points within 2 mm of the arcs, all heights near the top)
    rng = np.random.default_rng(8)
    k = rng.integers(0, 5, 400)
    ang = rng.uniform(-0.6, 0.6, 400)
    rad = valleys[k, 2] + rng.uniform(-1.5e-3, 2e-3, 400)
    dirs = np.stack([e[k, 0] * np.cos(ang) - e[k, 1] * np.sin(ang),
                     e[k, 0] * np.sin(ang) + e[k, 1] * np.cos(ang)], axis=1)
    X = np.column_stack([valleys[k, :2] + rad[:, None] * dirs, rng.uniform(-4e-3, 1e-3, 400)])
    d, _, H = _assert_fd(lambda Y: sdf_eval(prog, Y), X)
    assert (d > 0).sum() > 100 and (d < 0).sum() > 50
    assert (np.abs(H).max(axis=(1, 2)) > 100.0).sum() > 100  # the curved valley walls


def test_rounded_polygon_validation_and_orientation():
    sq = [[0, 0], [1, 0], [1, 1], [0, 1]]
    C = rounded_polygon(sq, [0.1, 0.2, 0.0, 0.3])
    Cr = rounded_polygon(sq[::-1], [0.3, 0.0, 0.2, 0.1])  # clockwise: radii follow
    assert np.allclose(np.sort(C[:, 2]), np.sort(Cr[:, 2]))
    assert np.all(C[:, 3] == 1.0)
    with pytest.raises(ValueError, match="overlap"):
        rounded_polygon(sq, 0.6)
    with pytest.raises(ValueError, match="valley_radius"):
        star_die(5, 0.04, 0.03, 0.02, 0.002, corner_radius=0.002, valley_radius=0.001)


def test_scene_shapes_csg_polygons_and_placement():
    """ShapeSpec: CSG, polygons and placed shapes from a scene file build the same program as
    the builders; bad shapes name the field."""
    from sim.scene.load import SceneError, load_scene
    from sim.tools.shapes import tool_program

    sc = load_scene("scenes/beam_forming.toml")
    die = sc.tools[0].shape
    assert die.kind == "subtract" and [s.kind for s in die.shapes] == ["box", "punch"]
    R = rotation([1, 0, 0], 0.5 * np.pi)
    ref = subtract(rounded_box([0.06, 0.02, 0.02], 0.0, [0, 0, -0.017]),
                   moved(punch(0.101, 0.04, 0.0), R, [0, 0.02, 0.08675]), 0.002)
    np.testing.assert_allclose(tool_program(die), ref, rtol=1e-15, atol=1e-15)
    # the cavity's lowest point sits 14.25 mm below the blank's mid-plane
    d, g, _ = sdf_eval(tool_program(die), np.array([[0.0, 0.0, -0.01425]]))
    assert abs(d[0]) < 1e-12 and np.allclose(g[0], [0, 0, 1], atol=1e-12)
    poly = {"kind": "polygon", "points": [[0, 0], [0.06, 0], [0.06, 0.04], [0.03, 0.015],
                                          [0, 0.04]], "height": 0.02, "corner_radius": 0.004,
            "reflex_radius": 0.005, "edge_radius": 0.002}
    o = {"tools.0.shape": {"kind": "union", "shapes": [poly, {"kind": "plane"}], "blend": 0.001}}
    prog = tool_program(load_scene("scenes/beam_forming.toml", o).tools[0].shape)
    ref = union(extruded_polygon(poly["points"], 0.0, 0.02, 0.004, 0.002, 0.005),
                plane([0, 0, 0], [0, 0, 1]), 0.001)
    np.testing.assert_array_equal(prog, ref)
    bad = [({"kind": "subtract", "shapes": [poly]}, "exactly two"),
           ({"kind": "union", "shapes": [poly]}, "at least two"),
           ({**poly, "corner_radius": 0.03, "edge_radius": 0.0}, "radii too large"),
           ({**poly, "points": [[0, 0], [1, 0]]}, "at least 3 points"),
           ({"kind": "box", "half_extents": [1, 1, 1], "shapes": [poly, poly]},
            "shapes: not a field of kind 'box'"),
           ({**poly, "rotation": [float("nan"), 0, 0]}, "finite"),
           ({"kind": "cone"}, "kind")]
    for shape, why in bad:
        with pytest.raises(SceneError, match=why) as err:
            load_scene("scenes/beam_forming.toml", {"tools.0.shape": shape})
        assert "tools.0.shape" in str(err.value)

"""Tools from triangle meshes: a surface file (STL, OBJ, PLY) checked and turned into a GRID
record (sim.tools.grid), a smooth signed distance the contact term evaluates like any other.

Preparation samples the signed distance at the nodes of a regular grid of spacing h near the
surface: libigl's AABB tree gives the nearest point on the triangles, the sign is that of the
angle-weighted pseudo-normal of the nearest feature (Baerentzen and Aanaes 2005), which is
exact for a closed, consistently wound surface and gives an open one its side. A CAD
tessellation's vertices lie on the surface and its flat facets inside a convex rounding (up to
the chordal error), so the distance is taken to the surface through the vertices: the facets'
less the surface's sag at the nearest point (facet_sag), and flat faces and sharp edges stay as
they are. The samples are turned into the coefficients of a tricubic B-spline by the local
quasi-interpolant c = P_x P_y P_z f, P = (-1, 8, -1) / 6 per axis, which reproduces cubics
(error O(h^4) on a smooth distance), so no global system is solved and only the bricks near
the surface are sampled. The B-spline is C2: the contact term's Hessian is that of the field
it integrates.

Why libigl: its signed distance (AABB tree, pseudo-normals, fast winding numbers) is a
well-kept C++ library with wheels; trimesh's proximity queries are pure Python and far slower.

The prepared record is cached by the file's SHA-256 and the preparation's parameters under
``$Q3T_CACHE`` (default ``~/.cache/q3t``) ``/meshtools``, written whole (a temporary file
renamed), and kept in memory for the process's last four tools.
"""

from __future__ import annotations

import functools
import hashlib
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim.text import figure, mm
from sim.tools.program import OP_GRID, program, record

BRICK = 6  # cells per brick side
BAND = 3  # the spline is exact (sampled) wherever |d| < BAND h, and beyond
FORMAT = 5  # of the cached records: bump when the layout or the sampling changes
MAX_NODES = 60_000_000  # grid nodes of a tool's box (a bool each): the memory bound
MAX_EXTENT = 5.0  # m: a tool larger than a press bed is a file in other units
MIN_EXTENT = 1e-4  # m
FLAT = 1e-10  # a triangle this much smaller than the median area is degenerate
# an edge whose faces' normals differ by more is a sharp edge of the tool, not a facet edge of a
# tessellated curve (a CAD exporter's angle tolerance is 5-20 degrees; tools' edges are ~90)
CREASE = math.radians(30.0)
# faces whose normals differ by less (1 - cos, 1e-4 rad) are coplanar: far above a float32
# STL's round-off (1e-7 relative), far below a tessellated curve's facet angle
COPLANAR = 5e-9
# _corner_normals and facet_sag. LONG: an edge this many times its fan's shortest is a straight
# line of the surface (a cylinder strip's generator, a flat's radius: a CAD strip's aspect ratio
# is tens, a smooth fan's edges differ by a factor of 2-3). BENT: a chord of the surface sags by
# about the tessellation's tolerance (at most 1.03 times it on the tests' meshes, the cup's
# tools, icospheres, UV spheres, cylinders), so an edge of a fit that sags this many times more
# is not a chord. STRAIGHT: the weight of the line's straightness against the neighbours'
# heights (both squared lengths of sag): near a constraint, and the 5 x 5 systems stay solvable
LONG, BENT, STRAIGHT = 8.0, 4.0, 100.0


class MeshToolError(ValueError):
    """A tool mesh that cannot be used; the message names the problem."""


@dataclass(frozen=True)
class MeshOptions:
    """How a mesh file becomes a tool: ``scale`` file units to m, ``spacing`` h (m) of the
    grid, ``open`` an open surface (the tool behind its faces), ``flip`` the tool in front."""

    scale: float = 1.0
    spacing: float = 5e-4
    open: bool = False
    flip: bool = False


def read_surface(path: str | Path, opts: MeshOptions,
                 check_size: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The surface V (n, 3) m, F (k, 3) of a file, checked (MeshToolError naming the problem);
    a closed one wound with outward normals, an open one flipped when ``flip``. Without
    ``check_size`` its size is not checked (a file whose scale is not known yet)."""
    from sim.geometry import trimesh as meshes

    try:
        m = meshes.load(path, opts.scale, merge=True)
    except ValueError as exc:
        raise MeshToolError(str(exc)) from None
    V, F = m.vertices, m.faces
    name = Path(path).name
    problem = ((check_size and _size_problem(V, opts)) or _triangle_problem(V, F)
               or _topology_problem(V, F, opts))
    if problem:
        raise MeshToolError(f"{name}: {problem}")
    if opts.open:
        return V, (F[:, ::-1] if opts.flip else F)
    if _volume(V, F) < 0:
        F = F[:, ::-1]
    problem = _self_intersection(V, F)
    if problem:
        raise MeshToolError(f"{name}: {problem}")
    return V, F


def _size_problem(V: np.ndarray, opts: MeshOptions) -> str | None:
    ext = float((V.max(0) - V.min(0)).max())
    if not MIN_EXTENT <= ext <= MAX_EXTENT:
        return (f"absurd size: {mm(ext)} across with scale = {opts.scale:g} (a tool "
                f"is {1e3 * MIN_EXTENT:g}-{1e3 * MAX_EXTENT:g} mm across; a file in mm needs "
                "scale = 0.001)")
    cells = (V.max(0) - V.min(0)) / opts.spacing + 2 * (BRICK + 2)
    if float(np.prod(cells)) > MAX_NODES:
        return (f"spacing {mm(opts.spacing)} is too fine for a tool {mm(ext)} "
                f"across (over {figure(MAX_NODES)} grid nodes): give a larger spacing")
    return None


def _triangle_problem(V: np.ndarray, F: np.ndarray) -> str | None:
    area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    flat = np.flatnonzero(area <= FLAT * np.median(area))
    if len(flat):
        return (f"{len(flat)} degenerate (zero-area) triangles (first: {flat[:5].tolist()})")
    return None


def _topology_problem(V: np.ndarray, F: np.ndarray, opts: MeshOptions) -> str | None:
    directed = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    _, inverse, count = np.unique(np.sort(directed, axis=1), axis=0, return_inverse=True,
                                  return_counts=True)
    if (count > 2).any():
        return f"{int((count > 2).sum())} edges shared by more than two triangles"
    forward = np.bincount(inverse.ravel(), weights=directed[:, 0] < directed[:, 1])
    if ((count == 2) & (forward != 1)).any():
        return (f"{int(((count == 2) & (forward != 1)).sum())} edges between triangles wound "
                "opposite ways (an inconsistent orientation)")
    if not opts.open and (count == 1).any():
        return (f"open: {int((count == 1).sum())} boundary edges, and the shape needs a closed "
                "surface (or set open = true: the tool lies behind the faces' normals)")
    return None


def _volume(V: np.ndarray, F: np.ndarray) -> float:
    return float(np.einsum("ij,ij->i", V[F[:, 0]], np.cross(V[F[:, 1]], V[F[:, 2]])).sum() / 6)


def _self_intersection(V: np.ndarray, F: np.ndarray) -> str | None:
    """A closed surface wound outward has winding number 0 just outside each face and 1 just
    inside; a part of it inside another part (an overlap, a fold) shows 1 or 2 there."""
    import igl

    N = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    N /= np.linalg.norm(N, axis=1)[:, None]
    # off each face by a hair: well inside the faces' neighbours, beyond round-off
    eps = 1e-6 * float((V.max(0) - V.min(0)).max())
    C = V[F].mean(1)
    Q = np.concatenate([C + eps * N, C - eps * N])
    w = igl.fast_winding_number(np.ascontiguousarray(V), np.ascontiguousarray(F), Q)
    bad = np.flatnonzero((np.abs(w[:len(F)]) > 0.5) | (np.abs(w[len(F):] - 1) > 0.5))
    if len(bad):
        return (f"self-intersecting: {len(bad)} triangles lie inside the tool's own material "
                f"(first: {bad[:5].tolist()})")
    return None


def grid_params(V: np.ndarray, F: np.ndarray, h: float) -> tuple[np.ndarray, dict]:
    """GRID record parameters (sim.tools.grid) of the surface V (n, 3), F (k, 3) at spacing h,
    and a report of what was sampled and stored."""
    t0 = time.perf_counter()
    B = BRICK
    L = B * h
    lo = V.min(0) - L  # one brick of far field around the surface
    nb = np.ceil((V.max(0) + L - lo) / L).astype(int)
    corners = np.stack(np.meshgrid(*[np.arange(n + 1) for n in nb], indexing="ij"), -1)
    far = _signed_distance(V, F, lo + L * corners.reshape(-1, 3)).reshape(nb + 1)
    # a brick holds a point with |d| < BAND h if a corner is within that plus half its diagonal
    reach = BAND * h + 0.5 * math.sqrt(3.0) * L
    near = np.abs(far) <= reach
    active = np.zeros(nb, bool)
    for a, b, c in np.ndindex(2, 2, 2):
        active |= near[a:a + nb[0], b:b + nb[1], c:c + nb[2]]
    bricks = np.argwhere(active)
    table = np.full(nb, -1.0)
    table[tuple(bricks.T)] = np.arange(len(bricks))
    coef, n_samples = _coefficients(V, F, lo, h, nb, bricks, facet_sag(V, F))
    head = [*lo, h, B, *nb, len(bricks), 0.0]
    params = np.concatenate([head, table.ravel(), far.ravel(), coef.ravel()])
    return params, {"triangles": len(F), "spacing": h, "bricks": len(bricks),
                    "samples": n_samples, "bytes": params.nbytes,
                    "seconds": round(time.perf_counter() - t0, 2)}


def _coefficients(V: np.ndarray, F: np.ndarray, lo: np.ndarray, h: float, nb: np.ndarray,
                  bricks: np.ndarray, sag: np.ndarray) -> tuple[np.ndarray, int]:
    """B-spline coefficients (n_bricks, B + 3, B + 3, B + 3) of the active bricks: the
    distance to the surface through the vertices (the facets' less their sag) sampled at the
    nodes their stencils and the prefilter reach (B + 5 per axis, global nodes I B - 2 ...),
    prefiltered per axis."""
    B = BRICK
    n = nb * B + 5  # nodes, shifted by 2
    need = np.zeros(n, bool)
    for I, J, K in bricks * B:
        need[I:I + B + 5, J:J + B + 5, K:K + B + 5] = True
    idx = np.flatnonzero(need)  # sorted: a brick's nodes are found by bisection
    del need
    vals = _signed_distance(V, F, lo + h * (np.stack(np.unravel_index(idx, n), -1) - 2), sag)
    off = np.arange(B + 5)
    ii = (bricks[:, 0, None] * B + off)[:, :, None, None]
    jj = (bricks[:, 1, None] * B + off)[:, None, :, None]
    kk = (bricks[:, 2, None] * B + off)[:, None, None, :]
    f = vals[np.searchsorted(idx, (ii * n[1] + jj) * n[2] + kk)]
    for axis in (1, 2, 3):
        f = _prefilter(f, axis)
    return f, len(idx)


def _prefilter(f: np.ndarray, axis: int) -> np.ndarray:
    """(-f[i-1] + 8 f[i] - f[i+1]) / 6 along ``axis``: the cubic B-spline quasi-interpolant."""
    a = np.moveaxis(f, axis, 0)
    return np.moveaxis((8.0 * a[1:-1] - a[:-2] - a[2:]) / 6.0, 0, axis)


def _signed_distance(V: np.ndarray, F: np.ndarray, P: np.ndarray,
                     sag: np.ndarray | None = None) -> np.ndarray:
    """Signed distance (> 0 in front of the faces) of points P (n, 3), in chunks (the nearest
    points and normals libigl also returns are 7 floats a point): the exact distance to the
    triangles, less the sag (facet_sag's coefficients, (k, 3)) of the curved surface at the
    nearest point when ``sag`` is given."""
    import igl

    V = np.ascontiguousarray(V, float)
    F = np.ascontiguousarray(F, np.int64)
    out = np.empty(len(P))
    chunk = 1 << 19
    for s in range(0, len(P), chunk):
        d, face, near, _ = igl.signed_distance(
            np.ascontiguousarray(P[s:s + chunk]), V, F,
            sign_type=igl.SIGNED_DISTANCE_TYPE_PSEUDONORMAL)
        if sag is not None:
            d = d - _sag_at(V, F, sag, face, near)
        out[s:s + chunk] = d
    return out


def facet_sag(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """How far the surface a CAD tessellation was made from lies in front of each facet: the
    coefficients (k, 3) of the quadratic sag(w) = c01 w0 w1 + c12 w1 w2 + c20 w2 w0 over each
    triangle's barycentric coordinates w, zero at its corners (the vertices lie on the surface).

    It is the offset of Phong tessellation (Boubekeur and Alexa 2008) with shape factor 1/2,
    c_ik = (v_i - v_k) . (n_i - n_k) / 2 from the corners' normals n, which is the sag of any
    quadric surface through the corners to leading order: a chordal tessellation's facets lie
    inside a convex rounding by up to the chordal error, and this puts them back. The corners'
    normals are what makes it exact where it must be:

    * a corner's normal is fitted to its vertex's neighbours (_corner_normals): exact on a
      quadric however lopsided the fan, as long as its neighbours decide the quadric (a rim
      vertex of an open surface has about four, all on one side, for five unknowns: its fit
      takes the ring beyond them too), and where a rounding meets a cylinder or a flat
      tangentially it is the straight side's, where an angle-weighted normal tilts by a
      quarter of the rounding's facet angle and bends a 10 mm edge by tens of micrometres;
    * only faces within CREASE of the corner's face count (its smooth side): a sharp edge keeps
      its faces' own normals, so it gets no sag and is not rounded;
    * a flat face (a connected set of coplanar faces whose vertices do not lie on two lines, as
      a strip of a cylinder or cone does) gets none: a holder's face stays exactly flat;
    * a corner whose fitted normal is further than CREASE from its face's (a cone's tip), and
      an edge that sags more than BENT times the tessellation's tolerance, get none: where the
      fit goes wrong the facets, exact at the vertices, are what is left."""
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    n /= np.linalg.norm(n, axis=1)[:, None]
    normal, tolerance = _corner_normals(V, F, n)
    P = V[F]
    coef = np.stack([0.5 * np.einsum("fj,fj->f", P[:, i] - P[:, j], normal[:, i] - normal[:, j])
                     for i, j in ((0, 1), (1, 2), (2, 0))], 1)
    coef[_flat_faces(V, F, n)] = 0.0
    # the safety net: an edge's sag at its middle is c / 4, and a chordal tessellation's edges
    # sag by its tolerance; one that sags BENT times more is not a chord of the surface but a
    # fit gone wrong (corners whose few neighbours a quadric interpolates with a tilt, as where
    # a long flat meets a rounding along a line), and the facet's edge, exact at its ends, is
    # kept straight. An edge's coefficient is the same in both its faces: no step between them
    coef[np.abs(coef) > 4.0 * BENT * tolerance] = 0.0
    return coef


def _corner_normals(V: np.ndarray, F: np.ndarray,
                    n: np.ndarray) -> tuple[np.ndarray, float]:
    """Each face's corners' normals (k, 3, 3), and the tessellation's tolerance (m: the sag of
    most of its short edges, 0 on a mesh of flats), fitted to the vertices of the faces around the
    corner's vertex within CREASE of the face's normal ``n`` (k, 3).

    First the plane through the vertex nearest them (total least squares) as a frame, then a
    quadric over it, h = g . x + x^T Q x / 2 (heights h over tangential x, least squares): the
    quadric takes up the curvature, so a fan of neighbours lopsided on a curved surface does
    not tilt the normal (g). A straight line of the surface through the vertex (a cylinder's
    generator, a radius of a flat: an edge LONG times the fan's shortest, of those the one
    most bent between its faces, as a strip's diagonal is not) decides what the neighbours
    leave open: of quadrics that fit alike the one straight along it. Where a rounding meets
    the line tangentially no quadric fits both; the free fit then bends the line by far more
    than the short edges' sag (BENT times), where it would tilt the normal by half the
    rounding's facet angle and move a 10 mm edge's middle by tens of micrometres. There the
    fit is one-sided, the neighbours on the line's side and across it, the line straight."""
    k = len(F)
    a, b, own = _fan(F, n)
    fitted, a = np.unique(a, return_inverse=True)  # the corners fitted, a indexes them
    m = len(fitted)
    corner_f = np.repeat(np.arange(k), 3)
    across = _across(F)
    v0 = V[F.ravel()[fitted[a]]]
    fb, kb = corner_f[b], b % 3
    # the two other vertices of b's face, and the cosine of the angle between the faces of
    # the edge to each (1 on a boundary)
    E = [V[F[fb, (kb + step) % 3]] - v0 for step in (1, 2)]
    other = [across[fb, kb], across[fb, (kb + 2) % 3]]
    bend = [np.where(g >= 0, np.einsum("ij,ij->i", n[fb], n[np.maximum(g, 0)]), 1.0)
            for g in other]

    def summed(w: np.ndarray, at: np.ndarray = a) -> np.ndarray:
        return np.bincount(at, weights=w, minlength=m)

    M = np.zeros((m, 3, 3))
    for i, j in ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)):
        M[:, i, j] = M[:, j, i] = sum(summed(e[:, i] * e[:, j]) for e in E)
    frame = np.linalg.eigh(M)[1]  # columns: the normal (least spread), two tangents
    normal, t1, t2 = frame[:, :, 0], frame[:, :, 1], frame[:, :, 2]

    shortest = np.full(m, np.inf)
    local = []  # per neighbour: length, height, the quadric's terms (x, y, x^2/2, xy, y^2/2)
    for e in E:
        x, y, h = (np.einsum("ij,ij->i", e, f[a]) for f in (t1, t2, normal))
        local.append((np.hypot(x, y), h, np.stack((x, y, 0.5 * x * x, x * y, 0.5 * y * y), 1)))
        np.minimum.at(shortest, a, local[-1][0])
    long = [length > LONG * shortest[a] for length, _, _ in local]
    straightest = np.full(m, np.inf)
    for lg, c in zip(long, bend, strict=True):
        np.minimum.at(straightest, a, np.where(lg, c, np.inf))
    S = np.zeros((m, 5, 5))  # the quadric's sag along the line (at its middle), squared
    line = np.zeros((m, 2))  # the line's direction
    for (length, _, phi), lg, c in zip(local, long, bend, strict=True):
        on = lg & (c == straightest[a])
        sag = np.where(on[:, None], phi[:, 2:] / 4, 0.0)
        for i in range(3):
            for j in range(3):
                S[:, 2 + i, 2 + j] += summed(sag[:, i] * sag[:, j])
        for i in range(2):
            line[:, i] += summed(np.where(on, phi[:, i] / length, 0.0))

    # a rim vertex's neighbours all lie on one side of it, about four for the quadric's five
    # terms: its fit takes the vertices one ring further out as well, unless a straight line
    # decides what they leave open (a strip's end: its further ring lies along the line)
    ring, ring_at = _second_ring(V, F, n, across, fitted, a, b, ~np.isfinite(straightest))
    x, y, h = (np.einsum("ij,ij->i", ring, f[ring_at]) for f in (t1, t2, normal))
    far = (np.hypot(x, y), h, np.stack((x, y, 0.5 * x * x, x * y, 0.5 * y * y), 1))

    def fit(keep: list[np.ndarray] | None, weight: float) -> np.ndarray:
        """The quadric (m, 5) fitted to the neighbours and the rim's further ring ``keep``
        (all), the line's sag weighted by ``weight``."""
        A = weight * S
        rhs = np.zeros((m, 5))
        for q, (at, (_, h, phi)) in enumerate([(a, lc) for lc in local] + [(ring_at, far)]):
            w = 1.0 if keep is None else keep[q].astype(float)
            for i in range(5):
                rhs[:, i] += summed(w * phi[:, i] * h, at)
                for j in range(5):
                    A[:, i, j] += summed(w * phi[:, i] * phi[:, j], at)
        # what neither the neighbours nor the line decide (a fan of four): the flattest
        Q = [2, 3, 4]
        # (1e-9 of the largest diagonal: far below any curvature the neighbours decide, and
        # lifts only the singular directions; 1e-300 where there are no neighbours at all)
        A[:, Q, Q] += 1e-300 + 1e-9 * A[:, Q, Q].max(axis=1)[:, None]
        return np.linalg.solve(A, rhs[:, :, None])[:, :, 0]

    # a weight 1e-4 of the neighbours': decides only what the neighbours leave open (a fan of
    # four on a cylinder), moving a determined fit by 1e-4 of its misfit at most
    free = fit(None, 1e-4)
    worst = np.zeros((2, m))  # the largest sag of a short and of a long edge at a corner
    for (_, _, phi), lg in zip(local, long, strict=True):
        sag = np.abs(np.einsum("ij,ij->i", phi[:, 2:], free[a, 2:])) / 4
        np.maximum.at(worst[0], a[~lg], sag[~lg])
        np.maximum.at(worst[1], a[lg], sag[lg])
    # the tessellation's tolerance: most short edges' sag (a rounding's, a cylinder's); a long
    # edge sags as much legitimately (a meridian at a sphere's pole, among tiny edges). The
    # 90th percentile: the largest short edges' sag, not the few bent ones at junctions
    curved = worst[0][worst[0] > 1e-12]
    tolerance = float(np.percentile(curved, 90)) if len(curved) else 0.0
    bent = worst[1] > BENT * np.maximum(worst[0], tolerance)
    g = free[:, :2]
    # the line's side: within 104.5 degrees of its direction (cos >= -0.25), the neighbours
    # ahead and beside it, not those behind it (the rounding a flat's radius runs away from)
    if bent.any():
        side = [np.einsum("ij,ij->i", phi[:, :2], line[a])
                >= -0.25 * length * np.linalg.norm(line[a], axis=1) for length, _, phi in local]
        side.append(np.ones(len(ring_at), bool))  # the further ring's corners have no line
        g[bent] = fit(side, STRAIGHT)[bent, :2]
    normal = normal - g[:, :1] * t1 - g[:, 1:] * t2
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    normal = normal[np.searchsorted(fitted, own)].reshape(k, 3, 3)
    normal *= np.sign(np.einsum("fij,fj->fi", normal, n))[:, :, None]
    # a smooth corner's normal lies among its fan's faces' normals, all within CREASE of the
    # face's: one further off is a fit the neighbours do not decide (a cone's tip, whose fan's
    # vertices all lie on lines through it), and the face's own normal gives no sag there
    off = np.einsum("fij,fj->fi", normal, n) < math.cos(CREASE)
    normal[off] = np.broadcast_to(n[:, None], normal.shape)[off]
    return normal, tolerance


def _second_ring(V: np.ndarray, F: np.ndarray, n: np.ndarray, across: np.ndarray,
                 fitted: np.ndarray, a: np.ndarray, b: np.ndarray,
                 wanted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each fitted corner (``fitted``, with its fan's pairs ``a``, ``b`` of
    :func:`_fan`) ``wanted`` at a rim vertex of an open surface: the vertices of the faces
    around its neighbours within CREASE of its face's normal ``n``, its neighbours and itself
    left out, as vectors (p, 3) from its vertex, and the fitted corner's index (p,) of each;
    ``across`` as :func:`_across` gives it."""
    rim = np.zeros(len(V), bool)
    f, j = np.nonzero(across < 0)
    rim[F[f, j]] = True
    rim[F[f, (j + 1) % 3]] = True
    vertex = F.ravel()[fitted]
    todo = np.flatnonzero(rim[vertex] & wanted)
    if not len(todo):
        return np.zeros((0, 3)), np.zeros(0, int)
    by_vertex = np.argsort(F.ravel(), kind="stable")
    vptr = np.concatenate([[0], np.cumsum(np.bincount(F.ravel(), minlength=len(V)))])
    by_corner = np.argsort(a, kind="stable")
    cptr = np.concatenate([[0], np.cumsum(np.bincount(a, minlength=len(fitted)))])
    vectors, at = [], []
    for i in todo:
        v = vertex[i]
        ring = np.setdiff1d(F[b[by_corner[cptr[i]:cptr[i + 1]]] // 3], [v])
        around = np.unique(np.concatenate([by_vertex[vptr[w]:vptr[w + 1]] // 3 for w in ring]))
        around = around[n[around] @ n[fitted[i] // 3] > math.cos(CREASE)]
        further = np.setdiff1d(F[around], np.append(ring, v))
        vectors.append(V[further] - V[v])
        at.append(np.full(len(further), i))
    return np.concatenate(vectors), np.concatenate(at)


def _fan(F: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pairs (a, b) of corners (3 f + j) at the same vertex whose faces' normals ``n`` are
    within CREASE (b's face is on a's smooth side), and the corner (3 k,) whose fit each corner
    takes: at a vertex without a sharp edge every corner has the same fan, so only the
    vertex's first corner is fitted."""
    corner_v = F.ravel()
    order = np.argsort(corner_v, kind="stable")
    counts = np.bincount(corner_v)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    per = counts[corner_v[order]]
    a = np.repeat(order, per)
    start = np.repeat(first[corner_v[order]] - np.cumsum(per) + per, per)
    b = order[np.arange(len(a)) + start]
    smooth = np.einsum("ij,ij->i", n[a // 3], n[b // 3]) > math.cos(CREASE)
    sharp = np.zeros(len(counts), bool)
    sharp[corner_v[a[~smooth]]] = True
    own = np.where(sharp[corner_v], np.arange(len(corner_v)), order[first[corner_v]])
    keep = smooth & (own[a] == a)
    return a[keep], b[keep], own


def _across(F: np.ndarray) -> np.ndarray:
    """The face (k, 3) across each triangle's edge j (its corners j and j + 1), -1 on a boundary."""
    k = len(F)
    directed = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    _, edge = np.unique(np.sort(directed, axis=1), axis=0, return_inverse=True)
    edge = edge.ravel()
    order = np.argsort(edge, kind="stable")
    same = np.flatnonzero(edge[order[1:]] == edge[order[:-1]])
    across = np.full(3 * k, -1)
    across[order[same]] = order[same + 1] % k
    across[order[same + 1]] = order[same] % k
    return across.reshape(3, k).T


def _flat_faces(V: np.ndarray, F: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Faces (bool, (k,)) of the tool's flat faces: connected sets of coplanar faces whose
    vertices are not on two lines (two triangles of a quad, a strip of a cylinder are)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    k = len(F)
    across = _across(F)
    f1 = np.repeat(np.arange(k), 3)[across.ravel() >= 0]
    f2 = across.ravel()[across.ravel() >= 0]
    coplanar = np.einsum("ij,ij->i", n[f1], n[f2]) > 1.0 - COPLANAR
    graph = coo_matrix((np.ones(int(coplanar.sum())), (f1[coplanar], f2[coplanar])),
                       shape=(k, k))
    _, label = connected_components(graph, directed=False)
    tol = 1e-6 * float((V.max(0) - V.min(0)).max())
    flat = np.zeros(k, bool)
    order = np.argsort(label, kind="stable")
    sizes = np.bincount(label)
    ends = np.cumsum(sizes)
    for region in np.flatnonzero(sizes >= 3):  # two triangles have at most 4 vertices
        faces = order[ends[region] - sizes[region]:ends[region]]
        points = V[np.unique(F[faces])]
        if len(points) > 4 and not _on_two_lines(points, tol):
            flat[faces] = True
    return flat


def _on_two_lines(P: np.ndarray, tol: float) -> bool:
    """Whether the points P (m >= 3, 3) lie on two straight lines (within tol): of any three
    of them two share a line, so one of the lines runs through two of the first three."""
    def off(Q: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        t = (b - a) / np.linalg.norm(b - a)
        return np.linalg.norm(np.cross(Q - a, t), axis=1) > tol

    for i, j in ((0, 1), (0, 2), (1, 2)):
        rest = P[off(P, P[i], P[j])]
        if len(rest) <= 2 or not off(rest, rest[0], rest[1]).any():
            return True
    return False


def _sag_at(V: np.ndarray, F: np.ndarray, coef: np.ndarray, face: np.ndarray,
            near: np.ndarray) -> np.ndarray:
    """facet_sag's sag at the points ``near`` (n, 3) on the faces ``face`` (n,)."""
    T = F[face]
    e1, e2, p = V[T[:, 1]] - V[T[:, 0]], V[T[:, 2]] - V[T[:, 0]], near - V[T[:, 0]]
    d11, d12, d22 = (np.einsum("ij,ij->i", x, y) for x, y in ((e1, e1), (e1, e2), (e2, e2)))
    p1, p2 = np.einsum("ij,ij->i", p, e1), np.einsum("ij,ij->i", p, e2)
    det = d11 * d22 - d12 * d12
    w1 = (d22 * p1 - d12 * p2) / det
    w2 = (d11 * p2 - d12 * p1) / det
    w0 = 1.0 - w1 - w2
    c = coef[face]
    return c[:, 0] * w0 * w1 + c[:, 1] * w1 * w2 + c[:, 2] * w2 * w0


def cache_dir() -> Path:
    return Path(os.environ.get("Q3T_CACHE") or Path.home() / ".cache" / "q3t") / "meshtools"


def _digest(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest() if Path(path).is_file() else ""


def _cached(digest: str, opts: MeshOptions) -> Path:
    key = hashlib.sha256(f"{FORMAT} {digest} {opts}".encode()).hexdigest()[:32]
    return cache_dir() / f"{key}.npy"


def mesh_program(path: str | Path, opts: MeshOptions) -> np.ndarray:
    """The SDF program of a mesh file's tool (cached by the file's content and ``opts``)."""
    return _program(str(path), _digest(path), opts)


@functools.lru_cache(maxsize=4)  # a worker's last few tools; each tens of MB
def _program(path: str, digest: str, opts: MeshOptions) -> np.ndarray:
    cached = _cached(digest, opts)
    if digest and cached.is_file():
        return program(record(OP_GRID, np.load(cached)))
    V, F = read_surface(path, opts)
    params, _ = grid_params(V, F, opts.spacing)
    cached.parent.mkdir(parents=True, exist_ok=True)
    tmp = cached.with_suffix(f".{os.getpid()}.tmp")
    with open(tmp, "wb") as fh:
        np.save(fh, params)
    os.replace(tmp, cached)
    return program(record(OP_GRID, params))

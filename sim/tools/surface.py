"""Triangle meshes of tool surfaces (the zero level set of an SDF program) for display.

``tool_mesh(prog)`` builds the surface explicitly when the program is a single primitive
(possibly wrapped in frames), with every vertex computed on the exact surface:

* REVOLVE: the 2-D (rho, z) outline of the rounded rectangle (arcs sampled with ``n_arc``
  segments per quarter circle) revolved with ``n_segments`` segments; a profile that reaches
  the axis closes with a pole vertex on each cap, so punches and rings are watertight.
* SWEEP (extruded polygon): the same outline, with rho replaced by offsets of the
  stored polygon (edges moved along their normals, convex corners as arcs of ``n_arc``
  segments, reflex corners mitred); prisms get flat caps by ear clipping. Watertight.
* RSWEEP (star die, polygons with rounded reflex corners): the same with offsets of the
  rounded outline (every arc's radius grows or shrinks with the offset).
* BOX: a subdivided cube surface mapped onto the rounded box by the closest-point
  projection onto the inner box plus the radius (flat faces stay flat, edges become
  cylinders, corners sphere octants). Watertight.
* PLANE: a square of side ``plane_size`` around the plane's point (open, not watertight).

Any CSG program (union / intersect / subtract, smooth or not) is meshed implicitly: marching
tetrahedra on a grid of ``resolution`` cells along the longest side of its bounding box
(Freudenthal split of each cube, consistent across cubes, so the result is closed where the
surface stays inside the grid). Each vertex is then moved onto the zero level set along its
own grid edge by bracketed root finding, so vertices stay distinct even on sharp CSG creases
(a Newton projection along g would collapse them there). Unbounded tools (planes, infinite
sweeps) are clipped to a cube of side ``plane_size`` (or to ``bounds``); there the surface is
open. Explicit sweeps whose offset outline would fold also fall back to this path.

Meshes are for display only: Python-level loops here run over corners and arcs, not nodes.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from sim.tools.implicit import mesh_implicit, tool_bounds
from sim.tools.polygon import edge_normals, is_simple_polygon
from sim.tools.pose import transform
from sim.tools.program import RCORNER, Node, parse

# a triangle mesh: vertices V (m, 3) float64 and faces F (k, 3) int64, outward normals
Mesh = tuple[np.ndarray, np.ndarray]


def _dedup_cyclic(P: np.ndarray, closed: bool, tol: float) -> np.ndarray:
    """Drop consecutive (and, for closed chains, wrap-around) duplicate points."""
    keep = np.ones(len(P), dtype=bool)
    keep[1:] = np.linalg.norm(np.diff(P, axis=0), axis=1) > tol
    P = P[keep]
    if closed and len(P) > 1 and np.linalg.norm(P[0] - P[-1]) <= tol:
        P = P[:-1]
    return P


def _profile(lo: float, hi: float, z0: float, z1: float, r: float, n_arc: int,
             axis: bool) -> tuple[np.ndarray, bool]:
    """Boundary of the rounded rectangle in the (u, z) plane, counter-clockwise.

    Returns (P (J, 2), closed). For lo = -inf the chain is open: it runs from the bottom cap
    rim (hi - r, z0) up the outer side to (hi - r, z1); with ``axis`` it starts at (0, z0) and
    ends at (0, z1) instead (revolution: the caps become discs closed by a pole).
    """
    lo_, hi_, a0, a1 = lo + r, hi - r, z0 + r, z1 - r
    k = n_arc if r > 0.0 else 0

    def arc(cu: float, cz: float, t0: float) -> np.ndarray:
        th = t0 + np.linspace(0.0, 0.5 * np.pi, k + 1)
        return np.stack([cu + r * np.cos(th), cz + r * np.sin(th)], axis=1)

    parts = [arc(hi_, a0, -0.5 * np.pi), arc(hi_, a1, 0.0)]
    if np.isfinite(lo):
        parts += [arc(lo_, a1, 0.5 * np.pi), arc(lo_, a0, np.pi)]
        closed = True
    else:
        closed = False
        if axis:
            parts = [np.array([[0.0, z0]])] + parts + [np.array([[0.0, z1]])]
    P = np.concatenate(parts)
    scale = max(abs(z1 - z0), abs(hi) if np.isfinite(hi) else 0.0, 1e-300)
    return _dedup_cyclic(P, closed, 1e-13 * scale), closed


def _offset_ring(poly: np.ndarray, u: float, n_arc: int) -> np.ndarray:
    """Points (M, 2) of the level set {w = u >= 0} of a CCW polygon's signed distance.

    Edges move by u along their outward normals; convex vertices become arcs of n_arc
    segments (n_arc + 1 points, all equal to the vertex when u = 0), reflex (and straight)
    vertices the mitre point. The point count depends on the polygon only.
    """
    n = edge_normals(poly)
    n_prev = np.roll(n, 1, axis=0)
    e = np.roll(poly, -1, axis=0) - poly
    e_prev = np.roll(e, 1, axis=0)
    cross = e_prev[:, 0] * e[:, 1] - e_prev[:, 1] * e[:, 0]
    pts = []
    for i in range(poly.shape[0]):
        if cross[i] > 1e-12 * np.linalg.norm(e_prev[i]) * np.linalg.norm(e[i]):
            a0 = np.arctan2(n_prev[i, 1], n_prev[i, 0])
            da = np.arctan2(cross[i], np.dot(e_prev[i], e[i]))  # turning angle in (0, pi)
            th = a0 + np.linspace(0.0, da, n_arc + 1)
            pts.append(poly[i] + u * np.stack([np.cos(th), np.sin(th)], axis=1))
        else:
            m = (n_prev[i] + n[i]) / (1.0 + np.dot(n_prev[i], n[i]))
            pts.append((poly[i] + u * m)[None, :])
    return np.concatenate(pts)


def _offset_ring_rounded(C: np.ndarray, u: float, n_arc: int) -> np.ndarray | None:
    """Points (M, 2) of the level set {w = u} of a rounded polygon (RSWEEP corners C (m, 8)),
    or None where it folds (an arc of radius rc + s u < 0). Arc i becomes n_arc + 1 points at
    radius rc + s u about its centre; a sharp corner an arc of radius u about the vertex
    (convex, u > 0; reflex, u < 0) or the mitre point repeated. M depends on C only."""
    c, rc, sg, a, b = C[:, 0:2], C[:, 2], C[:, 3], C[:, 4:6], C[:, 6:8]
    nxt = np.roll(a, -1, axis=0) - b  # edge i: b_i -> a_{i+1}
    L = np.linalg.norm(nxt, axis=1)
    ok = L > 0
    n_out = np.zeros_like(nxt)
    n_out[ok] = np.stack([nxt[ok, 1], -nxt[ok, 0]], axis=1) / L[ok, None]
    pts = []
    for i in range(len(C)):
        if rc[i] > 0.0:
            rad = rc[i] + sg[i] * u
            if rad < 0.0:
                return None
            e0, e1 = (a[i] - c[i]) / rc[i], (b[i] - c[i]) / rc[i]
        else:
            e0, e1 = n_out[i - 1], n_out[i]  # normals of the edges meeting there
            if sg[i] * u < 0.0:  # mitre
                m = (e0 + e1) / (1.0 + np.dot(e0, e1))
                pts.append(np.repeat((c[i] + u * m)[None, :], n_arc + 1, axis=0))
                continue
            rad = u
        a0 = np.arctan2(e0[1], e0[0])
        da = np.arctan2(e0[0] * e1[1] - e0[1] * e1[0], np.dot(e0, e1))
        th = a0 + np.linspace(0.0, da, n_arc + 1)
        pts.append(c[i] + rad * np.stack([np.cos(th), np.sin(th)], axis=1))
    return np.concatenate(pts)


def _weld(V: np.ndarray, F: np.ndarray,
          tol: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Merge vertices closer than tol, drop faces that became degenerate and unused vertices."""
    pairs = cKDTree(V).query_pairs(tol, output_type="ndarray")
    if len(pairs):
        graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])),
                           shape=(len(V), len(V)))
        _, label = connected_components(graph, directed=False)
        # representative of each cluster: its lowest vertex index
        first = np.full(label.max() + 1, len(V))
        np.minimum.at(first, label, np.arange(len(V)))
        rep = first[label]
    else:
        rep = np.arange(len(V))
    F = rep[F]
    F = F[(F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 0] != F[:, 2])]
    used, inv = np.unique(F, return_inverse=True)
    return V[used], inv.reshape(F.shape).astype(np.int64), used, rep


def _loft(rings: np.ndarray, closed: bool) -> np.ndarray:
    """Faces joining consecutive rings (J, M) of vertex indices, both cyclic in M."""
    J, M = rings.shape
    F = []
    for j in range(J if closed else J - 1):
        a = rings[j]
        b = rings[(j + 1) % J]
        a1 = np.roll(a, -1)
        b1 = np.roll(b, -1)
        F.append(np.stack([a, a1, b1], axis=1))
        F.append(np.stack([a, b1, b], axis=1))
    return np.concatenate(F)


def _earcut(P: np.ndarray) -> np.ndarray:
    """Ear-clipping triangulation of a simple CCW polygon P (n, 2): CCW triangles (k, 3)."""
    idx = list(range(len(P)))
    tris = []
    scale = np.ptp(P, axis=0).max()
    while len(idx) > 3:
        n = len(idx)
        Q = P[idx]
        prev = np.roll(Q, 1, axis=0)
        nxt = np.roll(Q, -1, axis=0)
        cr = (Q[:, 0] - prev[:, 0]) * (nxt[:, 1] - Q[:, 1]) - (Q[:, 1] - prev[:, 1]) * (
            nxt[:, 0] - Q[:, 0])
        found = False
        for k in np.argsort(-cr):
            if cr[k] <= 1e-14 * scale * scale:
                break
            a, b, c = prev[k], Q[k], nxt[k]
            others = np.ones(n, dtype=bool)
            others[[(k - 1) % n, k, (k + 1) % n]] = False
            R = Q[others]

            def side(p0: np.ndarray, p1: np.ndarray, R: np.ndarray = R) -> np.ndarray:
                return (p1[0] - p0[0]) * (R[:, 1] - p0[1]) - (p1[1] - p0[1]) * (R[:, 0] - p0[0])

            inside = (side(a, b) >= 0) & (side(b, c) >= 0) & (side(c, a) >= 0)
            if not inside.any():
                tris.append((idx[(k - 1) % n], idx[k], idx[(k + 1) % n]))
                idx.pop(k)
                found = True
                break
        if not found:  # numerically stuck: clip the most convex vertex anyway
            k = int(np.argmax(cr))
            tris.append((idx[(k - 1) % n], idx[k], idx[(k + 1) % n]))
            idx.pop(k)
    tris.append(tuple(idx))
    return np.array(tris, dtype=np.int64)


def _orient_outward(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    vol = np.einsum("ij,ij->i", V[F[:, 0]], np.cross(V[F[:, 1]], V[F[:, 2]])).sum()
    return F[:, ::-1].copy() if vol < 0 else F


def _mesh_profile(lo: float, hi: float, z0: float, z1: float, r: float, poly: np.ndarray | None,
                  n_segments: int, n_arc: int) -> Mesh | None:
    """Revolved (poly is None) or swept (offsets of poly) rounded-rectangle profile."""
    P, closed = _profile(lo, hi, z0, z1, r, n_arc, axis=poly is None)
    if poly is None:
        th = 2.0 * np.pi * np.arange(n_segments) / n_segments
        c, s = np.cos(th), np.sin(th)
        rings = [np.stack([u * c, u * s, np.full_like(c, z)], axis=1) for u, z in P]
        scale = max(np.abs(P).max(), 1e-300)
    elif poly.shape[1] == RCORNER:  # rounded polygon: offsets either way
        scale = max(np.abs(poly[:, 4:]).max() + abs(hi), abs(z0), abs(z1))
        rings = []
        for u, z in P:
            q = _offset_ring_rounded(poly, u, n_arc)
            if q is None or not is_simple_polygon(_dedup_cyclic(q, True, 1e-12 * scale)):
                return None  # the offset outline folds: leave it to the implicit mesher
            rings.append(np.concatenate([q, np.full((len(q), 1), z)], axis=1))
    else:
        scale = max(np.abs(poly).max() + abs(hi), abs(z0), abs(z1))
        if P[:, 0].min() < 0.0:
            return None  # inward offsets of the polygon: not built explicitly
        widest = _dedup_cyclic(_offset_ring(poly, P[:, 0].max(), n_arc), True, 1e-12 * scale)
        if not is_simple_polygon(widest):
            return None  # the offset outline folds: leave it to the implicit mesher
        rings = []
        for u, z in P:
            q = _offset_ring(poly, u, n_arc)
            rings.append(np.concatenate([q, np.full((len(q), 1), z)], axis=1))
    M = rings[0].shape[0]
    V = np.concatenate(rings)
    ring_idx = np.arange(len(P) * M).reshape(len(P), M)
    F = _loft(ring_idx, closed)
    V, F, used, rep = _weld(V, F, 1e-12 * scale)
    if poly is not None and not closed:
        new_of_old = np.full(len(rep), -1)
        new_of_old[used] = np.arange(len(used))
        caps = []
        for j, flip in ((0, True), (len(P) - 1, False)):
            ids = new_of_old[rep[ring_idx[j]]]
            keep = np.ones(M, dtype=bool)
            keep[1:] = ids[1:] != ids[:-1]
            ids = ids[keep]
            if ids[0] == ids[-1]:
                ids = ids[:-1]
            T = ids[_earcut(V[ids, :2])]
            caps.append(T[:, ::-1] if flip else T)
        F = np.concatenate([F] + caps)
    return V, _orient_outward(V, F)


def _mesh_box(c: np.ndarray, h: np.ndarray, r: float, n_arc: int) -> Mesh:
    half = max(1, n_arc // 2)

    def samples(hk: float) -> np.ndarray:
        if r == 0.0:
            return np.array([-hk, hk])
        arc = (hk - r) + r * np.tan(np.linspace(0.0, 0.25 * np.pi, half + 1))
        arc[-1] = hk
        return np.unique(np.concatenate([-arc, arc]))

    S = [samples(hk) for hk in h]
    V, F = [], []
    nv = 0
    for a in range(3):
        b, cc = (a + 1) % 3, (a + 2) % 3
        sb, sc = S[b], S[cc]
        B, C = np.meshgrid(sb, sc, indexing="ij")
        for sign in (1.0, -1.0):
            P = np.empty((B.size, 3))
            P[:, a] = sign * h[a]
            P[:, b] = B.ravel()
            P[:, cc] = C.ravel()
            ids = nv + np.arange(B.size).reshape(B.shape)
            q00, q10, q11, q01 = ids[:-1, :-1], ids[1:, :-1], ids[1:, 1:], ids[:-1, 1:]
            T = np.concatenate([np.stack([q00, q10, q11], -1).reshape(-1, 3),
                                np.stack([q00, q11, q01], -1).reshape(-1, 3)])
            F.append(T if sign > 0 else T[:, ::-1])
            V.append(P)
            nv += B.size
    V, F, _, _ = _weld(np.concatenate(V), np.concatenate(F), 1e-12 * h.max())
    if r > 0.0:
        inner = h - r
        core = np.clip(V, -inner, inner)
        v = V - core
        V = core + r * v / np.linalg.norm(v, axis=1, keepdims=True)
    return V + c, _orient_outward(V, F)


def _mesh_plane(p: np.ndarray, n: np.ndarray, size: float) -> Mesh:
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(n, a)
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    s = 0.5 * size
    V = np.array([p - s * u - s * v, p + s * u - s * v, p + s * u + s * v, p - s * u + s * v])
    F = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)
    if np.dot(np.cross(V[1] - V[0], V[2] - V[0]), n) < 0:
        F = F[:, ::-1].copy()
    return V, F


def _explicit(node: Node, n_segments: int, n_arc: int, plane_size: float) -> Mesh | None:
    """Explicit mesh of a primitive (or a framed one), None when it has to be implicit."""
    kind = node[0]
    if kind == "plane":
        return _mesh_plane(node[1], node[2], plane_size)
    if kind == "box":
        return _mesh_box(node[1], node[2], node[3], n_arc)
    if kind == "revolve":
        return _mesh_profile(*node[1:6], None, n_segments, n_arc)
    if kind in ("sweep", "rsweep"):
        if not np.isfinite(node[2]):
            return None
        return _mesh_profile(*node[1:6], node[6], n_segments, n_arc)
    if kind == "frame":
        m = _explicit(node[3], n_segments, n_arc, plane_size)
        if m is None:
            return None
        return m[0] @ node[1].T + node[2], m[1]
    return None


def tool_mesh(prog: npt.ArrayLike, R: npt.ArrayLike | None = None, t: npt.ArrayLike | None = None,
              *, n_segments: int = 96, n_arc: int = 12, resolution: int = 64,
              plane_size: float = 1.0, bounds: tuple[npt.ArrayLike, npt.ArrayLike] | None = None,
              method: str = "auto") -> Mesh:
    """Triangle mesh (V (m, 3) float64, F (k, 3) int64) of a tool surface, outward normals.

    prog: SDF program; R, t: optional pose, vertices then returned in world coordinates.
    n_segments: segments around a revolution; n_arc: segments per quarter arc of a rounding;
    resolution: grid cells along the longest side for implicit meshing; plane_size: side of
    the displayed square of a plane and of the clipping cube of unbounded implicit tools;
    bounds: optional (lo (3,), hi (3,)) box for implicit meshing; method: "auto" (explicit
    for a single primitive, implicit otherwise), "explicit" or "implicit".
    """
    tree = parse(prog)
    mesh = None
    if method in ("auto", "explicit"):
        mesh = _explicit(tree, n_segments, n_arc, plane_size)
        if mesh is None and method == "explicit":
            raise ValueError("no explicit mesh for this program (CSG): use method='implicit'")
    elif method != "implicit":
        raise ValueError(f"unknown method {method!r}")
    if mesh is None:
        if bounds is None:
            lo, hi = tool_bounds(tree)
            half = 0.5 * plane_size
            lo = np.where(np.isfinite(lo), lo, -half)
            hi = np.where(np.isfinite(hi), hi, half)
        else:
            lo, hi = (np.asarray(b, dtype=np.float64) for b in bounds)
        mesh = mesh_implicit(np.asarray(prog, dtype=np.float64), lo, hi, resolution)
    V, F = mesh
    V = np.ascontiguousarray(V, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int64)
    if R is not None or t is not None:
        V = transform(V, R, t)
    return V, F


def chordal_mesh(prog: npt.ArrayLike, chordal: float) -> Mesh:
    """Explicit mesh (V, F) of a revolved tool (a REVOLVE, possibly framed) whose triangles
    stay within ``chordal`` (m) of the surface: on a rounding (a torus) a flat triangle misses
    the surface by the chord heights around and along the arc together, so each gets half."""
    node = parse(prog)
    while node[0] == "frame":
        node = node[3]
    if node[0] != "revolve":
        raise ValueError("chordal_mesh: a revolved tool (punch, die ring, blank holder)")
    _, lo, hi, _, _, r = node

    def parts(radius: float, angle: float) -> int:
        """Segments of an arc of ``angle`` whose chords rise at most chordal / 2."""
        return max(1, math.ceil(angle / (2.0 * math.acos(1.0 - 0.5 * chordal / radius))))

    n_arc = parts(r, 0.5 * math.pi) if r > 0 else 1
    return tool_mesh(prog, n_segments=parts(hi, 2.0 * math.pi), n_arc=n_arc)

"""Plane polygon geometry of swept tools: orientation, edge normals, simplicity, offsets,
rounded corners (the RSWEEP outline) and star outlines."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt


def polygon_area(points: npt.ArrayLike) -> float:
    """Signed area of a 2-D polygon (> 0 when counter-clockwise)."""
    p = np.asarray(points, dtype=np.float64)
    q = np.roll(p, -1, axis=0)
    return 0.5 * float(np.sum(p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]))


def ccw(points: npt.ArrayLike) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if p.shape[0] < 3:
        raise ValueError("polygon needs at least 3 vertices")
    a = polygon_area(p)
    if a == 0.0:
        raise ValueError("degenerate polygon")
    return p if a > 0 else p[::-1].copy()


def edge_normals(points: npt.ArrayLike) -> np.ndarray:
    """Outward unit normals (m, 2) of the edges i -> i + 1 of a CCW polygon."""
    p = np.asarray(points, dtype=np.float64)
    e = np.roll(p, -1, axis=0) - p
    n = np.stack([e[:, 1], -e[:, 0]], axis=1)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def is_simple_polygon(P: np.ndarray) -> bool:
    """True if the closed polyline P (n, 2) has no two non-adjacent edges that intersect."""
    A = P
    B = np.roll(P, -1, axis=0)
    n = len(P)

    def orient(p: np.ndarray, q: np.ndarray, r: np.ndarray) -> np.ndarray:
        return np.sign((q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1])
                       - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0]))

    a, b = A[:, None, :], B[:, None, :]
    c, d = A[None, :, :], B[None, :, :]
    cross = (orient(a, b, c) * orient(a, b, d) < 0) & (orient(c, d, a) * orient(c, d, b) < 0)
    i, j = np.triu_indices(n, k=2)
    adjacent = (i == 0) & (j == n - 1)
    return not np.any(cross[i, j] & ~adjacent)


def offset_polygon(points: npt.ArrayLike, dist: float) -> np.ndarray:
    """Mitred offset of a CCW polygon by ``dist`` (> 0 outward, < 0 inward).

    Every edge moves by dist along its outward normal and vertices are the intersections of
    neighbouring moved edges. Raises ValueError if an edge would flip (offset too large).
    """
    p = ccw(points)
    n = edge_normals(p)
    n_prev = np.roll(n, 1, axis=0)
    den = 1.0 + np.sum(n_prev * n, axis=1)
    if np.any(den < 1e-9):
        raise ValueError("polygon has a cusp (edge reversal)")
    q = p + dist * (n_prev + n) / den[:, None]
    e0 = np.roll(p, -1, axis=0) - p
    e1 = np.roll(q, -1, axis=0) - q
    if np.any(np.sum(e0 * e1, axis=1) <= 0.0) or not is_simple_polygon(q):
        raise ValueError(f"polygon offset by {dist} inverts an edge: offset too large")
    return q


def rounded_polygon(points: npt.ArrayLike, radii: npt.ArrayLike) -> np.ndarray:
    """Corners (m, 8) of a simple polygon whose vertex i is rounded by an arc of radius
    radii[i] tangent to both edges: convex and reflex corners alike (0 keeps it sharp).

    Row i: cx cy rc s ax ay bx by (arc centre, radius, +1 convex / -1 reflex, tangent points
    on the incoming and outgoing edge), counter-clockwise, the layout of an RSWEEP record.
    Raises ValueError when two roundings would overlap on an edge or the outline folds.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    r = np.broadcast_to(np.asarray(radii, dtype=np.float64), (len(p),)).copy()
    if np.any(r < 0) or not np.all(np.isfinite(r)):
        raise ValueError("corner radii must be finite and >= 0")
    if len(p) < 3 or polygon_area(p) == 0.0:
        raise ValueError("polygon needs at least 3 vertices and a nonzero area")
    if polygon_area(p) < 0.0:  # made counter-clockwise: the radii follow their vertices
        p, r = p[::-1].copy(), r[::-1].copy()
    u_out = np.roll(p, -1, axis=0) - p
    length = np.linalg.norm(u_out, axis=1)
    if np.any(length <= 0.0):
        raise ValueError("polygon has repeated vertices")
    u_out /= length[:, None]
    u_in = np.roll(u_out, 1, axis=0)
    cross = u_in[:, 0] * u_out[:, 1] - u_in[:, 1] * u_out[:, 0]
    phi = np.arctan2(np.abs(cross), np.sum(u_in * u_out, axis=1))  # turning angle
    if np.any(phi > np.pi - 1e-6):
        raise ValueError("polygon has a cusp (edge reversal)")
    r[phi < 1e-12] = 0.0  # a straight vertex needs no rounding
    tang = r * np.tan(0.5 * phi)
    if np.any(tang + np.roll(tang, -1) > length * (1.0 + 1e-12)):
        i = int(np.argmax(tang + np.roll(tang, -1) - length))
        raise ValueError(f"corner radii of vertices {i} and {(i + 1) % len(p)} overlap on "
                         "their common edge: radii too large")
    a = p - tang[:, None] * u_in
    b = p + tang[:, None] * u_out
    bis = u_out - u_in
    nb = np.linalg.norm(bis, axis=1)
    bis = np.divide(bis, nb[:, None], out=np.zeros_like(bis), where=nb[:, None] > 0)
    c = p + (r / np.cos(0.5 * phi))[:, None] * bis
    s = np.where(cross >= 0.0, 1.0, -1.0)
    chord = np.stack([a, b], axis=1).reshape(-1, 2)
    keep = np.ones(len(chord), dtype=bool)
    keep[1:] = np.linalg.norm(np.diff(chord, axis=0), axis=1) > 1e-12 * np.abs(p).max()
    if not is_simple_polygon(chord[keep]):
        raise ValueError("rounded polygon is not simple")
    return np.column_stack([c, r, s, a, b])


def star_points(n_points: int, r_outer: float, r_inner: float, phase: float = 0.0) -> np.ndarray:
    """Vertices (2 n_points, 2) of a star, CCW, tips at r_outer, valleys at r_inner."""
    if n_points < 2 or not 0.0 < r_inner < r_outer:
        raise ValueError("star: need n_points >= 2 and 0 < r_inner < r_outer")
    ang = phase + np.pi * np.arange(2 * n_points) / n_points
    r = np.where(np.arange(2 * n_points) % 2 == 0, r_outer, r_inner)
    return np.stack([r * np.cos(ang), r * np.sin(ang)], axis=1)



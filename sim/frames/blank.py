"""The blank's geometry for the run summary (sim.frames.summary): its plane, its outer edge
with the edge's outward normals, the edge's draw-in, the out-of-plane waviness of a closed
curve (flange wrinkles) and the best-fit rigid alignment of one shape onto another
(springback). Pure functions of positions ``(n, 3)``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.geometry.trimesh import oriented_boundary_edges


@dataclass(frozen=True)
class Edge:
    """The blank's outer edge: ``vertices (m,)`` mid-surface vertex ids, ``outward (m, 3)``
    unit in-plane outward normals there (rest), ``normal (3,)`` the blank's unit normal (the
    side its faces' counter-clockwise order points to)."""

    vertices: np.ndarray
    outward: np.ndarray
    normal: np.ndarray


def plane_normal(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """The area-weighted mean normal of triangles ``F`` over ``V``, unit. Shape: (3,)."""
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]).sum(0)
    return n / np.linalg.norm(n)


def is_flat(V: np.ndarray, F: np.ndarray, tol: float) -> bool:
    """Every vertex within ``tol`` of the plane through the centroid normal to
    :func:`plane_normal` (a seeded imperfection far below ``tol`` keeps a blank flat)."""
    return bool(np.abs((V - V.mean(0)) @ plane_normal(V, F)).max() <= tol)


def outer_edge(V: np.ndarray, F: np.ndarray) -> Edge | None:
    """The longest closed boundary curve of a flat mesh (a disk's rim, a rectangle's outline,
    not a hole's edge) and its outward normals: at each vertex the bisector of the outward
    normals of its two boundary edges, each edge's being (b - a) x N for the edge a -> b as its
    face orders it (the sheet to its left). None for a mesh without a boundary."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    be = oriented_boundary_edges(F)
    if not len(be):
        return None
    n_v = len(V)
    graph = coo_matrix((np.ones(len(be)), (be[:, 0], be[:, 1])), shape=(n_v, n_v))
    _, label = connected_components(graph, directed=False)
    d = V[be[:, 1]] - V[be[:, 0]]
    length = np.bincount(label[be[:, 0]], np.linalg.norm(d, axis=1))
    keep = label[be[:, 0]] == int(np.argmax(length))
    N = plane_normal(V, F)
    out = np.cross(d[keep], N)
    out /= np.linalg.norm(out, axis=1, keepdims=True)
    acc, first = np.zeros_like(V), np.zeros_like(V)
    for c in range(2):
        np.add.at(acc, be[keep, c], out)
    first[be[keep, 0]] = out  # each vertex of a loop starts one of its edges
    verts = np.unique(be[keep])
    size = np.linalg.norm(acc[verts], axis=1, keepdims=True)
    # where the boundary doubles back on itself (a cusp) the two edges' normals cancel: the
    # vertex takes the normal of the edge it starts, never 0 / 0
    normals = np.where(size > 1e-9, acc[verts] / np.maximum(size, 1e-300), first[verts])
    return Edge(verts, normals, N)


def draw_in(rest: np.ndarray, cur: np.ndarray, edge: Edge) -> np.ndarray:
    """How far each edge vertex moved inwards in the blank's plane (m): minus its displacement
    along its rest outward normal, which lies in the plane, so motion along the blank's normal
    (the punch's direction) does not count. A disk's edge drawn from radius r0 to r reads
    r0 - r (to second order in its tangential motion); a rigid in-plane translation a reads
    -a . n_out, so |a| where the edge faces away from a. Shape: (m,)."""
    u = cur[edge.vertices] - rest[edge.vertices]
    return -np.einsum("ij,ij->i", u, edge.outward)


def waviness(P: np.ndarray) -> float:
    """Peak-to-valley of the heights of points ``P (m, 3)`` about their least-squares plane
    (its normal the direction of least spread): zero for points in any one plane, tilted or
    lifted; 2a for a curve z = a sin(k theta) sampled at its crests and troughs."""
    Pc = P - P.mean(0)
    normal = np.linalg.svd(Pc, full_matrices=False)[2][-1]
    h = Pc @ normal
    return float(h.max() - h.min())


def best_fit(P: np.ndarray, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rotation R (3, 3) and translation t (3,) that bring points ``P (n, 3)`` closest to
    ``Q (n, 3)`` in the least-squares sense, min sum |R p + t - q|^2 (Kabsch: the SVD of the
    cross-covariance, a reflection excluded)."""
    p0, q0 = P.mean(0), Q.mean(0)
    U, _, Wt = np.linalg.svd((P - p0).T @ (Q - q0))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Wt.T @ U.T)) or 1.0])
    R = Wt.T @ D @ U.T
    return R, q0 - R @ p0

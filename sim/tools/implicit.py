"""Implicit meshing of any SDF program for display: marching tetrahedra on a grid over the
tool's bounds, each vertex then moved onto the zero level set along its own grid edge
(sim.tools.surface says when this path is taken)."""

from __future__ import annotations

import itertools

import numpy as np

from sim.tools.evaluate import sdf_distance
from sim.tools.program import Node


def tool_bounds(node: Node) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box (lo (3,), hi (3,)) of a parsed program in its frame; +-inf if open."""
    inf = np.full(3, np.inf)
    kind = node[0]
    if kind == "plane":
        return -inf, inf
    if kind == "box":
        return node[1] - node[2], node[1] + node[2]
    if kind == "grid":
        return node[1], node[2]
    if kind == "revolve":
        hi = node[2]
        return np.array([-hi, -hi, node[3]]), np.array([hi, hi, node[4]])
    if kind == "sweep":
        poly, hi = node[6], node[2]
        return (np.r_[poly.min(0) - hi, node[3]], np.r_[poly.max(0) + hi, node[4]])
    if kind == "rsweep":  # outline within its tangent points and arcs (centre +- radius)
        C, hi = node[6], node[2]
        P = np.concatenate([C[:, 4:6], C[:, 6:8], C[:, :2] - C[:, 2:3], C[:, :2] + C[:, 2:3]])
        return (np.r_[P.min(0) - max(hi, 0.0), node[3]], np.r_[P.max(0) + max(hi, 0.0), node[4]])
    if kind == "frame":
        lo, hi = tool_bounds(node[3])
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            return -inf, inf
        corners = np.array(list(itertools.product(*zip(lo, hi, strict=True))))
        W = corners @ node[1].T + node[2]
        return W.min(0), W.max(0)
    la, ha = tool_bounds(node[2])
    lb, hb = tool_bounds(node[3])
    k = node[1]
    if kind == "union":
        return np.minimum(la, lb) - k, np.maximum(ha, hb) + k
    if kind == "intersect":
        return np.maximum(la, lb) - k, np.minimum(ha, hb) + k
    return la - k, ha + k  # subtract


def _marching_tets(f: np.ndarray, origin: np.ndarray,
                   h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Closed, outward-oriented isosurface {f = 0} of grid values f (nx, ny, nz) at
    origin (3,) + h (i, j, k).

    Returns V (linear interpolation on the grid edges), F, and the two grid nodes (flat
    indices, f < 0 at one end, f >= 0 at the other) of each vertex's edge.
    """
    nx, ny, nz = f.shape
    ff = f.ravel()
    I, J, K = np.meshgrid(np.arange(nx - 1), np.arange(ny - 1), np.arange(nz - 1),
                          indexing="ij")
    I, J, K = I.ravel(), J.ravel(), K.ravel()
    base = (I * ny + J) * nz + K
    step = np.array([ny * nz, nz, 1])
    corners = np.array(list(itertools.product((0, 1), repeat=3)))
    cv = ff[base[:, None] + corners @ step]
    mixed = (cv >= 0).any(1) & (cv < 0).any(1)
    base = base[mixed]
    tets = []
    for p in itertools.permutations(range(3)):
        e0, e1 = np.eye(3, dtype=np.int64)[p[0]], np.eye(3, dtype=np.int64)[p[1]]
        offs = np.array([[0, 0, 0], e0, e0 + e1, [1, 1, 1]]) @ step
        tets.append(base[:, None] + offs)
    T = np.concatenate(tets)
    vals = ff[T]
    pos = vals >= 0
    npos = pos.sum(1)
    T, vals, pos, npos = (a[(npos > 0) & (npos < 4)] for a in (T, vals, pos, npos))

    def coords(idx: np.ndarray) -> np.ndarray:
        i, rem = np.divmod(idx, ny * nz)
        j, k = np.divmod(rem, nz)
        return origin + h * np.stack([i, j, k], axis=-1)

    pos_c = (coords(T) * pos[..., None]).sum(1) / npos[:, None]
    neg_c = (coords(T) * (~pos)[..., None]).sum(1) / (4 - npos)[:, None]
    direction = pos_c - neg_c
    tri_edges, tri_dir = [], []
    odd = (npos == 1) | (npos == 3)
    if odd.any():
        minority = np.where((npos == 1)[:, None], pos, ~pos)[odd]
        order = np.argsort(~minority, axis=1, kind="stable")
        To = np.take_along_axis(T[odd], order, axis=1)
        o = To[:, 0]
        tri_edges.append(np.stack([np.stack([o, To[:, q]], -1) for q in (1, 2, 3)], 1))
        tri_dir.append(direction[odd])
    two = npos == 2
    if two.any():
        order = np.argsort(~pos[two], axis=1, kind="stable")
        Tt = np.take_along_axis(T[two], order, axis=1)
        a, b, c, d = Tt.T
        ac, ad, bd, bc = (np.stack(e, -1) for e in ((a, c), (a, d), (b, d), (b, c)))
        tri_edges += [np.stack([ac, ad, bd], 1), np.stack([ac, bd, bc], 1)]
        tri_dir += [direction[two], direction[two]]
    E = np.concatenate(tri_edges)  # (ntri, 3 vertices, 2 grid nodes)
    D = np.concatenate(tri_dir)
    E = np.sort(E, axis=2)
    keys = E[..., 0] * ff.size + E[..., 1]
    ukeys, F = np.unique(keys.ravel(), return_inverse=True)
    F = F.reshape(-1, 3).astype(np.int64)
    na, nb = np.divmod(ukeys, ff.size)
    fa, fb = ff[na], ff[nb]
    t = fa / (fa - fb)
    V = coords(na) + t[:, None] * (coords(nb) - coords(na))
    nrm = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    flip = np.einsum("ij,ij->i", nrm, D) < 0
    F[flip] = F[flip][:, ::-1]
    return V, F, na, nb


def _edge_roots(prog: np.ndarray, A: np.ndarray, B: np.ndarray, fa: np.ndarray, fb: np.ndarray,
                tol: float, iters: int = 60) -> np.ndarray:
    """Points (n, 3) on the segments A -> B (n, 3) where the SDF vanishes (fa < 0 <= fb or
    fa >= 0 > fb, values (n,) at A and B, updated in place).

    Illinois (modified regula falsi) on every segment at once: superlinear, always bracketed,
    so each vertex stays on its own grid edge and vertices never merge, even at CSG creases.
    """
    ta, tb = np.zeros(len(A)), np.ones(len(A))
    t = (ta * fb - tb * fa) / (fb - fa)
    side = np.zeros(len(A), dtype=np.int8)
    D = B - A
    todo = np.arange(len(A))  # segments not converged yet
    for _ in range(iters):
        i = todo
        t[i] = (ta[i] * fb[i] - tb[i] * fa[i]) / (fb[i] - fa[i])
        f = sdf_distance(prog, A[i] + t[i, None] * D[i])
        same = (f >= 0) == (fa[i] >= 0)
        # replace the endpoint on f's side; halve the other end's value if it was kept twice
        ta[i] = np.where(same, t[i], ta[i])
        tb[i] = np.where(same, tb[i], t[i])
        fa_i = np.where(same, f, np.where(side[i] == -1, 0.5 * fa[i], fa[i]))
        fb[i] = np.where(same, np.where(side[i] == 1, 0.5 * fb[i], fb[i]), f)
        fa[i] = fa_i
        side[i] = np.where(same, 1, -1)
        todo = i[np.abs(f) > tol]
        if todo.size == 0:
            break
    return A + t[:, None] * D


def mesh_implicit(prog: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                  resolution: int) -> tuple[np.ndarray, np.ndarray]:
    """Mesh (V (m, 3), F (k, 3)) of the program's zero level set inside the box lo, hi (3,)."""
    size = hi - lo
    h = size.max() / resolution
    # pad by two cells; the irrational shift keeps grid nodes off planes aligned with the box
    lo = lo - (2.0 + 1.0 / np.pi) * h
    n = np.ceil((size + 5.0 * h) / h).astype(int) + 1
    axes = [lo[i] + h * np.arange(n[i]) for i in range(3)]
    G = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    f = sdf_distance(prog, G)
    V, F, na, nb = _marching_tets(f.reshape(tuple(n)), lo, h)
    # move each vertex along its grid edge onto the zero level set
    V = _edge_roots(prog, G[na], G[nb], f[na].copy(), f[nb].copy(), 1e-13 * size.max())
    return V, F



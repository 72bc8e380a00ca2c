"""Sparse Hessian layout: the upper triangle of the DoF graph in CSR, fixed for a whole run.

Every term adds into ``data`` through precomputed slots, so the pattern (and with it the
symbolic factorisation) never changes. DoF ``3 * node + c``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numba import njit


@dataclass(frozen=True)
class Pattern:
    """Upper-triangular CSR pattern ``(indptr, indices)``, element slots of the packed upper
    triangle ``(n_elem, 3 n_en (3 n_en + 1) / 2)`` and node-block slots ``(n_nodes, 3, 3)``
    (-1 below the diagonal); ``schedule``: the order of a race-free parallel scatter."""

    n_dof: int
    indptr: np.ndarray
    indices: np.ndarray
    elem_slots: np.ndarray
    node_slots: np.ndarray
    schedule: Schedule

    @property
    def nnz(self) -> int:
        return len(self.indices)

    def matrix(self, data: np.ndarray) -> sp.csr_matrix:
        """The full symmetric matrix (for SciPy and tests)."""
        U = sp.csr_matrix((data, self.indices, self.indptr), shape=(self.n_dof, self.n_dof))
        return U + sp.triu(U, 1).T


def element_dofs(conn: np.ndarray) -> np.ndarray:
    """DoFs per element ``(n_elem, 3 n_en)``, node-major."""
    return (3 * conn[:, :, None] + np.arange(3)).reshape(len(conn), -1)


@njit(cache=True)
def _packed_slots(indptr: np.ndarray, indices: np.ndarray, dofs: np.ndarray) -> np.ndarray:
    """Global slot of each upper-triangle entry (r <= c) of each element matrix (its DoFs
    ``dofs (n_elem, k)``), packed row by row ``(n_elem, k (k+1) / 2)``, int32: half the
    entries of a full k x k map at half the width, which is what the scatter streams through
    memory every assembly."""
    n_e, k = dofs.shape
    out = np.empty((n_e, k * (k + 1) // 2), np.int32)
    for e in range(n_e):
        p = 0
        for a in range(k):
            for b in range(a, k):
                r, c = dofs[e, a], dofs[e, b]
                if c < r:
                    r, c = c, r
                lo, hi = indptr[r], indptr[r + 1]
                out[e, p] = lo + np.searchsorted(indices[lo:hi], c)
                p += 1
    return out


@njit(cache=True)
def _slots(indptr: np.ndarray, indices: np.ndarray, dofs: np.ndarray) -> np.ndarray:
    n_e, k = dofs.shape
    out = np.full((n_e, k, k), -1, np.int64)
    for e in range(n_e):
        for a in range(k):
            r = dofs[e, a]
            lo, hi = indptr[r], indptr[r + 1]
            for b in range(k):
                c = dofs[e, b]
                if c >= r:
                    out[e, a, b] = lo + np.searchsorted(indices[lo:hi], c)
    return out


@dataclass(frozen=True)
class Schedule:
    """Elements in scatter order ``order``, cut into blocks ``order[block_ptr[b]:block_ptr[b+1]]``
    of mesh-adjacent elements; blocks ``color_ptr[c]:color_ptr[c+1]`` share no node, so one
    thread per block scatters them in parallel without races. A block's elements touch the
    same Hessian rows, which stay in cache while the block runs: colouring single elements
    instead spreads every colour over the whole mesh, and each of its 9 colours swept the whole
    Hessian (5 MB for the Q3T beam, about 30 MB for the cup) through memory again. The order does
    not depend on the thread count, so neither do the sums."""

    order: np.ndarray
    block_ptr: np.ndarray
    color_ptr: np.ndarray

    def blocks(self, color: int) -> list[np.ndarray]:
        return [self.order[self.block_ptr[b]:self.block_ptr[b + 1]]
                for b in range(self.color_ptr[color], self.color_ptr[color + 1])]


# elements per block: a Q3T block's rows (about 30 nodes x 3) stay in a core's L2, and the
# beam (4,504 elements) still has about 70 blocks to spread over the threads
BLOCK = 64


@njit(cache=True)
def _color_blocks(conn: np.ndarray, order: np.ndarray, block_ptr: np.ndarray, n_nodes: int,
                  max_colors: int) -> np.ndarray:
    """First colour, per block, none of whose blocks touches any of its nodes."""
    n_b = len(block_ptr) - 1
    color = np.full(n_b, -1, np.int64)
    used = np.zeros((max_colors, n_nodes), np.bool_)
    for b in range(n_b):
        for c in range(max_colors):
            free = True
            for t in range(block_ptr[b], block_ptr[b + 1]):
                for a in range(conn.shape[1]):
                    if used[c, conn[order[t], a]]:
                        free = False
                        break
                if not free:
                    break
            if free:
                for t in range(block_ptr[b], block_ptr[b + 1]):
                    for a in range(conn.shape[1]):
                        used[c, conn[order[t], a]] = True
                color[b] = c
                break
    return color


def scatter_schedule(conn: np.ndarray, n_nodes: int, block: int = BLOCK) -> Schedule:
    """Blocks of ``block`` elements consecutive in their lowest node (the generated meshes
    number nodes row by row, so these are compact patches), coloured greedily."""
    order = np.argsort(conn.min(axis=1), kind="stable")
    n_b = max(1, -(-len(order) // block))
    block_ptr = np.minimum(np.arange(n_b + 1) * block, len(order))
    # a block meets only the blocks around it; 64 colours cover every mesh we make (2 to 5
    # for the meshes here); more raises below
    color = _color_blocks(conn, order, block_ptr, n_nodes, 64)
    if np.any(color < 0):
        raise ValueError("mesh needs more than 64 colours for the parallel scatter")
    by_color = np.argsort(color, kind="stable")
    sizes = np.diff(block_ptr)[by_color]
    new_order = np.concatenate([order[block_ptr[b]:block_ptr[b + 1]] for b in by_color])
    return Schedule(new_order, np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64),
                    np.searchsorted(color[by_color], np.arange(color.max() + 2)).astype(np.int64))


def build_pattern(conn: np.ndarray, n_nodes: int, pairs: np.ndarray | None = None) -> Pattern:
    """``pairs (m, 2)``: extra node couplings (a tool DoF and the sheet nodes it can touch)."""
    dofs = element_dofs(conn)
    k = dofs.shape[1]
    rows = np.repeat(dofs, k, axis=1).ravel()
    cols = np.tile(dofs, (1, k)).ravel()
    if pairs is not None and len(pairs):
        pd = element_dofs(pairs)
        rows = np.concatenate([rows, np.repeat(pd, 6, axis=1).ravel()])
        cols = np.concatenate([cols, np.tile(pd, (1, 6)).ravel()])
    keep = cols >= rows
    n_dof = 3 * n_nodes
    A = sp.csr_matrix((np.ones(keep.sum()), (rows[keep], cols[keep])), shape=(n_dof, n_dof))
    A.sum_duplicates()
    A.sort_indices()
    indptr, indices = A.indptr.astype(np.int64), A.indices.astype(np.int64)
    node_dofs = (3 * np.arange(n_nodes)[:, None] + np.arange(3))
    if len(indices) >= 2**31:
        raise ValueError(f"Hessian pattern has {len(indices)} entries: beyond int32 slots")
    return Pattern(n_dof, indptr, indices, _packed_slots(indptr, indices, dofs),
                   _slots(indptr, indices, node_dofs).reshape(n_nodes, 3, 3),
                   scatter_schedule(conn, n_nodes))


@njit(cache=True, inline='always')
def drain_element_gradient(grad: np.ndarray, nodes: np.ndarray, g: np.ndarray,
                           ok: bool) -> None:
    """Add an element's gradient ``g (3 n_en,)`` into ``grad`` at its ``nodes`` (not when its
    energy was not finite: ``ok`` False) and hand ``g`` back zeroed for the next element."""
    for a in range(len(nodes)):
        for i in range(3):
            if ok:
                grad[nodes[a], i] += g[3 * a + i]
            g[3 * a + i] = 0.0


@njit(cache=True)
def scatter_node_blocks(data: np.ndarray, node_slots: np.ndarray, nodes: np.ndarray,
                        blocks: np.ndarray) -> None:
    """data[slots] += blocks for 3x3 node blocks ``(n, 3, 3)`` at ``nodes (n,)``; node_slots
    ``(n_nodes, 3, 3)`` (:class:`Pattern`)."""
    for t in range(len(nodes)):
        s = node_slots[nodes[t]]
        for i in range(3):
            for j in range(3):
                if s[i, j] >= 0:
                    data[s[i, j]] += blocks[t, i, j]


@njit(cache=True)
def sym_matvec(indptr: np.ndarray, indices: np.ndarray, data: np.ndarray,
               x: np.ndarray) -> np.ndarray:
    """y = A x (n,) for the symmetric A stored as its upper triangle in CSR (indptr (n + 1,),
    indices and data (nnz,))."""
    n = len(indptr) - 1
    y = np.zeros(n)
    for r in range(n):
        acc = 0.0
        for p in range(indptr[r], indptr[r + 1]):
            c = indices[p]
            acc += data[p] * x[c]
            if c != r:
                y[c] += data[p] * x[r]
        y[r] += acc
    return y


def pair_slots(pattern: Pattern, pairs: np.ndarray) -> np.ndarray:
    """Slots of the off-diagonal 3x3 blocks (a, b) of node pairs ``(m, 2)`` with a < b,
    shape (m, 3, 3)."""
    return _slots(pattern.indptr, pattern.indices, element_dofs(pairs))[:, :3, 3:]

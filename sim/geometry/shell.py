"""Extrusion of a mid-surface triangle mesh into a layer of prisms of a given element type.

Global node numbering is layer-major like the local one: node ``k * n_plane + a`` is in-plane
node ``a`` on thickness layer ``k``. In-plane nodes are the mesh vertices first, then edge nodes
(p-1 per edge, ordered from the lower to the higher vertex id), then face-interior nodes, so
mid-surface vertex ``v`` has its bottom-skin node ``v`` and its top-skin node ``q * n_plane + v``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.elements.base import Prism
from sim.geometry.trimesh import TriMesh, edges, vertex_normals


@dataclass(frozen=True)
class Shell:
    """A discretised solid shell.

    rest: node rest positions ``(n_nodes, 3)``; conn: element connectivity ``(n_elem, n_en)``;
    n_plane: in-plane nodes per layer; mesh: the mid-surface; thickness: per vertex ``(n_v,)``.
    """

    element: Prism
    mesh: TriMesh
    thickness: np.ndarray
    rest: np.ndarray
    conn: np.ndarray
    n_plane: int
    plane_mid: np.ndarray  # rest mid-surface position of every in-plane node (n_plane, 3)

    @property
    def n_nodes(self) -> int:
        return len(self.rest)

    @property
    def n_vertices(self) -> int:
        return len(self.mesh.vertices)

    def skin_nodes(self, top: bool) -> np.ndarray:
        """Corner-vertex nodes of the top or bottom skin, ``(n_v,)``."""
        layer = self.element.q if top else 0
        return layer * self.n_plane + np.arange(self.n_vertices)

    def layer_nodes(self, layer: int) -> np.ndarray:
        return layer * self.n_plane + np.arange(self.n_plane)


def _inplane_nodes(mesh: TriMesh, elem: Prism) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-face in-plane node ids ``(n_f, n_tri)`` and, per in-plane node, the barycentric weights
    ``(n_plane, 3)`` on the vertices ``(n_plane, 3)`` it is interpolated from."""
    F = mesh.faces
    n_v, n_f, p = len(mesh.vertices), len(F), elem.p
    ids = [F]
    src_v = [np.repeat(np.arange(n_v)[:, None], 3, 1)]
    src_w = [np.tile([1.0, 0.0, 0.0], (n_v, 1))]
    if p > 1:
        uniq, fe = edges(F)
        n_edge = len(uniq)
        for e_local, (a, b) in enumerate([(0, 1), (1, 2), (2, 0)]):
            forward = F[:, a] < F[:, b]
            cols = []
            for s in range(1, p):
                k = np.where(forward, s - 1, p - 1 - s)  # position along the sorted edge
                cols.append(n_v + fe[:, e_local] * (p - 1) + k)
            ids.append(np.stack(cols, 1))
        s = np.arange(1, p) / p
        src_v.append(np.repeat(uniq, p - 1, axis=0)[:, [0, 1, 1]])
        src_w.append(np.tile(np.column_stack([1 - s, s, 0 * s]), (n_edge, 1)))
        n_int = (p - 1) * (p - 2) // 2
        if n_int:
            base = n_v + n_edge * (p - 1)
            ids.append(base + np.arange(n_f * n_int).reshape(n_f, n_int))
            interior = [idx for idx in elem.triangle_multi_indices if min(idx) > 0]
            bary = np.array(interior, float) / p
            src_v.append(np.repeat(F, n_int, axis=0))
            src_w.append(np.tile(bary, (n_f, 1)))
    return np.concatenate(ids, 1), np.concatenate(src_v), np.concatenate(src_w)


def extrude(mesh: TriMesh, thickness: np.ndarray | float, elem: Prism) -> Shell:
    """Extrude ``mesh`` along vertex normals by ``thickness`` (scalar or per vertex ``(n_v,)``)
    into prisms of type ``elem``; higher-order in-plane nodes interpolate the vertex positions,
    normals and thicknesses linearly (the mid-surface stays the input's flat triangles), unless
    the mesh knows its ``surface``: then every in-plane node is put on it, along its normal."""
    n_v = len(mesh.vertices)
    h = np.broadcast_to(np.asarray(thickness, float), (n_v,)).copy()
    if np.any(~np.isfinite(h)) or np.any(h <= 0):
        raise ValueError("thickness must be finite and positive at every vertex")
    tri_ids, src_v, src_w = _inplane_nodes(mesh, elem)
    n_plane = len(src_v)
    mid = np.einsum("nk,nkd->nd", src_w, mesh.vertices[src_v])
    if mesh.surface is not None:
        mid, nrm = mesh.surface.project(mid)
    else:
        nrm = np.einsum("nk,nkd->nd", src_w, vertex_normals(mesh)[src_v])
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    hp = np.einsum("nk,nk->n", src_w, h[src_v])
    ws = np.linspace(-1.0, 1.0, elem.q + 1)
    rest = np.concatenate([mid + (w * hp / 2)[:, None] * nrm for w in ws])
    conn = np.concatenate([tri_ids + k * n_plane for k in range(elem.q + 1)], axis=1)
    return Shell(elem, mesh, h, rest, conn.astype(np.int64), n_plane, mid)

"""Tensor-product prisms: a Lagrange triangle of degree p in-plane times a Lagrange line of degree q
through the thickness.

Local node order is layer-major: node ``k * n_tri + a`` is triangle node ``a`` on thickness layer
``k`` (layer 0 is the bottom skin w = -1, the last layer the top skin w = +1). Triangle nodes are
the three vertices, then the edge nodes of edges (0,1), (1,2), (2,0) in order from the first to the
second vertex, then interior nodes. Barycentric coordinates are (l0, l1, l2) = (u, v, 1 - u - v),
which is the paper's Eq. (4).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from itertools import product

import numpy as np

from sim.geometry.quadrature import Rule, prism_rule


def _triangle_indices(p: int) -> list[tuple[int, int, int]]:
    """Multi-indices (i, j, k), i+j+k = p, of the degree-p triangle nodes in our local order."""
    verts = [(p, 0, 0), (0, p, 0), (0, 0, p)]
    edges = []
    for a, b in [(0, 1), (1, 2), (2, 0)]:
        for s in range(1, p):
            idx = [0, 0, 0]
            idx[a], idx[b] = p - s, s
            edges.append(tuple(idx))
    interior = [(i, j, p - i - j) for i in range(1, p) for j in range(1, p - i) if p - i - j > 0]
    return verts + edges + interior


def _lagrange_1d_factor(m: int, p: int, lam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """prod_{s<m} (p*lam - s)/(s+1) and its derivative in lam. Shape of lam: (n,)."""
    val = np.ones_like(lam)
    der = np.zeros_like(lam)
    for s in range(m):
        f = (p * lam - s) / (s + 1)
        der = der * f + val * p / (s + 1)
        val = val * f
    return val, der


def line_lagrange(q: int, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lagrange basis on equispaced nodes of [-1, 1]: values and derivatives, shape (n, q+1)."""
    nodes = np.linspace(-1.0, 1.0, q + 1)
    val = np.ones((len(w), q + 1))
    der = np.zeros((len(w), q + 1))
    for a in range(q + 1):
        for b in range(q + 1):
            if b == a:
                continue
            f = (w - nodes[b]) / (nodes[a] - nodes[b])
            der[:, a] = der[:, a] * f + val[:, a] / (nodes[a] - nodes[b])
            val[:, a] = val[:, a] * f
    return val, der


@dataclass(frozen=True)
class Prism:
    """A prism element: in-plane degree ``p``, thickness degree ``q`` and a default quadrature;
    ``small_mesh_quadrature``: the rule without spurious modes, when the default has some on
    patches of one or two triangles (docs/verification.md, 'Quadrature and spurious
    modes'); ``routine``: run wherever every element is meant (each shipped scene in the
    tests); an element too costly for that (the quartic reference) runs only where it is named.
    ``note``: a line on when to choose it. ``assumed_strain``: its transverse shear strains
    come from tying points on the triangle's edges and its thickness strain from its corners
    (sim.terms.ans), not from the displacement field at the quadrature point."""

    name: str
    p: int
    q: int
    default_quadrature: tuple[int, int]
    small_mesh_quadrature: tuple[int, int] | None = None
    routine: bool = True
    assumed_strain: bool = False
    # what an engineer choosing it should know, in a line (the page's element box)
    note: str = ""

    @cached_property
    def triangle_multi_indices(self) -> list[tuple[int, int, int]]:
        return _triangle_indices(self.p)

    @property
    def n_tri(self) -> int:
        return (self.p + 1) * (self.p + 2) // 2

    @property
    def n_layers(self) -> int:
        return self.q + 1

    @property
    def n_nodes(self) -> int:
        return self.n_tri * self.n_layers

    def edge_for_spacing(self, spacing: float) -> float:
        """The mesh edge length that puts this element's in-plane nodes ``spacing`` apart: an
        edge of degree p carries p + 1 nodes, p spacings (the paper's same-nodes comparison)."""
        return self.p * spacing

    def triangle_basis(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """In-plane shape functions at ``uv (n, 2)``: values (n, n_tri), d/du d/dv (n, n_tri, 2)."""
        lam = np.stack([uv[:, 0], uv[:, 1], 1.0 - uv[:, 0] - uv[:, 1]], axis=1)
        dlam = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, -1.0]])
        n = len(uv)
        val = np.ones((n, self.n_tri))
        grad = np.zeros((n, self.n_tri, 2))
        for a, idx in enumerate(self.triangle_multi_indices):
            factors = [_lagrange_1d_factor(m, self.p, lam[:, c]) for c, m in enumerate(idx)]
            vals = [f[0] for f in factors]
            val[:, a] = vals[0] * vals[1] * vals[2]
            for c in range(3):
                others = np.prod([vals[o] for o in range(3) if o != c], axis=0)
                grad[:, a, :] += (factors[c][1] * others)[:, None] * dlam[c][None, :]
        return val, grad

    def basis(self, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Shape functions at reference points ``(n, 3)``: values (n, n_nodes), gradient in (u,v,w)
        of shape (n, n_nodes, 3)."""
        tv, tg = self.triangle_basis(pts[:, :2])
        lv, lg = line_lagrange(self.q, pts[:, 2])
        val = np.einsum("nk,na->nka", lv, tv).reshape(len(pts), -1)
        g_uv = np.einsum("nk,nad->nkad", lv, tg)
        g_w = np.einsum("nk,na->nka", lg, tv)[..., None]
        grad = np.concatenate([g_uv, g_w], axis=-1).reshape(len(pts), -1, 3)
        return val, grad

    def reference_nodes(self) -> np.ndarray:
        """Reference coordinates of the nodes, shape (n_nodes, 3)."""
        tri = np.array([(i / self.p, j / self.p) for i, j, _ in self.triangle_multi_indices])
        ws = np.linspace(-1.0, 1.0, self.q + 1)
        return np.array([(u, v, w) for w, (u, v) in product(ws, tri)])

    def quadrature(self, rule: tuple[int, int] | None = None) -> Rule:
        return prism_rule(*(rule or self.default_quadrature))

"""Dead loads: gravity / body force, traction on the rim, pressure on a skin, a surface load of
fixed direction on the mid-surface, point loads.

All are linear in x: E = -f . x with a nodal force vector f computed once by quadrature on the
rest geometry, scaled in time by the step's load factor.
"""

from __future__ import annotations

import numpy as np

from sim.elements.base import line_lagrange
from sim.geometry.quadrature import Rule, line_rule, triangle_rule
from sim.geometry.shell import Shell
from sim.geometry.trimesh import edges
from sim.terms import Term


class ExternalForce(Term):
    """E(x) = -s f . (x - X), ``f (n_nodes, 3)``; ``factor`` s the load curve's value, set by
    the stepping (sim.model.curves.load_factor). Measured from the rest state X so the energy
    carries no large constant that would drown its changes in round-off near convergence."""

    name = "external_force"

    def __init__(self, f: np.ndarray, rest: np.ndarray):
        self.f = f
        self.rest = rest
        self.factor = 0.0

    def energy(self, x: np.ndarray) -> float:
        return -self.factor * float(np.sum(self.f * (x - self.rest)))

    def add_gradient(self, x: np.ndarray, g: np.ndarray) -> None:
        g -= self.factor * self.f


def _scatter(shell: Shell, elems: np.ndarray, pts: np.ndarray,
             weights_vec: np.ndarray) -> np.ndarray:
    """Sum N_a(pts) * weights_vec over quadrature points into nodal forces.

    elems (m,), pts (m, nq, 3) reference points, weights_vec (m, nq, 3)."""
    f = np.zeros((shell.n_nodes, 3))
    m, nq = pts.shape[:2]
    N, _ = shell.element.basis(pts.reshape(-1, 3))
    N = N.reshape(m, nq, -1)
    contrib = np.einsum("mqa,mqd->mad", N, weights_vec)
    np.add.at(f, shell.conn[elems], contrib)
    return f


def _map(shell: Shell, elems: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Rest positions and reference Jacobians at reference points (m, nq, 3)."""
    m, nq = pts.shape[:2]
    N, dN = shell.element.basis(pts.reshape(-1, 3))
    Xe = shell.rest[shell.conn[elems]]
    dN = dN.reshape(m, nq, -1, 3)
    return np.einsum("mqaj,mad->mqdj", dN, Xe)


def body_force(shell: Shell, wdetJ: np.ndarray, rule: Rule,
               density_times_accel: np.ndarray) -> np.ndarray:
    """f_a = int rho g N_a dV over every element. wdetJ (n_elem, n_qp), rho g (3,)."""
    n_e = len(shell.conn)
    pts = np.broadcast_to(rule.points, (n_e,) + rule.points.shape)
    w = wdetJ[:, :, None] * np.asarray(density_times_accel)[None, None, :]
    return _scatter(shell, np.arange(n_e), pts, w)


def _edge_faces(shell: Shell, plane_nodes_mask: np.ndarray) -> list[tuple[int, int, int]]:
    """(element, local edge) of rim faces whose both vertices are selected boundary nodes
    (``plane_nodes_mask (n_plane,)``)."""
    F = shell.mesh.faces
    out = []
    uniq, fe = edges(F)
    count = np.bincount(fe.ravel(), minlength=len(uniq))
    for le, (a, b) in enumerate([(0, 1), (1, 2), (2, 0)]):
        on = (count[fe[:, le]] == 1) & plane_nodes_mask[F[:, a]] & plane_nodes_mask[F[:, b]]
        out += [(e, a, b) for e in np.flatnonzero(on)]
    return out


_CORNER_UV = np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]])  # barycentric (u, v, 1-u-v)


def traction(shell: Shell, plane_mask: np.ndarray, t_vec: np.ndarray) -> np.ndarray:
    """Traction ``t_vec (3,)`` (Pa, per rest area) on the rim faces of the boundary edges
    between selected in-plane nodes ``plane_mask (n_plane,)``."""
    faces = _edge_faces(shell, plane_mask)
    if not faces:
        raise ValueError("traction region contains no boundary edge")
    sp_, sw = line_rule(shell.element.p + 1)
    wp, ww = line_rule(shell.element.q + 1)
    s = (sp_ + 1) / 2
    pts, wts = [], []
    for _, a, b in faces:
        uv = _CORNER_UV[a][None, :] * (1 - s[:, None]) + _CORNER_UV[b][None, :] * s[:, None]
        pts.append([(u, v, w) for w in wp for (u, v) in uv])
        wts.append([wi * si / 2 for wi in ww for si in sw])
    elems = np.array([e for e, _, _ in faces])
    pts, wts = np.array(pts), np.array(wts)
    J = _map(shell, elems, pts)
    ds = J[..., 0] * 0
    for e_i, (_, a, b) in enumerate(faces):
        d_uv = _CORNER_UV[b] - _CORNER_UV[a]
        ds[e_i] = J[e_i, :, :, 0] * d_uv[0] + J[e_i, :, :, 1] * d_uv[1]
    dA = np.linalg.norm(np.cross(ds, J[..., 2]), axis=-1) * wts
    return _scatter(shell, elems, pts, dA[..., None] * np.asarray(t_vec)[None, None, :])


def pressure(shell: Shell, elem_mask: np.ndarray, p: float, top: bool) -> np.ndarray:
    """Pressure ``p`` (Pa) pushing on the top (or bottom) skin of the selected elements
    ``elem_mask (n_elem,)``, along the rest inward normal of that skin (a dead load)."""
    elems = np.flatnonzero(elem_mask)
    if len(elems) == 0:
        raise ValueError("pressure region contains no element")
    tp, tw = _area_rule(shell)
    w0 = 1.0 if top else -1.0
    pts = np.broadcast_to(np.column_stack([tp, np.full(len(tp), w0)]), (len(elems), len(tp), 3))
    J = _map(shell, elems, np.ascontiguousarray(pts))
    n = np.cross(J[..., 0], J[..., 1]) * tw[None, :, None]  # area-weighted outward (for top)
    force = -p * n if top else p * n
    return _scatter(shell, elems, np.ascontiguousarray(pts), force)


def surface_force(shell: Shell, elem_mask: np.ndarray, t_vec: np.ndarray) -> np.ndarray:
    """A force ``t_vec (3,)`` (Pa) per rest mid-surface area of the selected elements
    ``elem_mask (n_elem,)``, of fixed direction (a roof's weight: snow, or self weight given
    per area as the classical shell benchmarks give it), on the mid-surface w = 0: its share of
    each node column follows the element's basis through the thickness there."""
    elems = np.flatnonzero(elem_mask)
    if len(elems) == 0:
        raise ValueError("surface load region contains no element")
    tp, tw = _area_rule(shell)
    pts = np.broadcast_to(np.column_stack([tp, np.zeros(len(tp))]), (len(elems), len(tp), 3))
    pts = np.ascontiguousarray(pts)
    J = _map(shell, elems, pts)
    dA = np.linalg.norm(np.cross(J[..., 0], J[..., 1]), axis=-1) * tw[None, :]
    return _scatter(shell, elems, pts, dA[..., None] * np.asarray(t_vec)[None, None, :])


def _area_rule(shell: Shell) -> tuple[np.ndarray, np.ndarray]:
    """A triangle rule exact for the area of a skin of the element's degree."""
    return triangle_rule(3 if shell.element.p == 1 else 7)


def point_force(shell: Shell, vertex: int, force: np.ndarray) -> np.ndarray:
    """A force (3,) on the node column of mid-surface vertex ``vertex``, split over its layers by
    the through-thickness integrals of the line basis (1/2, 1/2 linear; 1/6, 2/3, 1/6
    quadratic)."""
    wp, ww = line_rule(shell.element.q + 1)
    L, _ = line_lagrange(shell.element.q, wp)
    share = (L * ww[:, None]).sum(0) / 2
    f = np.zeros((shell.n_nodes, 3))
    for k, s in enumerate(share):
        f[k * shell.n_plane + vertex] += s * np.asarray(force)
    return f

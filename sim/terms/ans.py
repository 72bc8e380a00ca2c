"""Assumed natural strains for prisms linear in-plane: the transverse shear tied on the
triangle's edges (MITC3), the thickness strain at its corners.

Strains are covariant in the element's reference coordinates xi = (r, s, w) = (u, v, w):
e_ij = 1/2 (g_i . g_j - G_i . G_j) with g_i = dx/dxi_i, G_i = dX/dxi_i, formed from the
displacement (1/2 (G_i . h_j + h_i . G_j + h_i . h_j), h_i = du/dxi_i) so that a small strain
keeps its digits. At each quadrature point the transverse shear pair (e_rw, e_sw) is replaced by
the lowest-order edge interpolation of its tangential values at three tying points at the point's
own w (Lee and Bathe 2004, MITC3): e_rw at A = (1/2, 0), e_sw at B = (0, 1/2), e_sw - e_rw at
C = (1/2, 1/2), so that each edge's tangential shear is constant along it:

    e~_rw = e_rw^A + s c,   e~_sw = e_sw^B - r c,   c = (e_sw^B - e_rw^A) - (e_sw^C - e_rw^C).

The thickness strain e_ww is tied at the triangle's corners, at the point's own w, and
interpolated linearly between them, e~_ww = (1 - r - s) e_ww^1 + r e_ww^2 + s e_ww^3 (Betsch,
Gruttmann and Stein 1996; Bischoff and Ramm 1997): on a curved shell the corners' directors G_w
differ, and the displacement field's e_ww = G_w . h_w + h_w . h_w / 2 at a point between them
mixes one corner's director with another's rotation, a thickness strain from bending alone
(curvature thickness locking: the pinched hemisphere at 16 cells 0.59 of its reference without
the tying, 0.96 with it, docs/elements-ans.md). At each corner it is the field's, so the
length of a column of nodes is the material's thickness there; between the corners, where the
directors fan out more than at rest (a sheet bent over a radius), the interpolated geometry's
thickness is the chord of their arc, shorter than the material's, and the geometry's volume
less than the material's (the other way round where a curved sheet is flattened).

The modified Green-Lagrange strain E = J^-T e~ J^-1 enters the material through C = I + 2 E; with
a plastic state through C^ = Fp^-T C Fp^-1, i.e. E^ = A^T e~ A + (Fp^-T Fp^-1 - I) / 2 with
A = J^-1 Fp^-1. Every material here is isotropic in the stretches s_i = sqrt(1 + 2 eps_i), eps_i
(and v_i) the eigenvalues (vectors) of E^, so with g = dW/ds, H = d2W/ds2 and the pair
derivatives sym, twist of sim.materials.isotropic.principal:

    dW/dE^ = sum_i S_i v_i v_i^T,             S_i = g_i / s_i,
    d2W = sum_ij h_ij deps_i deps_j + 2 sum_{i<j} kappa_ij (v_i^T dE^ v_j)^2,
    h_ij = H_ij / (s_i s_j) - delta_ij g_i / s_i^3,   kappa_ij = (sym - twist)_ij / (s_i s_j)

(kappa is the divided difference (S_i - S_j) / (eps_i - eps_j), formed without cancellation by
the material's own pair terms). With m_i = A v_i, deps_i = m_i^T de~ m_i.

Hill48 (sim.materials.hill) is a function of C^ too, of its log in the sheet's material axes;
not isotropic, its stress and tangent in the frame v_i are full (not diagonal): dW/dE^ =
M S' M^T with M = (m_1 m_2 m_3) and d2W = x^T Dp x over the unique components x of
M^T de~ M (:func:`sim.materials.hill.hill_green`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from sim.geometry.quadrature import Rule
from sim.geometry.shell import Shell
from sim.materials.hill import HILL48, hill_energy, hill_flow_strain, hill_green, hill_strain6
from sim.materials.isotropic import (
    NEO_HOOKEAN,
    PAIRS,
    clamp_psd,
    clamp_psd_into,
    det3,
    eigh3,
    jacobi3_lanes_into,
    neo_hookean_green,
    principal,
    principal_energy,
    principal_into,
    project3_into,
)
from sim.materials.plasticity import plastic_flow
from sim.solve.assembly import drain_element_gradient
from sim.solve.threads import over_colours, total
from sim.terms import PROJECT_ELEMENT, PROJECT_QP

# tying points in (u, v): A on the edge v = 0, B on u = 0, C on the third edge
TYING = np.array([[0.5, 0.0], [0.0, 0.5], [0.5, 0.5]])
N_TIE = 3
# the thickness strain's tying points: the corners, where the barycentric weights are
# 1 - u - v, u and v
CORNERS = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
# The basis rows of a level (_level_rows) that can be nonzero in a node's columns, by its vertex
# a % 3 (nodes layer-major, the vertices at (1, 0), (0, 1), (0, 0)): dN/dr vanishes at the
# vertex (0, 1), dN/ds at (1, 0), dN/dw at each tying point on the vertex off its edge and at
# each corner on the other vertices. _congruence sums only these; Tying checks the rest are 0.
LIVE_ROWS = ((0, 2, 3, 5, 7), (1, 2, 4, 5, 8), (0, 1, 2, 3, 4, 5, 6))


class Tying:
    """What the ANS kernels need of a shell and a rule, computed once.

    ``dNq (n_qp, n_en, 3)``: reference gradients at the quadrature points; ``dNt (n_lev, 3, n_en,
    3)``: at the tying points A, B, C of each thickness level; ``lev_ptr (n_lev + 1,)``: the
    quadrature points of level l are lev_ptr[l]:lev_ptr[l+1] (the rule is level-major);
    ``rs (n_qp, 2)``: their in-plane coordinates; ``Gq (n_e, n_qp, 3, 3)``: G[k, i] = dX_k/dxi_i,
    ``A0`` its inverse; ``Gt (n_e, n_lev, 3, 3, 3)``: G at the tying points; ``dNc (n_lev, 3,
    n_en)``: dN/dw at each level's corners, the thickness strain's tying points, and ``Gw (n_e,
    n_lev, 3, 3)``: G_w there (corner, component)."""

    def __init__(self, shell: Shell, rule: Rule):
        el = shell.element
        pts = rule.points
        levels, start = np.unique(pts[:, 2], return_index=True)
        order = np.argsort(start)
        levels = levels[order]
        counts = np.array([np.sum(pts[:, 2] == w) for w in levels])
        self.lev_ptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        if not all(np.all(pts[self.lev_ptr[i]:self.lev_ptr[i + 1], 2] == w)
                   for i, w in enumerate(levels)):
            raise ValueError("assumed-strain elements need a level-major prism rule")
        self.rs = np.ascontiguousarray(pts[:, :2])
        _, self.dNq = el.basis(pts)
        tpts = np.array([(u, v, w) for w in levels for (u, v) in TYING])
        _, dNt = el.basis(tpts)
        self.dNt = np.ascontiguousarray(dNt.reshape(len(levels), N_TIE, el.n_nodes, 3))
        Xe = shell.rest[shell.conn]
        self.Gq = np.ascontiguousarray(np.einsum("eak,qai->eqki", Xe, self.dNq))
        self.A0 = np.ascontiguousarray(np.linalg.inv(self.Gq))
        self.Gt = np.ascontiguousarray(np.einsum("eak,ltai->eltki", Xe, self.dNt))
        cpts = np.array([(u, v, w) for w in levels for (u, v) in CORNERS])
        dNc = el.basis(cpts)[1].reshape(len(levels), 3, el.n_nodes, 3)
        self.dNc = np.ascontiguousarray(dNc[..., 2])
        self.Gw = np.ascontiguousarray(np.einsum("eak,lca->elck", Xe, self.dNc))
        # the kernels form dN/dr, dN/ds once per level: a triangle linear in-plane has them
        # the same at every point of a level, to the bit (they are dL/dr times the same Q(w))
        for lev in range(len(levels)):
            inplane = self.dNq[self.lev_ptr[lev], :, :2]
            if not (all(np.array_equal(d[:, :2], inplane)
                        for d in self.dNq[self.lev_ptr[lev]:self.lev_ptr[lev + 1]])
                    and all(np.array_equal(d[:, :2], inplane) for d in self.dNt[lev])
                    and all(np.array_equal(d[:, :2], inplane) for d in dNc[lev])):
                raise ValueError("assumed-strain elements need a prism linear in-plane")
            for a in range(el.n_nodes):
                if not np.all(_basis_rows_zero(self.dNq[self.lev_ptr[lev]], self.dNt[lev],
                                               self.dNc[lev], a)[_dead_rows(a)]):
                    raise ValueError("assumed-strain elements need the prism's vertex order "
                                     "(sim.terms.ans.LIVE_ROWS)")


def _basis_rows_zero(dN: np.ndarray, dNt: np.ndarray, dNc: np.ndarray, a: int) -> np.ndarray:
    """(9,) bool: which of a level's basis rows (:func:`_level_rows`) vanish at node a
    whatever the displacement, from dN (n_en, 3) at a point, dNt (3, n_en, 3) at the tying
    points and dNc (3, n_en) at the corners."""
    r, s = dN[a, 0] == 0.0, dN[a, 1] == 0.0
    return np.array([r, s, r and s, r and dNt[0, a, 2] == 0.0, s and dNt[1, a, 2] == 0.0,
                     r and s and dNt[2, a, 2] == 0.0, dNc[0, a] == 0.0, dNc[1, a] == 0.0,
                     dNc[2, a] == 0.0])


def _dead_rows(a: int) -> np.ndarray:
    return np.setdiff1d(np.arange(9), LIVE_ROWS[a % 3])


@njit(cache=True, inline='always')
def _level_gradients(u: np.ndarray, dNq: np.ndarray, q0: int, dNt: np.ndarray, lev: int,
                     Hs: np.ndarray) -> None:
    """The displacement's reference gradient at level ``lev``'s tying points (``dNt (3 n_lev,
    n_en, 3)``, level-major) and points ``q0, q0 + 1, ...`` of ``dNq`` into ``Hs (3 + n_in, 3,
    3)``, Hn[k, i] = sum_a u[a, k] dN[a, i]: the in-plane columns once, as dN/dr and dN/ds are
    the same at all of them (:class:`Tying` checks it). The tables are indexed, not sliced:
    a slice in numba is a new array whose reference count is taken and dropped, and in the
    element's loops those atomic counts cost more than the sums."""
    n_en = u.shape[0]
    for k in range(3):
        for i in range(2):
            acc = 0.0
            for a in range(n_en):
                acc += u[a, k] * dNq[q0, a, i]
            for t in range(Hs.shape[0]):
                Hs[t, k, i] = acc
        for t in range(3):
            acc = 0.0
            for a in range(n_en):
                acc += u[a, k] * dNt[3 * lev + t, a, 2]
            Hs[t, k, 2] = acc
        for t in range(3, Hs.shape[0]):
            acc = 0.0
            for a in range(n_en):
                acc += u[a, k] * dNq[q0 + t - 3, a, 2]
            Hs[t, k, 2] = acc


@njit(cache=True, inline='always')
def _cov(G: np.ndarray, e: int, p: int, Hs: np.ndarray, t: int, i: int, j: int) -> float:
    """e_ij = 1/2 (G_i . h_j + h_i . G_j + h_i . h_j), G = G[e, p] and h = Hs[t]."""
    acc = 0.0
    for k in range(3):
        acc += (G[e, p, k, i] * Hs[t, k, j] + Hs[t, k, i] * G[e, p, k, j]
                + Hs[t, k, i] * Hs[t, k, j])
    return 0.5 * acc


@njit(cache=True, inline='always')
def _tied(Gt: np.ndarray, e: int, lev: int, Hs: np.ndarray, tv: np.ndarray) -> None:
    """Level ``lev``'s tied values into ``tv (3,)``: e_rw at A, e_sw at B, e_sw - e_rw at C,
    from Hs[:3] (:func:`_level_gradients`); ``Gt (n_e, 3 n_lev, 3, 3)``."""
    t0 = 3 * lev
    tv[0] = _cov(Gt, e, t0, Hs, 0, 0, 2)
    tv[1] = _cov(Gt, e, t0 + 1, Hs, 1, 1, 2)
    tv[2] = _cov(Gt, e, t0 + 2, Hs, 2, 1, 2) - _cov(Gt, e, t0 + 2, Hs, 2, 0, 2)


@njit(cache=True, inline='always')
def _corner_thickness(u: np.ndarray, dNc: np.ndarray, Gw: np.ndarray, e: int, lev: int,
                      hc: np.ndarray, tw: np.ndarray) -> None:
    """Level ``lev``'s thickness strains at its corners into ``tw (3,)``, e_ww = (G_w + h_w / 2)
    . h_w, and h_w there into ``hc (3, 3)`` (corner, component); ``dNc (n_lev, 3, n_en)`` dN/dw
    and ``Gw (n_e, n_lev, 3, 3)`` G_w at the corners."""
    for c in range(3):
        acc = 0.0
        for k in range(3):
            h = 0.0
            for a in range(u.shape[0]):
                h += u[a, k] * dNc[lev, c, a]
            hc[c, k] = h
            acc += (Gw[e, lev, c, k] + 0.5 * h) * h
        tw[c] = acc


@njit(cache=True, inline='always')
def _strain_hat(Gq: np.ndarray, e: int, q: int, Hs: np.ndarray, h: int, r: float, s: float,
                tv: np.ndarray, tw: np.ndarray, A: np.ndarray, plastic: bool,
                fp_inv: np.ndarray, en: np.ndarray, Eh: np.ndarray) -> None:
    """en: the assumed covariant strain e~ (3, 3) at point q, (r, s), its displacement gradient
    Hs[h], from the level's tied shear values ``tv`` (:func:`_tied`) and its corners' thickness
    strains ``tw`` (:func:`_corner_thickness`); Eh: E^ = A^T e~ A (+ the plastic part, from
    ``fp_inv (n_e, n_qp, 3, 3)``)."""
    en[0, 0] = _cov(Gq, e, q, Hs, h, 0, 0)  # the in-plane strains are the field's, the rest tied
    en[1, 1] = _cov(Gq, e, q, Hs, h, 1, 1)
    en[0, 1] = _cov(Gq, e, q, Hs, h, 0, 1)
    c = (tv[1] - tv[0]) - tv[2]
    en[0, 2] = tv[0] + s * c
    en[1, 2] = tv[1] - r * c
    en[2, 2] = (1.0 - r - s) * tw[0] + r * tw[1] + s * tw[2]
    for i in range(3):
        for j in range(i):
            en[i, j] = en[j, i]
    for I in range(3):  # noqa: E741
        for J in range(I, 3):
            acc = 0.0
            for i in range(3):
                for j in range(3):
                    acc += A[i, I] * en[i, j] * A[j, J]
            if plastic:  # (Fp^-T Fp^-1 - I) / 2
                acc += 0.5 * (fp_inv[e, q, 0, I] * fp_inv[e, q, 0, J]
                              + fp_inv[e, q, 1, I] * fp_inv[e, q, 1, J]
                              + fp_inv[e, q, 2, I] * fp_inv[e, q, 2, J] - (1.0 if I == J else 0.0))
            Eh[I, J] = acc
            Eh[J, I] = acc


@njit(cache=True, inline='always')
def _map(A0: np.ndarray, e: int, q: int, plastic: bool, fp_inv: np.ndarray,
         A: np.ndarray) -> None:
    """A = J^-1 Fp^-1 at point q (J^-1 alone without a plastic state)."""
    for i in range(3):
        for J in range(3):
            if plastic:
                A[i, J] = (A0[e, q, i, 0] * fp_inv[e, q, 0, J] + A0[e, q, i, 1] * fp_inv[e, q, 1, J]
                           + A0[e, q, i, 2] * fp_inv[e, q, 2, J])
            else:
                A[i, J] = A0[e, q, i, J]


@njit(cache=True, inline='always')
def _tie_rows(dNt: np.ndarray, Gt: np.ndarray, e: int, t0: int, Hs: np.ndarray, P: np.ndarray,
              r0: int) -> None:
    """The tied shear rows into P[r0 + 3], P[r0 + 4], P[r0 + 5] (node-major DoF 3 a + k): de_rw
    at A, de_sw at B and de_sw - de_rw at C, the tying points t0, t0 + 1, t0 + 2 of dNt and Gt
    (level-major), Hs[0], Hs[1], Hs[2] their displacement gradients; de_iw/du = 1/2 (g_i dN_w +
    g_w dN_i). Stored in one pass, each entry once."""
    tA, tB, tC = t0, t0 + 1, t0 + 2
    for k in range(3):
        gAr, gAw = Gt[e, tA, k, 0] + Hs[0, k, 0], Gt[e, tA, k, 2] + Hs[0, k, 2]
        gBs, gBw = Gt[e, tB, k, 1] + Hs[1, k, 1], Gt[e, tB, k, 2] + Hs[1, k, 2]
        gCr, gCs = Gt[e, tC, k, 0] + Hs[2, k, 0], Gt[e, tC, k, 1] + Hs[2, k, 1]
        gCw = Gt[e, tC, k, 2] + Hs[2, k, 2]
        for a in range(dNt.shape[1]):
            p = 3 * a + k
            P[r0 + 3, p] = 0.5 * (gAr * dNt[tA, a, 2] + gAw * dNt[tA, a, 0])
            P[r0 + 4, p] = 0.5 * (gBs * dNt[tB, a, 2] + gBw * dNt[tB, a, 1])
            P[r0 + 5, p] = (0.5 * (gCs * dNt[tC, a, 2] + gCw * dNt[tC, a, 1])
                            - 0.5 * (gCr * dNt[tC, a, 2] + gCw * dNt[tC, a, 0]))


# natural strain components in row order: rr, ss, ww, rs, rw, sw
VOIGT = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))
# VOIGT's and PAIRS's rows and columns apart, as tuples: numba reads a global tuple as a
# constant, where a global array's every read in a loop took and dropped a reference count
VOIGT_I, VOIGT_J = tuple(i for i, _ in VOIGT), tuple(j for _, j in VOIGT)
PAIRS_I, PAIRS_J = tuple(int(i) for i in PAIRS[:, 0]), tuple(int(j) for j in PAIRS[:, 1])


@njit(cache=True, inline='always')
def _to_natural(bt: np.ndarray, ia: int, Sh: np.ndarray, js: int, Sn: np.ndarray,
                jn: int) -> None:
    """Sn[jn] = A Sh[js] A^T, A = bt[ia]: a stress of the E^ frame as the contravariant natural
    components. The 3 x 3s by their index in a stack, not as views: each view or array handed
    to a function is a reference count taken and dropped, per point."""
    for i in range(3):
        for j in range(i, 3):
            acc = 0.0
            for I in range(3):  # noqa: E741
                for J in range(3):
                    acc += bt[ia, i, I] * Sh[js, I, J] * bt[ia, j, J]
            Sn[jn, i, j] = acc
            Sn[jn, j, i] = acc


@njit(cache=True)
def _neo_hookean_natural(bt: np.ndarray, b: int, mu: float, lam: float, want: int,
                         m3: np.ndarray, Dv: np.ndarray) -> float:
    """Neo-Hookean in closed form, no eigen-decomposition, at E^ = bt[b] with A = bt[3 + b]
    (:func:`_ans_block`'s stack): W; for want >= 1 the natural stress Sn = m3[1] = A S^ A^T
    with S^ = 2 mu C^-1 E^ + lam ln J C^-1 (= mu (I - C^-1) + lam ln J C^-1, without its
    cancellation at small strain); for want == 2 the natural tangent
    Dv = lam g g + (mu - lam ln J) (g g + g g) over the rows, g = A C^-1 A^T. Scratch: m3[2],
    m3[4]. The arrays are stacks indexed here (:func:`_to_natural`)."""
    W, lj = neo_hookean_green(bt[b], mu, lam)
    if want == 0 or not np.isfinite(W):
        return W
    c00, c11, c22 = 1.0 + 2.0 * bt[b, 0, 0], 1.0 + 2.0 * bt[b, 1, 1], 1.0 + 2.0 * bt[b, 2, 2]
    c01, c02, c12 = 2.0 * bt[b, 0, 1], 2.0 * bt[b, 0, 2], 2.0 * bt[b, 1, 2]
    m3[4, 0, 0] = c11 * c22 - c12 * c12
    m3[4, 1, 1] = c00 * c22 - c02 * c02
    m3[4, 2, 2] = c00 * c11 - c01 * c01
    m3[4, 0, 1] = m3[4, 1, 0] = c02 * c12 - c01 * c22
    m3[4, 0, 2] = m3[4, 2, 0] = c01 * c12 - c02 * c11
    m3[4, 1, 2] = m3[4, 2, 1] = c01 * c02 - c00 * c12
    det = c00 * m3[4, 0, 0] + c01 * m3[4, 0, 1] + c02 * m3[4, 0, 2]
    for i in range(3):
        for j in range(3):
            m3[4, i, j] /= det
    for i in range(3):  # S^ into m3[2] (scratch), then to natural
        for j in range(3):
            m3[2, i, j] = (2.0 * mu * (m3[4, i, 0] * bt[b, 0, j] + m3[4, i, 1] * bt[b, 1, j]
                                       + m3[4, i, 2] * bt[b, 2, j]) + lam * lj * m3[4, i, j])
    _to_natural(bt, 3 + b, m3, 2, m3, 1)
    if want < 2:
        return W
    _to_natural(bt, 3 + b, m3, 4, m3, 2)
    c = mu - lam * lj
    for v in range(6):  # symmetric but for the products' round-off: the upper half, mirrored
        i, j = VOIGT_I[v], VOIGT_J[v]
        mv = 1.0 if i == j else 2.0
        for u in range(v, 6):
            k, ll = VOIGT_I[u], VOIGT_J[u]
            mu_ = 1.0 if k == ll else 2.0
            d = mv * mu_ * (lam * m3[2, i, j] * m3[2, k, ll]
                            + c * (m3[2, i, k] * m3[2, j, ll] + m3[2, i, ll] * m3[2, j, k]))
            Dv[v, u] = d
            Dv[u, v] = d
    return W


@njit(cache=True)
def _principal_natural(model: int, lam: np.ndarray, V: np.ndarray, A: np.ndarray,  # noqa: C901
                       params: np.ndarray, ep: float, want: int, psd: bool, Sn: np.ndarray,
                       Dv: np.ndarray, M: np.ndarray, cv: np.ndarray, Dp: np.ndarray,
                       m3: np.ndarray, v3: np.ndarray) -> float:
    """Any isotropic model through the principal frame of E^ (module docstring), its
    eigenvalues ``lam (3,)`` ascending and vectors ``V (3, 3)``, for want >= 1 (an energy
    alone is :func:`_point_energy`'s): W, Sn and Dv as :func:`_neo_hookean_natural`;
    ``psd``: Dv projected to positive semi-definite, which in that frame is the 3 x 3 block's
    eigenvalues and the pairs' clamped at zero.
    Scratch: M (3, 3), cv (2, 6, 6), Dp (6, 6), m3 (2, 3, 3), v3 (9, 3)."""
    st, pr = v3[7], v3[:7]
    if not 1.0 + 2.0 * lam[0] > 0.0:
        return np.inf
    for i in range(3):
        st[i] = np.sqrt(1.0 + 2.0 * lam[i])
    W = principal_into(model, st, params, ep, pr)
    if not np.isfinite(W):
        return W
    gs, H, sym, twist = pr[0], pr[1:4], pr[4], pr[5]
    _columns(A, V, M)
    Sp0, Sp1, Sp2 = gs[0] / st[0], gs[1] / st[1], gs[2] / st[2]
    for i in range(3):
        for j in range(3):
            Sn[i, j] = Sp0 * M[i, 0] * M[j, 0] + Sp1 * M[i, 1] * M[j, 1] + Sp2 * M[i, 2] * M[j, 2]
    if want < 2:
        return W
    for c in range(6):
        for d in range(6):
            Dp[c, d] = 0.0
    for a in range(3):
        for b in range(3):
            Dp[a, b] = H[a, b] / (st[a] * st[b])
        Dp[a, a] -= gs[a] / st[a] ** 3
    for c in range(3):
        a, b = PAIRS_I[c], PAIRS_J[c]
        Dp[3 + c, 3 + c] = 2.0 * (sym[c] - twist[c]) / (st[a] * st[b])
    if psd:
        project3_into(Dp, m3[0], v3[8], m3[1])
        for c in range(3, 6):
            Dp[c, c] = max(Dp[c, c], 0.0)
    _natural_tangent(M, Dp, cv, Dv, True)
    return W


@njit(cache=True, inline='always')
def _point_energy(model: int, closed: bool, Ehs: np.ndarray, lams: np.ndarray, Vs: np.ndarray,
                  b: int, params: np.ndarray, frames: np.ndarray, e: int, ep: float,
                  cl: np.ndarray, Vm: np.ndarray, w6: np.ndarray) -> float:
    """W alone of the law at E^ ``Ehs[b]``: Neo-Hookean's closed form (``closed``), else the
    law's at E^'s eigenvalues ``lams[b] (3,)`` ascending (Hill48 with its vectors ``Vs[b]`` in
    the material axes ``frames[e]``; scratch: cl (3,) for the log strain, Vm (3, 3) and w6
    (2, 6) of :func:`sim.materials.hill.hill_energy`)."""
    if closed:
        return neo_hookean_green(Ehs[b], params[0], params[1])[0]
    if not 1.0 + 2.0 * lams[b, 0] > 0.0:
        return np.inf
    if model == HILL48:  # the log strain as hill_green forms it from C^'s eigenvalues
        for i in range(3):
            cl[i] = 0.5 * np.log(1.0 + 2.0 * lams[b, i])
        return hill_energy(cl, Vs[b], params, frames[e], ep, Vm, w6)
    return principal_energy(model, np.sqrt(1.0 + 2.0 * lams[b, 0]),
                            np.sqrt(1.0 + 2.0 * lams[b, 1]), np.sqrt(1.0 + 2.0 * lams[b, 2]),
                            params, ep)


@njit(cache=True, inline='always')
def _columns(A: np.ndarray, V: np.ndarray, M: np.ndarray) -> None:
    """M = A V: the columns m_a = A v_a, E^'s eigenvectors as natural components."""
    for i in range(3):
        for a in range(3):
            M[i, a] = A[i, 0] * V[0, a] + A[i, 1] * V[1, a] + A[i, 2] * V[2, a]


@njit(cache=True, inline='always')
def _natural_tangent(M: np.ndarray, Dp: np.ndarray, cv: np.ndarray, Dv: np.ndarray,
                     block: bool) -> None:
    """Dv = cv^T Dp cv: a tangent ``Dp`` over the unique components of X = M^T de~ M (the
    diagonal m_a^T de~ m_a, then the pairs m_a^T de~ m_b of PAIRS) over the natural rows,
    X's components being cv[0] (6, 6) times those rows; cv[1] scratch for Dp cv. Formed as
    cv^T (Dp cv), its upper triangle mirrored: Dp is symmetric, and a point's tangent is
    most of the assumed-strain element's arithmetic after the Hessian's congruence."""
    C, DC = cv[0], cv[1]
    for c in range(6):
        a, b = (c, c) if c < 3 else (PAIRS_I[c - 3], PAIRS_J[c - 3])
        for v in range(6):
            i, j = VOIGT_I[v], VOIGT_J[v]
            C[c, v] = M[i, a] * M[j, b] + (M[j, a] * M[i, b] if i != j else 0.0)
    for c in range(6):
        # an isotropic Dp (``block``) is its 3 x 3 block and the pairs' diagonal: the rest of
        # its row adds zeros
        d0, d1 = (0, 6) if not block else ((0, 3) if c < 3 else (c, c + 1))
        for u in range(6):
            acc = 0.0
            for d in range(d0, d1):
                acc += Dp[c, d] * C[d, u]
            DC[c, u] = acc
    for v in range(6):
        for u in range(v, 6):
            acc = 0.0
            for c in range(6):
                acc += C[c, v] * DC[c, u]
            Dv[v, u] = acc
            Dv[u, v] = acc


@njit(cache=True)
def _hill_natural(lam: np.ndarray, V: np.ndarray, A: np.ndarray, params: np.ndarray,
                  frame: np.ndarray, ep: float, want: int, psd: bool, Sn: np.ndarray,
                  Dv: np.ndarray, M: np.ndarray, cv: np.ndarray, Dp: np.ndarray, Sp: np.ndarray,
                  v3: np.ndarray, q6: np.ndarray) -> float:
    """Hill48 in the frame of E^'s eigenvectors (module docstring; ``lam``, ``V`` as
    :func:`_principal_natural` takes them, the vectors for an energy too): W, Sn and Dv as
    :func:`_neo_hookean_natural`, ``psd`` as :func:`_principal_natural` (Hill's Dp is full:
    its eigenvalues). Scratch: M, Sp (3, 3), cv (2, 6, 6), Dp (6, 6), v3 (>= 8, 3),
    q6 (8, 6)."""
    cl = v3[7]
    if not 1.0 + 2.0 * lam[0] > 0.0:
        return np.inf
    for i in range(3):
        cl[i] = 1.0 + 2.0 * lam[i]
    W = hill_green(cl, V, params, frame, ep, want, Sp, Dp)
    if want == 0 or not np.isfinite(W):
        return W
    _columns(A, V, M)
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for a in range(3):
                for b in range(3):
                    acc += M[i, a] * Sp[a, b] * M[j, b]
            Sn[i, j] = acc
    if want == 2:
        if psd:
            _project_into(Dp, q6)
        _natural_tangent(M, Dp, cv, Dv, False)
    return W


@njit(cache=True, inline='always')
def _level_rows(dNq: np.ndarray, q0: int, dNt: np.ndarray, Gq: np.ndarray, Gt: np.ndarray,
                e: int, lev: int, Hs: np.ndarray, dNc: np.ndarray, Gw: np.ndarray,
                hc: np.ndarray, P: np.ndarray, r0: int) -> None:
    """Level ``lev``'s basis rows into ``P[r0:r0 + 9]`` (k columns), node-major: de_rr, de_ss,
    de_rs (the same at every point of a level: g_r, g_s and dN/dr, dN/ds do not vary in-plane
    for a triangle linear in-plane; dNq and Gq at its point q0, ``Hs[3]`` the displacement's
    reference gradient there), the tied shear rows (A's e_rw, B's e_sw, C's e_sw - e_rw;
    ``Hs[:3]`` at A, B, C) and de_ww at the three corners (dNc, Gw and ``hc`` as
    :func:`_corner_thickness` takes and gives them); every strain row of the level is a
    combination of these (:func:`_add_point_tangent`)."""
    _tie_rows(dNt, Gt, e, 3 * lev, Hs, P, r0)
    for a in range(dNq.shape[1]):
        d0, d1 = dNq[q0, a, 0], dNq[q0, a, 1]
        for kk in range(3):
            p = 3 * a + kk
            g0, g1 = Gq[e, q0, kk, 0] + Hs[3, kk, 0], Gq[e, q0, kk, 1] + Hs[3, kk, 1]
            P[r0, p] = g0 * d0
            P[r0 + 1, p] = g1 * d1
            P[r0 + 2, p] = 0.5 * (g0 * d1 + g1 * d0)
            for c in range(3):
                P[r0 + 6 + c, p] = (Gw[e, lev, c, kk] + hc[c, kk]) * dNc[lev, c, a]


@njit(cache=True, inline='always')
def _add_point_tangent(Dv: np.ndarray, w: float, r: float, s: float, Mb: np.ndarray) -> None:
    """Mb (upper triangle) += w Phi^T Dv Phi, Phi (6, 9) the natural rows (VOIGT order) of the
    level's point at (r, s) over the level's basis rows (:func:`_level_rows`): rr, ss, rs are
    the basis rows 0, 1, 2 themselves, the shear pair the MITC3 interpolation z0, z1 of the
    tied rows 3, 4, 5 and ww the corners' rows 6, 7, 8 weighted z2 = (1 - r - s, r, s)
    (:func:`_strain_hat`), so Phi's product is a few sums by blocks."""
    z0 = (1.0 - s, s, -s)  # e~_rw, e~_sw over the tied rows A, B, C
    z1 = (r, 1.0 - r, r)
    z2 = (1.0 - r - s, r, s)  # e~_ww over the corners
    single = (0, 1, 3)  # the natural rows rr, ss, rs: basis rows 0, 1, 2
    for a in range(3):
        na = single[a]
        for b in range(a, 3):
            Mb[a, b] += w * Dv[na, single[b]]
        ds0, ds1, dw = w * Dv[na, 4], w * Dv[na, 5], w * Dv[na, 2]
        for t in range(3):
            Mb[a, 3 + t] += ds0 * z0[t] + ds1 * z1[t]
            Mb[a, 6 + t] += dw * z2[t]
    d44, d45, d55 = w * Dv[4, 4], w * Dv[4, 5], w * Dv[5, 5]
    d42, d52, d22 = w * Dv[4, 2], w * Dv[5, 2], w * Dv[2, 2]
    for t in range(3):
        s0, s1 = z0[t], z1[t]
        for t2 in range(t, 3):
            Mb[3 + t, 3 + t2] += (s0 * (d44 * z0[t2] + d45 * z1[t2])
                                  + s1 * (d45 * z0[t2] + d55 * z1[t2]))
            Mb[6 + t, 6 + t2] += d22 * z2[t] * z2[t2]
        sw = s0 * d42 + s1 * d52
        for t2 in range(3):
            Mb[3 + t, 6 + t2] += sw * z2[t2]


@njit(cache=True, inline='always')
def _level_geometric(dNq: np.ndarray, q0: int, dNt: np.ndarray, dNc: np.ndarray, lev: int,
                     gv: np.ndarray, v: np.ndarray, Kg: np.ndarray) -> None:
    """Kg (upper, node b >= a) += level ``lev``'s initial-stress term dN_a^T sig dN_b from its
    stresses over the basis rows ``gv (9,)`` (:func:`_ans_block`: sum_q w Phi^T Sv, the
    stress each basis row carries): S_rr, S_ss and 2 S_rs summed over the level's points
    (dNq at any of them, q0), the tied shear's at the tying points A, B, C (tA, tB, tC) and
    the thickness stress at the corners (dNc, dN/dw there). dN/dr, dN/ds are the same at all
    of them (:class:`Tying`), so the shear's terms are dN/dr (x) v_r + dN/ds (x) v_s and
    transposes, v_r = (tA dN^A/dw - tC dN^C/dw) / 2, v_s = (tB dN^B/dw + tC dN^C/dw) / 2,
    formed once per node into the scratch ``v (2, n_en)``."""
    n = Kg.shape[0]
    srr, sss, srs = gv[0], gv[1], 0.5 * gv[2]
    hA, hB, hC = 0.5 * gv[3], 0.5 * gv[4], 0.5 * gv[5]
    tA, tB, tC = 3 * lev, 3 * lev + 1, 3 * lev + 2
    for a in range(n):
        v[0, a] = hA * dNt[tA, a, 2] - hC * dNt[tC, a, 2]
        v[1, a] = hB * dNt[tB, a, 2] + hC * dNt[tC, a, 2]
    for a in range(n):
        ar, as_ = dNq[q0, a, 0], dNq[q0, a, 1]
        tr, ts = srr * ar + srs * as_ + v[0, a], srs * ar + sss * as_ + v[1, a]
        w0, w1, w2 = gv[6] * dNc[lev, 0, a], gv[7] * dNc[lev, 1, a], gv[8] * dNc[lev, 2, a]
        for b in range(a, n):
            acc = tr * dNq[q0, b, 0] + ts * dNq[q0, b, 1] + v[0, b] * ar + v[1, b] * as_
            acc += w0 * dNc[lev, 0, b]
            acc += w1 * dNc[lev, 1, b]
            acc += w2 * dNc[lev, 2, b]
            Kg[a, b] += acc


@njit(cache=True, inline='always')
def _material_rows(P: np.ndarray, Mb: np.ndarray, T: np.ndarray, r0: int) -> None:
    """T = Mb P on a level's nine rows r0 to r0 + 9 of P and T ``(n_r, k)``, ``Mb (9, 9)``:
    each row of T in one pass over its columns, contiguous, which vectorise, so that each
    entry of T is stored once (a pass per three rows of P, each adding into T, loaded and
    stored it three times). Indexed, not sliced into rows (:func:`_level_gradients`), over
    unsigned indices: numba then adds no wraparound test."""
    uk = np.uint64(P.shape[1])
    ur = np.uint64(r0)
    for c in range(9):
        m0, m1, m2 = Mb[c, 0], Mb[c, 1], Mb[c, 2]
        m3, m4, m5 = Mb[c, 3], Mb[c, 4], Mb[c, 5]
        m6, m7, m8 = Mb[c, 6], Mb[c, 7], Mb[c, 8]
        uc = ur + np.uint64(c)
        for col in range(uk):
            T[uc, col] = ((((m0 * P[ur, col] + m1 * P[ur + 1, col]) + m2 * P[ur + 2, col])
                           + ((m3 * P[ur + 3, col] + m4 * P[ur + 4, col]) + m5 * P[ur + 5, col]))
                          + ((m6 * P[ur + 6, col] + m7 * P[ur + 7, col]) + m8 * P[ur + 8, col]))


@njit(cache=True, inline='always')
def _congruence(P: np.ndarray, T: np.ndarray, K: np.ndarray) -> None:  # noqa: C901
    """K (upper triangle) = P^T T, the material part sum_l P_l^T Mb_l P_l of all levels at
    once (rows of P and T stacked, ``(n_r, k)``, n_r a multiple of 9). A node's three rows of
    K at a time, from its diagonal block on, in one pass over the columns per level: the
    column loops are contiguous and vectorise, and each entry of T is loaded once per node,
    not once per row. The lower triangle, which nothing reads (the scatter, the
    initial-stress term and the element's projection take the upper), would double the
    arithmetic; the node's diagonal block is formed whole. A node's rows sum only the basis
    rows alive there (LIVE_ROWS, checked by :class:`Tying`), in the order of all nine: the
    others' products are zeros, and dropping them changes no bit of K. The three vertex kinds'
    loops are written out, alike but for their rows: a helper taking the rows would count its
    five array arguments at every call, per node and level (numba's reference counts)."""
    nr, k = P.shape
    uk = np.uint64(k)
    for a in range(k // 3):
        p = 3 * a
        up = np.uint64(p)
        k0, k1, k2 = K[p], K[p + 1], K[p + 2]
        for c in range(0, nr, 9):
            t = T[c:c + 9]
            first = c == 0  # the first level's sums are stored, not added to zeros
            if a % 3 == 0:  # LIVE_ROWS[0]
                x0, x2, x3, x5, x7 = P[c, p], P[c + 2, p], P[c + 3, p], P[c + 5, p], P[c + 7, p]
                y0, y2, y3 = P[c, p + 1], P[c + 2, p + 1], P[c + 3, p + 1]
                y5, y7 = P[c + 5, p + 1], P[c + 7, p + 1]
                z0, z2, z3 = P[c, p + 2], P[c + 2, p + 2], P[c + 3, p + 2]
                z5, z7 = P[c + 5, p + 2], P[c + 7, p + 2]
                for col in range(up, uk):
                    t0, t2, t3, t5, t7 = t[0, col], t[2, col], t[3, col], t[5, col], t[7, col]
                    s0 = ((x0 * t0 + x2 * t2) + (x3 * t3 + x5 * t5)) + x7 * t7
                    s1 = ((y0 * t0 + y2 * t2) + (y3 * t3 + y5 * t5)) + y7 * t7
                    s2 = ((z0 * t0 + z2 * t2) + (z3 * t3 + z5 * t5)) + z7 * t7
                    k0[col] = s0 if first else k0[col] + s0
                    k1[col] = s1 if first else k1[col] + s1
                    k2[col] = s2 if first else k2[col] + s2
            elif a % 3 == 1:  # LIVE_ROWS[1]
                x1, x2, x4, x5, x8 = (P[c + 1, p], P[c + 2, p], P[c + 4, p], P[c + 5, p],
                                      P[c + 8, p])
                y1, y2, y4 = P[c + 1, p + 1], P[c + 2, p + 1], P[c + 4, p + 1]
                y5, y8 = P[c + 5, p + 1], P[c + 8, p + 1]
                z1, z2, z4 = P[c + 1, p + 2], P[c + 2, p + 2], P[c + 4, p + 2]
                z5, z8 = P[c + 5, p + 2], P[c + 8, p + 2]
                for col in range(up, uk):
                    t1, t2, t4, t5, t8 = t[1, col], t[2, col], t[4, col], t[5, col], t[8, col]
                    s0 = ((x1 * t1 + x2 * t2) + (x4 * t4 + x5 * t5)) + x8 * t8
                    s1 = ((y1 * t1 + y2 * t2) + (y4 * t4 + y5 * t5)) + y8 * t8
                    s2 = ((z1 * t1 + z2 * t2) + (z4 * t4 + z5 * t5)) + z8 * t8
                    k0[col] = s0 if first else k0[col] + s0
                    k1[col] = s1 if first else k1[col] + s1
                    k2[col] = s2 if first else k2[col] + s2
            else:  # LIVE_ROWS[2]: rows 0 to 6
                x0, x1, x2, x3 = P[c, p], P[c + 1, p], P[c + 2, p], P[c + 3, p]
                x4, x5, x6 = P[c + 4, p], P[c + 5, p], P[c + 6, p]
                y0, y1, y2, y3 = P[c, p + 1], P[c + 1, p + 1], P[c + 2, p + 1], P[c + 3, p + 1]
                y4, y5, y6 = P[c + 4, p + 1], P[c + 5, p + 1], P[c + 6, p + 1]
                z0, z1, z2, z3 = P[c, p + 2], P[c + 1, p + 2], P[c + 2, p + 2], P[c + 3, p + 2]
                z4, z5, z6 = P[c + 4, p + 2], P[c + 5, p + 2], P[c + 6, p + 2]
                for col in range(up, uk):
                    t0, t1, t2, t3 = t[0, col], t[1, col], t[2, col], t[3, col]
                    t4, t5, t6 = t[4, col], t[5, col], t[6, col]
                    s0 = ((((x0 * t0 + x1 * t1) + x2 * t2) + ((x3 * t3 + x4 * t4) + x5 * t5))
                          + x6 * t6)
                    s1 = ((((y0 * t0 + y1 * t1) + y2 * t2) + ((y3 * t3 + y4 * t4) + y5 * t5))
                          + y6 * t6)
                    s2 = ((((z0 * t0 + z1 * t1) + z2 * t2) + ((z3 * t3 + z4 * t4) + z5 * t5))
                          + z6 * t6)
                    k0[col] = s0 if first else k0[col] + s0
                    k1[col] = s1 if first else k1[col] + s1
                    k2[col] = s2 if first else k2[col] + s2


@njit(cache=True, inline='always')
def _project_into(K: np.ndarray, q: np.ndarray) -> None:
    """:func:`_project` of a small K (n, n) on the scratch ``q (n + 2, n)``: a point's Hill48
    tangent, an element's initial-stress term (sim.materials.isotropic.clamp_psd_into)."""
    n = K.shape[0]
    for p in range(n):
        for c in range(p):
            K[p, c] = K[c, p]
    clamp_psd_into(K, q[:n], q[n], q[n + 1])


@njit(cache=True)
def _project(K: np.ndarray) -> None:
    """K (upper triangle) <- its projection to positive semi-definite (both triangles): an
    element's Hessian (PROJECT_ELEMENT)."""
    k = K.shape[0]
    for p in range(k):
        for c in range(p):
            K[p, c] = K[c, p]
    clamp_psd(K)


def ans_kernel(x: np.ndarray, rest: np.ndarray, conn: np.ndarray, dNq: np.ndarray,
               dNt: np.ndarray, lev_ptr: np.ndarray, rs: np.ndarray, Gq: np.ndarray,
               A0: np.ndarray, Gt: np.ndarray, dNc: np.ndarray, Gw: np.ndarray,
               wdetJ: np.ndarray, model: int, params: np.ndarray,
               fp_inv: np.ndarray, ep: np.ndarray, frames: np.ndarray, plastic: bool, want: int,
               project: int,
               order: np.ndarray, block_ptr: np.ndarray, color_ptr: np.ndarray,
               slots: np.ndarray, grad: np.ndarray, data: np.ndarray) -> float:
    """:func:`sim.terms.elasticity.elastic_kernel` for assumed-strain elements: same arguments
    and scatter (``frames`` as there), the element's geometry from :class:`Tying` (Gq, A0,
    Gt, Gw per element). ``project``: PROJECT_QP by the Hessian's parts (:func:`_ans_elements`),
    PROJECT_ELEMENT the element's whole Hessian (an eigen-decomposition of its 3 n_en x 3 n_en
    matrix, most of the evaluation's time)."""
    energies = np.zeros(conn.shape[0])
    over_colours(_ans_block, order, block_ptr, color_ptr, x, rest, conn,
                 (dNq, dNt, lev_ptr, rs, Gq, A0, Gt, dNc, Gw), wdetJ, model, params, fp_inv, ep,
                 frames, plastic, want, project, slots, grad, data, energies, scatter=want > 0)
    return total(energies)


@njit(cache=True, nogil=True)
def _ans_block(x: np.ndarray, rest: np.ndarray, conn: np.ndarray, tying: tuple,  # noqa: C901
               wdetJ: np.ndarray, model: int, params: np.ndarray, fp_inv: np.ndarray,
               ep: np.ndarray, frames: np.ndarray, plastic: bool, want: int, project: int,
               slots: np.ndarray, grad: np.ndarray, data: np.ndarray, energies: np.ndarray,
               elements: np.ndarray) -> None:
    """A thread's share of a colour's blocks in :func:`ans_kernel`: each element e of its
    ``elements``, its energy into energies[e], its gradient (want >= 1) through ``g (k,)``
    into ``grad``, its Hessian (want == 2) through ``K (k, k)``, its upper triangle
    node-major, into ``data`` at ``slots[e]``; an element with an inverted point or one
    without energy has E = inf, and nothing is added. ``frames[e] (3, 3)``: its material
    axes (read by Hill48). ``project``: PROJECT_QP makes the Hessian positive
    semi-definite by its parts: each point's material tangent (over the natural strain rows,
    as a point's is in Q3T's projection) and the element's initial-stress term (n_en x n_en:
    the tied strains' stresses act at the tying points, so it has no per-point split); a sum
    of positive semi-definite parts, without the element's 3 n_en x 3 n_en
    eigen-decomposition that PROJECT_ELEMENT takes (:func:`ans_kernel`).

    Per level, the points' strain rows are combinations Phi of the level's basis rows P, so
    the material part is summed as P^T (sum_q w Phi^T D Phi) P, one product of the 9 rows
    per level instead of one of 6 rows per point; the levels' rows are stacked so that one
    product :func:`_congruence` forms all of it. Scratch, made once for the share's elements:
    Kg (n_en, n_en); P and T (9 n_lev, k), level l's rows from 9 l on; Mb (9, 9), Hs (3 +
    n_in, 3, 3) (:func:`_level_gradients`), u (n_en, 3); 3 x 3s (en, Sn, a scratch, M, Ci, hc, and
    m2 (2, 3, 3) for :func:`_principal_natural`); three points' E^, A, E^'s eigenvectors
    (3, 3, 3) and eigenvalues (3, 3); Dv, Dp (6, 6) and cv (2, 6, 6); gv (9,), tv, tw (3,); v3
    (9, 3); kq (n_en + 10, max(n_en, 6)), the projections' (a point's 6 x 6 in 8 rows, Kg's in
    n_en + 2); vg (2, n_en) (:func:`_level_geometric`). The tables and scratch are indexed,
    not sliced, in the loops over levels and points (:func:`_level_gradients`), and the loop
    over the elements is this function's, not a loop around an inlined function of one
    element: an inlined function takes a reference count of each array it is given, at every
    call."""
    dNq, dNt_lev, lev_ptr, rs, Gq, A0, Gt_lev, dNc, Gw = tying
    n_en = conn.shape[1]
    k = 3 * n_en
    n_lev = lev_ptr.shape[0] - 1
    n_in = lev_ptr[1] - lev_ptr[0]
    # the levels' tying points on one axis, as the points are on dNq's and Gq's
    dNt = dNt_lev.reshape((3 * n_lev, n_en, 3))
    Gt = Gt_lev.reshape((Gt_lev.shape[0], 3 * n_lev, 3, 3))
    nbp = 9  # a level's rows (_level_rows, _material_rows)
    nr = n_lev * nbp  # a multiple of 9 (_congruence)
    g = np.zeros(k)
    Kg = np.empty((n_en, n_en))
    P, T, Mb = np.zeros((nr, k)), np.zeros((nr, k)), np.zeros((nbp, nbp))
    K = np.empty((k, k) if want == 2 else (0, 0))
    Hs, u = np.empty((3 + n_in, 3, 3)), np.empty((n_en, 3))
    m3, bt, sc = np.empty((8, 3, 3)), np.empty((10, 3, 3)), np.empty((4, 6, 6))
    gvs, v3 = np.empty((3, nbp)), np.empty((9, 3))
    kq, vg = np.empty((n_en + 10, max(n_en, 6))), np.empty((2, n_en))
    en, Sn, M, Ci, hc, m2 = m3[0], m3[1], m3[3], m3[4], m3[5], m3[6:]
    Ehs, As, Vs, lams = bt[0:3], bt[3:6], bt[6:9], bt[9]
    Dv, Dp, cv = sc[0], sc[3], sc[1:3]
    gv, tv, tw = gvs[0], gvs[1, :3], gvs[2, :3]
    cl, w6, kqh, kqg = v3[7], kq[n_en + 2:n_en + 4, :6], kq[n_en + 2:, :6], kq[:n_en + 2]
    psd = want == 2 and project == PROJECT_QP
    # Neo-Hookean's closed form, where no principal frame is needed to project in
    closed = model == NEO_HOOKEAN and not psd
    for e in elements:
        for a in range(n_en):
            for i in range(3):
                u[a, i] = x[conn[e, a], i] - rest[conn[e, a], i]
        if want == 2:
            for a in range(n_en):
                for b in range(n_en):
                    Kg[a, b] = 0.0
        E = 0.0
        ok = True  # False: an inverted point, or one without energy
        for lev in range(lev_ptr.shape[0] - 1):
            q0 = lev_ptr[lev]
            n_in = lev_ptr[lev + 1] - q0
            r0 = lev * nbp  # the level's rows in P and T
            _level_gradients(u, dNq, q0, dNt, lev, Hs)
            _corner_thickness(u, dNc, Gw, e, lev, hc, tw)
            _tied(Gt, e, lev, Hs, tv)
            if want >= 1:
                _level_rows(dNq, q0, dNt, Gq, Gt, e, lev, Hs, dNc, Gw, hc, P, r0)
                for c in range(nbp):
                    gv[c] = 0.0
                    for d in range(nbp):
                        Mb[c, d] = 0.0
            # the points three at a time: their strains first, E^'s eigen-decompositions side
            # by side (jacobi3_lanes_into), then each point's law
            for j0 in range(0, n_in, 3):
                nb = min(3, n_in - j0)
                for b in range(nb):
                    q = q0 + j0 + b
                    h = 3 + j0 + b
                    for i in range(3):  # g = G + h: an inverted element has no energy
                        for jj in range(3):
                            en[i, jj] = Gq[e, q, i, jj] + Hs[h, i, jj]
                    if not det3(en) > 0.0:
                        ok = False
                        break
                    A = As[b]
                    _map(A0, e, q, plastic, fp_inv, A)
                    _strain_hat(Gq, e, q, Hs, h, rs[q, 0], rs[q, 1], tv, tw, A, plastic,
                                fp_inv, en, Ehs[b])
                if not ok:
                    break
                if not closed:
                    jacobi3_lanes_into(Ehs, nb, lams, Vs, want > 0 or model == HILL48)
                for b in range(nb):
                    q = q0 + j0 + b
                    r, s = rs[q, 0], rs[q, 1]
                    A = As[b]
                    epq = ep[e, q] if plastic else 0.0
                    # the laws are called, not inlined by numba: inlined, they made the kernel's
                    # compile much longer and ran no faster. A line search's energy alone is the
                    # law's W, inlined: a call passes every array it is given, most of them the
                    # tangent's scratch, which an energy does not touch
                    if want == 0:
                        W = _point_energy(model, closed, Ehs, lams, Vs, b, params, frames, e, epq,
                                          cl, M, w6)
                    elif closed:
                        W = _neo_hookean_natural(bt, b, params[0], params[1], want, m3, Dv)
                    elif model == HILL48:
                        W = _hill_natural(lams[b], Vs[b], A, params, frames[e], epq, want, psd, Sn,
                                          Dv, M, cv, Dp, Ci, v3, kqh)
                    else:
                        W = _principal_natural(model, lams[b], Vs[b], A, params, epq, want, psd, Sn,
                                               Dv, M, cv, Dp, m2, v3)
                    if not np.isfinite(W):
                        ok = False
                        break
                    w = wdetJ[e, q]
                    E += w * W
                    if want == 0:
                        continue
                    # gv += w Phi^T Sv, Sv the stress over the natural rows (off-diagonals twice)
                    s02, s12 = Sn[0, 2] * 2.0, Sn[1, 2] * 2.0
                    gv[0] += w * Sn[0, 0]
                    gv[1] += w * Sn[1, 1]
                    gv[2] += w * (Sn[0, 1] * 2.0)
                    gv[3] += w * ((1.0 - s) * s02 + r * s12)
                    gv[4] += w * (s * s02 + (1.0 - r) * s12)
                    gv[5] += w * (-s * s02 + r * s12)
                    sww = w * Sn[2, 2]
                    gv[6] += (1.0 - r - s) * sww
                    gv[7] += r * sww
                    gv[8] += s * sww
                    if want < 2:
                        continue
                    _add_point_tangent(Dv, w, r, s, Mb)
                if not ok:
                    break
            if not ok:
                break
            if want == 0:
                continue
            for p in range(k):
                acc = 0.0
                for c in range(9):
                    acc += gv[c] * P[r0 + c, p]
                g[p] += acc
            if want < 2:
                continue
            for c in range(9):
                for d in range(c):
                    Mb[c, d] = Mb[d, c]
            _material_rows(P, Mb, T, r0)
            # the initial-stress term: the stresses at the tying points are the basis rows'
            _level_geometric(dNq, q0, dNt, dNc, lev, gv, vg, Kg)
        energies[e] = E if ok else np.inf
        if want >= 1:
            drain_element_gradient(grad, conn[e], g, ok)
        if want < 2 or not ok:
            continue
        _congruence(P, T, K)
        if psd:
            _project_into(Kg, kqg)
        for a in range(n_en):
            for b in range(a, n_en):
                for i in range(3):
                    K[3 * a + i, 3 * b + i] += Kg[a, b]
        if project == PROJECT_ELEMENT:
            _project(K)
        p = 0
        for r in range(k):
            for col in range(r, k):
                data[np.uint64(slots[e, p])] += K[r, col]
                p += 1


@njit(cache=True)
def _principal_at(x: np.ndarray, rest: np.ndarray, conn: np.ndarray, e: int, dNq: np.ndarray,
                  dNt: np.ndarray, lev_ptr: np.ndarray, lev: int, rs: np.ndarray,
                  Gq: np.ndarray, A0: np.ndarray, Gt: np.ndarray, dNc: np.ndarray,
                  Gw: np.ndarray, q: int, plastic: bool,
                  fp_inv: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
    """Stretches (3,), principal directions V (3, 3) of C^ at element e's quadrature point q
    (of level ``lev``), and ok; the arrays :class:`Tying`'s."""
    n_en = conn.shape[1]
    n_lev = lev_ptr.shape[0] - 1
    u = np.empty((n_en, 3))
    for a in range(n_en):
        for i in range(3):
            u[a, i] = x[conn[e, a], i] - rest[conn[e, a], i]
    q0 = lev_ptr[lev]
    Hs = np.empty((3 + lev_ptr[lev + 1] - q0, 3, 3))
    dNt = dNt.reshape((3 * n_lev, n_en, 3))
    Gt = Gt.reshape((Gt.shape[0], 3 * n_lev, 3, 3))
    _level_gradients(u, dNq, q0, dNt, lev, Hs)
    tv, tw = np.empty(N_TIE), np.empty(3)
    _tied(Gt, e, lev, Hs, tv)
    _corner_thickness(u, dNc, Gw, e, lev, np.empty((3, 3)), tw)
    en, Eh, A = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
    _map(A0, e, q, plastic, fp_inv, A)
    _strain_hat(Gq, e, q, Hs, 3 + q - q0, rs[q, 0], rs[q, 1], tv, tw, A, plastic, fp_inv, en,
                Eh)
    lam, V = eigh3(Eh)
    ok = 1.0 + 2.0 * lam[0] > 0.0
    return np.sqrt(np.maximum(1.0 + 2.0 * lam, 1e-300)), V, ok


@njit(cache=True, nogil=True)
def ans_volume_kernel(x: np.ndarray, rest: np.ndarray, conn: np.ndarray, dNq: np.ndarray,
                      dNt: np.ndarray, lev_ptr: np.ndarray, rs: np.ndarray, Gq: np.ndarray,
                      A0: np.ndarray, Gt: np.ndarray, dNc: np.ndarray, Gw: np.ndarray,
                      out: np.ndarray, e0: int, e1: int) -> None:
    """The material's volume ratio J = sqrt(det C) of the assumed strain into ``out (n_elem,
    n_qp)``, elements e0 to e1 (C = I + 2 E, the plastic state aside: its flow keeps volume),
    the J every material takes; 0 where the strain inverts the point."""
    none = np.empty((0, 0, 3, 3))  # no plastic state: never read
    for e in range(e0, e1):
        for lev in range(lev_ptr.shape[0] - 1):
            for q in range(lev_ptr[lev], lev_ptr[lev + 1]):
                s, _, ok = _principal_at(x, rest, conn, e, dNq, dNt, lev_ptr, lev, rs, Gq, A0,
                                         Gt, dNc, Gw, q, False, none)
                if ok:
                    out[e, q] = s[0] * s[1] * s[2]


@njit(cache=True, nogil=True)
def ans_commit_kernel(x: np.ndarray, rest: np.ndarray, conn: np.ndarray, dNq: np.ndarray,
                      dNt: np.ndarray, lev_ptr: np.ndarray, rs: np.ndarray, Gq: np.ndarray,
                      A0: np.ndarray, Gt: np.ndarray, dNc: np.ndarray, Gw: np.ndarray,
                      model: int, params: np.ndarray,
                      frames: np.ndarray, fp_inv: np.ndarray, ep: np.ndarray, e0: int,
                      e1: int) -> None:
    """:func:`sim.terms.elasticity.plastic_commit_kernel` on the assumed strain, elements e0 to
    e1: the return
    map in the principal frame V of C^, Fp^-1 <- Fp^-1 V diag(exp(-deps_p)) V^T (Hill48:
    Fp^-1 <- Fp^-1 exp(-dEp), sim.materials.hill)."""
    mu, law, hp = params[0], int(params[2]), params[3:]
    for e in range(e0, e1):
        for lev in range(lev_ptr.shape[0] - 1):
            for q in range(lev_ptr[lev], lev_ptr[lev + 1]):
                s, V, ok = _principal_at(x, rest, conn, e, dNq, dNt, lev_ptr, lev, rs, Gq, A0,
                                         Gt, dNc, Gw, q, True, fp_inv)
                if not ok:
                    continue
                if model == HILL48:
                    _, e6 = hill_strain6(V, np.log(s), frames[e])
                    expm, dg = hill_flow_strain(e6, params, frames[e], ep[e, q])
                    if dg > 0.0:
                        fp_inv[e, q] = fp_inv[e, q] @ expm
                        ep[e, q] += dg
                    continue
                dep, dg = plastic_flow(np.log(s), ep[e, q], mu, law, hp)
                if dg == 0.0:
                    continue
                fp_inv[e, q] = fp_inv[e, q] @ ((V * np.exp(-dep)) @ np.ascontiguousarray(V.T))
                ep[e, q] += dg


@njit(cache=True, nogil=True)
def ans_stress_kernel(x: np.ndarray, rest: np.ndarray, conn: np.ndarray, dNq: np.ndarray,
                      dNt: np.ndarray, lev_ptr: np.ndarray, rs: np.ndarray, Gq: np.ndarray,
                      A0: np.ndarray, Gt: np.ndarray, dNc: np.ndarray, Gw: np.ndarray,
                      model: int, params: np.ndarray,
                      frames: np.ndarray, fp_inv: np.ndarray, ep: np.ndarray,
                      plastic: bool, out: np.ndarray, e0: int, e1: int) -> None:
    """Von Mises equivalent of the Cauchy stress into ``out (n_elem, n_qp)``, elements e0 to
    e1, from the assumed strain (of the Kirchhoff stress U S^ U over J, U = C^^1/2: a rotation
    of it, the same invariants)."""
    eye = np.eye(3)
    for e in range(e0, e1):
        Sp, Dp = np.empty((3, 3)), np.empty((6, 6))
        for lev in range(lev_ptr.shape[0] - 1):
            for q in range(lev_ptr[lev], lev_ptr[lev + 1]):
                s, V, ok = _principal_at(x, rest, conn, e, dNq, dNt, lev_ptr, lev, rs, Gq, A0,
                                         Gt, dNc, Gw, q, plastic, fp_inv)
                if not ok:
                    continue
                if model == HILL48:
                    hill_green(s * s, V, params, frames[e], ep[e, q], 1, Sp, Dp)
                    tau3 = Sp * np.outer(s, s)
                    dev3 = tau3 - np.trace(tau3) / 3.0 * eye
                    out[e, q] = np.sqrt(1.5 * np.sum(dev3 * dev3)) / (s[0] * s[1] * s[2])
                    continue
                W, gs, H, sym, twist = principal(model, s, params, ep[e, q] if plastic else 0.0)
                tau = gs * s
                dev = tau - tau.mean()
                out[e, q] = np.sqrt(1.5 * (dev @ dev)) / (s[0] * s[1] * s[2])

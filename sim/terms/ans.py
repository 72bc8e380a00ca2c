"""Assumed natural transverse shear strains (MITC3 tying) for prisms linear in-plane.

Strains are covariant in the element's reference coordinates xi = (r, s, w) = (u, v, w):
e_ij = 1/2 (g_i . g_j - G_i . G_j) with g_i = dx/dxi_i, G_i = dX/dxi_i, formed from the
displacement (1/2 (G_i . h_j + h_i . G_j + h_i . h_j), h_i = du/dxi_i) so that a small strain
keeps its digits. At each quadrature point the transverse shear pair (e_rw, e_sw) is replaced by
the lowest-order edge interpolation of its tangential values at three tying points at the point's
own w (Lee and Bathe 2004, MITC3): e_rw at A = (1/2, 0), e_sw at B = (0, 1/2), e_sw - e_rw at
C = (1/2, 1/2), so that each edge's tangential shear is constant along it:

    e~_rw = e_rw^A + s c,   e~_sw = e_sw^B - r c,   c = (e_sw^B - e_rw^A) - (e_sw^C - e_rw^C).

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
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from sim.geometry.quadrature import Rule
from sim.geometry.shell import Shell
from sim.materials.isotropic import PAIRS, det3, eigh3, principal
from sim.materials.plasticity import plastic_flow

# tying points in (u, v): A on the edge v = 0, B on u = 0, C on the third edge
TYING = np.array([[0.5, 0.0], [0.0, 0.5], [0.5, 0.5]])


class Tying:
    """What the ANS kernels need of a shell and a rule, computed once.

    ``dNq (n_qp, n_en, 3)``: reference gradients at the quadrature points; ``dNt (n_lev, 3, n_en,
    3)``: at the tying points A, B, C of each thickness level; ``lev_ptr (n_lev + 1,)``: the
    quadrature points of level l are lev_ptr[l]:lev_ptr[l+1] (the rule is level-major);
    ``rs (n_qp, 2)``: their in-plane coordinates; ``Gq (n_e, n_qp, 3, 3)``: G[k, i] = dX_k/dxi_i,
    ``A0`` its inverse; ``Gt (n_e, n_lev, 3, 3, 3)``: G at the tying points."""

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
        self.dNt = np.ascontiguousarray(dNt.reshape(len(levels), 3, el.n_nodes, 3))
        Xe = shell.rest[shell.conn]
        self.Gq = np.ascontiguousarray(np.einsum("eak,qai->eqki", Xe, self.dNq))
        self.A0 = np.ascontiguousarray(np.linalg.inv(self.Gq))
        self.Gt = np.ascontiguousarray(np.einsum("eak,ltai->eltki", Xe, self.dNt))


@njit(cache=True, inline='always')
def _nat_gradient(u: np.ndarray, dN: np.ndarray, Hn: np.ndarray) -> None:
    """Hn[k, i] = sum_a u[a, k] dN[a, i]: the displacement's reference gradient."""
    for k in range(3):
        for i in range(3):
            Hn[k, i] = 0.0
    for a in range(u.shape[0]):
        for k in range(3):
            for i in range(3):
                Hn[k, i] += u[a, k] * dN[a, i]


@njit(cache=True, inline='always')
def _cov(G: np.ndarray, Hn: np.ndarray, i: int, j: int) -> float:
    """e_ij = 1/2 (G_i . h_j + h_i . G_j + h_i . h_j)."""
    acc = 0.0
    for k in range(3):
        acc += G[k, i] * Hn[k, j] + Hn[k, i] * G[k, j] + Hn[k, i] * Hn[k, j]
    return 0.5 * acc


@njit(cache=True, inline='always')
def _tied(u: np.ndarray, dNt: np.ndarray, Gt: np.ndarray, Hn: np.ndarray) -> tuple:
    """The tied values (e_rw at A, e_sw at B, e_sw - e_rw at C) of one level."""
    _nat_gradient(u, dNt[0], Hn)
    eA = _cov(Gt[0], Hn, 0, 2)
    _nat_gradient(u, dNt[1], Hn)
    eB = _cov(Gt[1], Hn, 1, 2)
    _nat_gradient(u, dNt[2], Hn)
    eD = _cov(Gt[2], Hn, 1, 2) - _cov(Gt[2], Hn, 0, 2)
    return eA, eB, eD


@njit(cache=True, inline='always')
def _strain_hat(Gq: np.ndarray, Hn: np.ndarray, r: float, s: float, eA: float, eB: float,
                eD: float, A: np.ndarray, plastic: bool, fp_inv: np.ndarray, en: np.ndarray,
                Eh: np.ndarray) -> None:
    """en: the assumed covariant strain e~ (3, 3); Eh: E^ = A^T e~ A (+ the plastic part)."""
    for i in range(3):
        for j in range(i, 3):
            en[i, j] = _cov(Gq, Hn, i, j)
    c = (eB - eA) - eD
    en[0, 2] = eA + s * c
    en[1, 2] = eB - r * c
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
                acc += 0.5 * (fp_inv[0, I] * fp_inv[0, J] + fp_inv[1, I] * fp_inv[1, J]
                              + fp_inv[2, I] * fp_inv[2, J] - (1.0 if I == J else 0.0))
            Eh[I, J] = acc
            Eh[J, I] = acc


@njit(cache=True, inline='always')
def _map(A0: np.ndarray, plastic: bool, fp_inv: np.ndarray, A: np.ndarray) -> None:
    """A = J^-1 Fp^-1 (J^-1 alone without a plastic state)."""
    for i in range(3):
        for J in range(3):
            if plastic:
                A[i, J] = A0[i, 0] * fp_inv[0, J] + A0[i, 1] * fp_inv[1, J] + A0[i, 2] * fp_inv[2, J]
            else:
                A[i, J] = A0[i, J]


@njit(cache=True, inline='always')
def _tie_rows(dN: np.ndarray, G: np.ndarray, Hn: np.ndarray, i: int, out: np.ndarray,
              sign: float) -> None:
    """out += sign de_iw/du (node-major DoF 3 a + k) at a tying point: 1/2 (g_i dN_w + g_w dN_i)."""
    for a in range(dN.shape[0]):
        for k in range(3):
            out[3 * a + k] += sign * 0.5 * ((G[k, i] + Hn[k, i]) * dN[a, 2]
                                            + (G[k, 2] + Hn[k, 2]) * dN[a, i])


@njit(cache=True, inline='always')
def _geometric(dN: np.ndarray, sig: np.ndarray, Kg: np.ndarray) -> None:
    """Kg[a, b] += dN_a^T sig dN_b (the initial-stress term of sum sig_ij d2e_ij)."""
    n = dN.shape[0]
    for b in range(n):
        t0 = sig[0, 0] * dN[b, 0] + sig[0, 1] * dN[b, 1] + sig[0, 2] * dN[b, 2]
        t1 = sig[1, 0] * dN[b, 0] + sig[1, 1] * dN[b, 1] + sig[1, 2] * dN[b, 2]
        t2 = sig[2, 0] * dN[b, 0] + sig[2, 1] * dN[b, 1] + sig[2, 2] * dN[b, 2]
        for a in range(n):
            Kg[a, b] += dN[a, 0] * t0 + dN[a, 1] * t1 + dN[a, 2] * t2


@njit(cache=True, inline='always')
def _shear_sig(sig: np.ndarray, i: int, tau: float) -> None:
    """sig = tau/2 (e_i (x) e_w + e_w (x) e_i), zero elsewhere: d2(tau e_iw)."""
    for a in range(3):
        for b in range(3):
            sig[a, b] = 0.0
    sig[i, 2] = sig[2, i] = 0.5 * tau


@njit(cache=True, inline='always')
def _ans_element(x, rest, nodes, tg, wdetJ, model, params, fp_inv, ep, plastic,  # noqa: C901
                 want, g, K, Kg, rows, R, tie, u, Hn, en, Eh, A, sig):
    """Energy of one element; adds its gradient into ``g (k,)`` (want >= 1) and its Hessian's
    upper triangle, node-major, into ``K (k, k)`` (want == 2; zeroed here). ``tg``: the
    element's (dNq, dNt, lev_ptr, rs, Gq, A0, Gt) of :class:`Tying`. Scratch: Kg (n_en, n_en),
    rows, R (6, k), tie (3, k), u (n_en, 3), Hn, en, Eh, A, sig (3, 3)."""
    dNq, dNt, lev_ptr, rs, Gq, A0, Gt = tg
    n_en = nodes.shape[0]
    k = 3 * n_en
    for a in range(n_en):
        for i in range(3):
            u[a, i] = x[nodes[a], i] - rest[nodes[a], i]
    if want == 2:
        for p in range(k):
            for c in range(k):
                K[p, c] = 0.0
        for a in range(n_en):
            for b in range(n_en):
                Kg[a, b] = 0.0
    E = 0.0
    for lev in range(lev_ptr.shape[0] - 1):
        eA, eB, eD = _tied(u, dNt[lev], Gt[lev], Hn)
        if want >= 1:  # rows of the tied values: A's e_rw, B's e_sw, C's e_sw - e_rw
            for t in range(3):
                for p in range(k):
                    tie[t, p] = 0.0
            _nat_gradient(u, dNt[lev, 0], Hn)
            _tie_rows(dNt[lev, 0], Gt[lev, 0], Hn, 0, tie[0], 1.0)
            _nat_gradient(u, dNt[lev, 1], Hn)
            _tie_rows(dNt[lev, 1], Gt[lev, 1], Hn, 1, tie[1], 1.0)
            _nat_gradient(u, dNt[lev, 2], Hn)
            _tie_rows(dNt[lev, 2], Gt[lev, 2], Hn, 1, tie[2], 1.0)
            _tie_rows(dNt[lev, 2], Gt[lev, 2], Hn, 0, tie[2], -1.0)
        tA = tB = tC = 0.0  # the level's weighted tying stresses (geometric term)
        for q in range(lev_ptr[lev], lev_ptr[lev + 1]):
            r, s = rs[q, 0], rs[q, 1]
            _nat_gradient(u, dNq[q], Hn)
            for i in range(3):  # g = G + h: an inverted element has no energy
                for j in range(3):
                    en[i, j] = Gq[q, i, j] + Hn[i, j]
            if not det3(en) > 0.0:
                return np.inf
            _map(A0[q], plastic, fp_inv[q], A)
            _strain_hat(Gq[q], Hn, r, s, eA, eB, eD, A, plastic, fp_inv[q], en, Eh)
            lam, V = eigh3(Eh)
            if not 1.0 + 2.0 * lam[0] > 0.0:
                return np.inf
            st = np.sqrt(1.0 + 2.0 * lam)
            W, gs, H, sym, twist = principal(model, st, params, ep[q] if plastic else 0.0)
            if not np.isfinite(W):
                return np.inf
            w = wdetJ[q]
            E += w * W
            if want == 0:
                continue
            M = A @ V  # m_i = A v_i, columns
            # natural strain rows (rr, ss, ww, rs, rw, sw): de~_ij/du, node-major DoFs
            for a in range(n_en):
                for kk in range(3):
                    p = 3 * a + kk
                    g0, g1, g2 = Gq[q, kk, 0] + Hn[kk, 0], Gq[q, kk, 1] + Hn[kk, 1], \
                        Gq[q, kk, 2] + Hn[kk, 2]
                    rows[0, p] = g0 * dNq[q, a, 0]
                    rows[1, p] = g1 * dNq[q, a, 1]
                    rows[2, p] = g2 * dNq[q, a, 2]
                    rows[3, p] = 0.5 * (g0 * dNq[q, a, 1] + g1 * dNq[q, a, 0])
                    rows[4, p] = (1.0 - s) * tie[0, p] + s * tie[1, p] - s * tie[2, p]
                    rows[5, p] = r * tie[0, p] + (1.0 - r) * tie[1, p] + r * tie[2, p]
            # principal rows: deps_i = m_i^T de~ m_i, then the pairs m_i^T de~ m_j
            for c in range(6):
                if c < 3:
                    i, j = c, c
                else:
                    i, j = PAIRS[c - 3, 0], PAIRS[c - 3, 1]
                c0 = M[0, i] * M[0, j]
                c1 = M[1, i] * M[1, j]
                c2 = M[2, i] * M[2, j]
                c3 = M[0, i] * M[1, j] + M[1, i] * M[0, j]
                c4 = M[0, i] * M[2, j] + M[2, i] * M[0, j]
                c5 = M[1, i] * M[2, j] + M[2, i] * M[1, j]
                for p in range(k):
                    R[c, p] = (c0 * rows[0, p] + c1 * rows[1, p] + c2 * rows[2, p]
                               + c3 * rows[3, p] + c4 * rows[4, p] + c5 * rows[5, p])
            Sp0, Sp1, Sp2 = gs[0] / st[0], gs[1] / st[1], gs[2] / st[2]
            for p in range(k):
                g[p] += w * (Sp0 * R[0, p] + Sp1 * R[1, p] + Sp2 * R[2, p])
            if want < 2:
                continue
            h = np.empty((3, 3))
            for i in range(3):
                for j in range(3):
                    h[i, j] = H[i, j] / (st[i] * st[j])
                h[i, i] -= gs[i] / st[i] ** 3
            kap = np.empty(3)
            for c in range(3):
                i, j = PAIRS[c, 0], PAIRS[c, 1]
                kap[c] = 2.0 * w * (sym[c] - twist[c]) / (st[i] * st[j])
            for p in range(k):
                t0 = w * (h[0, 0] * R[0, p] + h[0, 1] * R[1, p] + h[0, 2] * R[2, p])
                t1 = w * (h[1, 0] * R[0, p] + h[1, 1] * R[1, p] + h[1, 2] * R[2, p])
                t2 = w * (h[2, 0] * R[0, p] + h[2, 1] * R[1, p] + h[2, 2] * R[2, p])
                t3, t4, t5 = kap[0] * R[3, p], kap[1] * R[4, p], kap[2] * R[5, p]
                for col in range(p, k):
                    K[p, col] += (t0 * R[0, col] + t1 * R[1, col] + t2 * R[2, col]
                                  + t3 * R[3, col] + t4 * R[4, col] + t5 * R[5, col])
            # initial stress: S~ = sum_i S_i m_i m_i^T at the point, the shear pair at the tying
            # points with the weights of the interpolation
            for i in range(3):
                for j in range(3):
                    sig[i, j] = w * (Sp0 * M[i, 0] * M[j, 0] + Sp1 * M[i, 1] * M[j, 1]
                                     + Sp2 * M[i, 2] * M[j, 2])
            Srw, Ssw = sig[0, 2], sig[1, 2]
            tA += 2.0 * ((1.0 - s) * Srw + r * Ssw)
            tB += 2.0 * (s * Srw + (1.0 - r) * Ssw)
            tC += 2.0 * (r * Ssw - s * Srw)
            sig[0, 2] = sig[2, 0] = sig[1, 2] = sig[2, 1] = 0.0
            _geometric(dNq[q], sig, Kg)
        if want == 2:
            _shear_sig(sig, 0, tA)
            _geometric(dNt[lev, 0], sig, Kg)
            _shear_sig(sig, 1, tB)
            _geometric(dNt[lev, 1], sig, Kg)
            _shear_sig(sig, 1, tC)
            sig[0, 2] = sig[2, 0] = -0.5 * tC
            _geometric(dNt[lev, 2], sig, Kg)
    if want == 2:
        for a in range(n_en):
            for b in range(n_en):
                for i in range(3):
                    p, c = 3 * a + i, 3 * b + i
                    if c >= p:
                        K[p, c] += Kg[a, b]
    return E


@njit(cache=True)
def _project(K: np.ndarray) -> None:
    """K (upper triangle) <- its projection to positive semi-definite (both triangles)."""
    k = K.shape[0]
    for p in range(k):
        for c in range(p):
            K[p, c] = K[c, p]
    ev, Q = np.linalg.eigh(K)
    K[:, :] = (Q * np.maximum(ev, 0.0)) @ Q.T


@njit(cache=True, parallel=True)
def ans_kernel(x, rest, conn, dNq, dNt, lev_ptr, rs, Gq, A0, Gt, wdetJ, model, params, fp_inv,
               ep, plastic, want, project, order, block_ptr, color_ptr, slots, grad, data):
    """:func:`sim.terms.elasticity.elastic_kernel` for assumed-shear elements: same arguments
    and scatter, the element's geometry from :class:`Tying` (Gq, A0, Gt per element). Any
    projection (``project`` != 0) is the element's: the initial-stress term of the tied shear
    has no per-point PSD split."""
    n_e, n_en = conn.shape
    k = 3 * n_en
    energies = np.zeros(n_e)
    for c in range(len(color_ptr) - 1):
        for blk in prange(color_ptr[c], color_ptr[c + 1]):
            g = np.zeros(k)
            K = np.empty((k, k) if want == 2 else (0, 0))
            Kg = np.empty((n_en, n_en))
            rows, R, tie = np.empty((6, k)), np.empty((6, k)), np.empty((3, k))
            u, Hn, en = np.empty((n_en, 3)), np.empty((3, 3)), np.empty((3, 3))
            Eh, A, sig = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
            for t in range(block_ptr[blk], block_ptr[blk + 1]):
                e = order[t]
                E = _ans_element(x, rest, conn[e], (dNq, dNt, lev_ptr, rs, Gq[e], A0[e], Gt[e]),
                                 wdetJ[e], model, params, fp_inv[e], ep[e], plastic, want, g,
                                 K, Kg, rows, R, tie, u, Hn, en, Eh, A, sig)
                energies[e] = E
                ok = np.isfinite(E)
                if want >= 1:
                    for a in range(n_en):
                        for i in range(3):
                            if ok:
                                grad[conn[e, a], i] += g[3 * a + i]
                            g[3 * a + i] = 0.0
                if want == 2 and ok:
                    if project != 0:
                        _project(K)
                    s = slots[e]
                    p = 0
                    for r in range(k):
                        for col in range(r, k):
                            data[np.uint64(s[p])] += K[r, col]
                            p += 1
    return energies.sum()


@njit(cache=True)
def _principal_at(x, rest, nodes, dNq, dNt, lev, rs, Gq, A0, Gt, q, plastic, fp_inv):
    """Stretches (3,), principal directions V (3, 3) of C^ at quadrature point q, and ok."""
    n_en = nodes.shape[0]
    u = np.empty((n_en, 3))
    for a in range(n_en):
        for i in range(3):
            u[a, i] = x[nodes[a], i] - rest[nodes[a], i]
    Hn, en, Eh, A = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
    eA, eB, eD = _tied(u, dNt[lev], Gt[lev], Hn)
    _nat_gradient(u, dNq[q], Hn)
    _map(A0[q], plastic, fp_inv, A)
    _strain_hat(Gq[q], Hn, rs[q, 0], rs[q, 1], eA, eB, eD, A, plastic, fp_inv, en, Eh)
    lam, V = eigh3(Eh)
    ok = 1.0 + 2.0 * lam[0] > 0.0
    return np.sqrt(np.maximum(1.0 + 2.0 * lam, 1e-300)), V, ok


@njit(cache=True, parallel=True)
def ans_commit_kernel(x, rest, conn, dNq, dNt, lev_ptr, rs, Gq, A0, Gt, params, fp_inv, ep):
    """:func:`sim.terms.elasticity.plastic_commit_kernel` on the assumed strain: the return
    map in the principal frame V of C^, Fp^-1 <- Fp^-1 V diag(exp(-deps_p)) V^T."""
    mu, law, hp = params[0], int(params[2]), params[3:]
    for e in prange(conn.shape[0]):
        for lev in range(lev_ptr.shape[0] - 1):
            for q in range(lev_ptr[lev], lev_ptr[lev + 1]):
                s, V, ok = _principal_at(x, rest, conn[e], dNq, dNt, lev, rs, Gq[e], A0[e],
                                         Gt[e], q, True, fp_inv[e, q])
                if not ok:
                    continue
                dep, dg = plastic_flow(np.log(s), ep[e, q], mu, law, hp)
                if dg == 0.0:
                    continue
                fp_inv[e, q] = fp_inv[e, q] @ ((V * np.exp(-dep)) @ np.ascontiguousarray(V.T))
                ep[e, q] += dg


@njit(cache=True, parallel=True)
def ans_stress_kernel(x, rest, conn, dNq, dNt, lev_ptr, rs, Gq, A0, Gt, model, params, fp_inv,
                      ep, plastic):
    """Von Mises equivalent of the Cauchy stress ``(n_elem, n_qp)`` from the assumed strain."""
    out = np.zeros((conn.shape[0], dNq.shape[0]))
    eye = np.eye(3)
    for e in prange(conn.shape[0]):
        for lev in range(lev_ptr.shape[0] - 1):
            for q in range(lev_ptr[lev], lev_ptr[lev + 1]):
                fi = fp_inv[e, q] if plastic else eye
                s, V, ok = _principal_at(x, rest, conn[e], dNq, dNt, lev, rs, Gq[e], A0[e],
                                         Gt[e], q, plastic, fi)
                if not ok:
                    continue
                W, gs, H, sym, twist = principal(model, s, params, ep[e, q] if plastic else 0.0)
                tau = gs * s
                dev = tau - tau.mean()
                out[e, q] = np.sqrt(1.5 * (dev @ dev)) / (s[0] * s[1] * s[2])
    return out

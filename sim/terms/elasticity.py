"""Elastic (and elastoplastic) stored energy: sum over elements and quadrature points of
w detJ Psi(F), with F = sum_a x_a (x) dN_a/dX (paper Eq. 2-3), formed as
F = I + sum_a u_a (x) dN_a/dX from the displacement u = x - X: the rest state gives F = I and zero
force exactly, and the round-off of the sum scales with |u|, not with |X| (summing x_a dN_a
cancels terms of size |X| / h to leave O(1): at h/L = 1e-4 that alone was a force 15x the load).

The plastic state, when a scene has one, enters as G = F Fp^{-1} = Fp^{-1} + sum_a u_a (x) b_a:
the energy density is then an isotropic function of G, so the chain rule only maps dN/dX to
b = dN/dX Fp^{-1}.
"""

from __future__ import annotations

import numpy as np
from numba import get_num_threads, njit, prange

from sim.materials.isotropic import (
    NEO_HOOKEAN,
    neo_hookean_h,
    polar_svd,
    principal,
    stress_tangent_h,
)
from sim.materials.plasticity import plastic_flow
from sim.terms import Term

PROJECT_NONE, PROJECT_QP, PROJECT_ELEMENT = 0, 1, 2


def reference_gradients(rest: np.ndarray, conn: np.ndarray, dN: np.ndarray,
                        weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """dN/dX ``(n_elem, n_qp, n_en, 3)`` and w detJ ``(n_elem, n_qp)`` from the rest positions.

    dN: reference gradients ``(n_qp, n_en, 3)``; raises on an element with detJ <= 0, or flat
    to round-off: detJ below 1e-10 of the median (a zero-area triangle's detJ is round-off,
    1e-16 of the others, of either sign; slivers of aspect ratio 1e4 are still 1e-4).
    """
    Xe = rest[conn]  # (n_e, n_en, 3)
    J = np.einsum("ead,qaj->eqdj", Xe, dN)  # dX_d / dxi_j
    det = np.linalg.det(J)
    flat = det <= 1e-10 * np.median(det)
    if np.any(flat):
        bad = np.unique(np.nonzero(flat)[0])
        raise ValueError(f"{len(bad)} element(s) inverted or flat in the rest state "
                         f"(first: {bad[:5].tolist()}); check thickness and mesh orientation")
    Jinv = np.linalg.inv(J)
    dNdX = np.einsum("qaj,eqjd->eqad", dN, Jinv)
    return np.ascontiguousarray(dNdX), det * weights[None, :]


@njit(cache=True, inline='always')
def _element(x, rest, nodes, dNdX, wdetJ, model, params, fp_inv, ep, plastic, want, project, g,
             Kp, CB, G, P, C, b, u, FiT):
    """Energy of one element; adds its gradient into ``g (n_en*3,)`` (want >= 1) and the upper
    triangle of its Hessian, packed row by row, into ``Kp (k (k+1) / 2,)`` (want == 2).
    Scratch, reused from element to element: ``CB (9, k)``, ``G, P, FiT (3, 3)``,
    ``C (9, 9)``, ``b, u (n_en, 3)``.

    Inlined into the kernel (as are the helpers it calls per quadrature point): a call passes
    each array as a reference-counted struct, and those calls took 55 % of the Q3T beam's
    gradient and 30 % of its Hessian evaluation. numba's cache keys a kernel on its own file
    only; sim/__init__.py therefore keys the cache folder on all of sim's sources, so an edit
    of an inlined helper in another module (sim.materials.isotropic) recompiles this kernel.
    """
    n_en = nodes.shape[0]
    k = 3 * n_en
    E = 0.0
    # Neo-Hookean's closed form serves energy, gradient and exact Hessian; a projected tangent
    # needs the principal frame. The projection only changes the Hessian: energy and gradient
    # of a line search come from the same formula as those of an assembly.
    closed = model == NEO_HOOKEAN and not (want == 2 and project == PROJECT_QP)
    mu, lam = params[0], params[1]
    for a in range(n_en):
        for i in range(3):
            u[a, i] = x[nodes[a], i] - rest[nodes[a], i]
    for q in range(dNdX.shape[0]):
        for a in range(n_en):
            for J in range(3):
                if plastic:  # b = dN/dX Fp^-1
                    b[a, J] = (dNdX[q, a, 0] * fp_inv[q, 0, J] + dNdX[q, a, 1] * fp_inv[q, 1, J]
                               + dNdX[q, a, 2] * fp_inv[q, 2, J])
                else:
                    b[a, J] = dNdX[q, a, J]
        # G - I: the displacement part, plus Fp^-1 - I under a plastic state (zero before
        # it flows, so an unyielded plastic scene runs on the elastic bits)
        _displacement_gradient(u, b, G)
        if plastic:
            for i in range(3):
                for J in range(3):
                    G[i, J] += fp_inv[q, i, J] - (1.0 if i == J else 0.0)
        if closed:
            W = neo_hookean_h(G, mu, lam, want == 2, P, C, FiT)
        else:
            W = stress_tangent_h(model, G, params, ep[q] if plastic else 0.0, want == 2,
                                 want == 2 and project == PROJECT_QP, P, C)
        if not np.isfinite(W):
            return np.inf
        w = wdetJ[q]
        E += w * W
        if want == 0:
            continue
        for a in range(n_en):
            for i in range(3):
                g[3 * a + i] += w * (P[i, 0] * b[a, 0] + P[i, 1] * b[a, 1] + P[i, 2] * b[a, 2])
        if want < 2:
            continue
        for r in range(9):
            cr = CB[r]
            for kk in range(3):
                c0, c1, c2 = C[r, 3 * kk], C[r, 3 * kk + 1], C[r, 3 * kk + 2]
                for bn in range(np.uint64(n_en)):
                    cr[np.uint64(3) * bn + np.uint64(kk)] = (c0 * b[bn, 0] + c1 * b[bn, 1]
                                                             + c2 * b[bn, 2])
        off = 0  # packed offset of (row, row)
        for row in range(k):
            a, i = row // 3, row % 3
            b0, b1, b2 = w * b[a, 0], w * b[a, 1], w * b[a, 2]
            c0, c1, c2, kp = CB[3 * i], CB[3 * i + 1], CB[3 * i + 2], Kp[off - row:]
            # contiguous, and unsigned so that numba adds no negative-index wraparound: this
            # loop vectorises (with signed indices, 3.5x slower)
            for col in range(np.uint64(row), np.uint64(k)):
                kp[col] += b0 * c0[col] + b1 * c1[col] + b2 * c2[col]
            off += k - row
    if want == 2 and project == PROJECT_ELEMENT:
        K = np.empty((k, k))
        off = 0
        for row in range(k):
            for col in range(row, k):
                K[row, col] = K[col, row] = Kp[off + col - row]
            off += k - row
        ev, Q = np.linalg.eigh(K)
        K = (Q * np.maximum(ev, 0.0)) @ Q.T
        off = 0
        for row in range(k):
            for col in range(row, k):
                Kp[off + col - row] = K[row, col]
            off += k - row
    return E


@njit(cache=True, parallel=True)
def elastic_kernel(x, rest, conn, dNdX, wdetJ, model, params, fp_inv, ep, plastic, want,
                   project, colors, color_ptr, slots, grad, data, n_chunks):
    """Total energy; adds the gradient into ``grad (n_nodes, 3)`` (want >= 1) and the Hessian
    into ``data`` through the packed upper-triangle ``slots (n_elem, k (k+1) / 2)``
    (want == 2). Elements of one colour share no node, so each colour is scattered in parallel
    without races. Returns inf on inversion."""
    n_e, n_en = conn.shape
    k = 3 * n_en
    energies = np.zeros(n_e)
    # ``n_chunks`` (a few per thread), each with its own scratch: numba's heap arrays, made
    # per element, cost as much as a linear prism's arithmetic
    for c in range(len(color_ptr) - 1):
        lo, n = color_ptr[c], color_ptr[c + 1] - color_ptr[c]
        for ch in prange(n_chunks):
            # scratch per chunk; g and Kp are handed back zeroed by the scatter that drains them
            g = np.zeros(k)
            Kp = np.zeros(k * (k + 1) // 2 if want == 2 else 0)
            CB, C = np.empty((9, k)), np.empty((9, 9))
            G, P = np.empty((3, 3)), np.empty((3, 3))
            b, u, FiT = np.empty((n_en, 3)), np.empty((n_en, 3)), np.empty((3, 3))
            for t in range(lo + ch * n // n_chunks, lo + (ch + 1) * n // n_chunks):
                e = colors[t]
                E = _element(x, rest, conn[e], dNdX[e], wdetJ[e], model, params, fp_inv[e],
                             ep[e], plastic, want, project, g, Kp, CB, G, P, C, b, u, FiT)
                energies[e] = E
                ok = np.isfinite(E)
                if want >= 1:
                    for a in range(n_en):
                        for i in range(3):
                            if ok:
                                grad[conn[e, a], i] += g[3 * a + i]
                            g[3 * a + i] = 0.0
                if want == 2:
                    s = slots[e]
                    for p in range(Kp.shape[0]):
                        if ok:  # slots are >= 0: unsigned, numba skips the wraparound test
                            data[np.uint64(s[p])] += Kp[p]
                        Kp[p] = 0.0
    return energies.sum()


@njit(cache=True, inline='always')
def _displacement_gradient(u, b, H):
    """H = sum_a u_a (x) b_a into ``H (3, 3)``; u ``(n_en, 3)``."""
    for i in range(3):  # loops: inlined into a prange body, H[:] = 0 would be a nested parfor
        for J in range(3):
            H[i, J] = 0.0
    for a in range(u.shape[0]):
        for i in range(3):
            for J in range(3):
                H[i, J] += u[a, i] * b[a, J]


@njit(cache=True)
def _deformation_gradient(x, rest, nodes, b, G0):
    """G = G0 + sum_a (x_a - X_a) (x) b_a, G0 the gradient at rest (I, or Fp^-1)."""
    u = np.empty((nodes.shape[0], 3))
    for a in range(nodes.shape[0]):
        for i in range(3):
            u[a, i] = x[nodes[a], i] - rest[nodes[a], i]
    G = np.empty((3, 3))
    _displacement_gradient(u, b, G)
    return G + G0


@njit(cache=True, parallel=True)
def plastic_commit_kernel(x, rest, conn, dNdX, params, fp_inv, ep):
    """Return-map every quadrature point at the converged state x and update, in place,
    Fp^-1 (n_elem, n_qp, 3, 3) <- Fp_n^-1 V diag(exp(-deps_p)) V^T and ep (n_elem, n_qp) += dgamma
    (the flow is isochoric: det Fp^-1 stays 1 to round-off)."""
    mu, law, hp = params[0], int(params[2]), params[3:]
    for e in prange(conn.shape[0]):
        for q in range(dNdX.shape[1]):
            G = _deformation_gradient(x, rest, conn[e], dNdX[e, q] @ fp_inv[e, q], fp_inv[e, q])
            U, s, V, ok = polar_svd(G)
            if not ok:
                continue
            eps = np.log(s)
            dep, dg = plastic_flow(eps, ep[e, q], mu, law, hp)
            if dg == 0.0:
                continue
            fp_inv[e, q] = fp_inv[e, q] @ ((V * np.exp(-dep)) @ np.ascontiguousarray(V.T))
            ep[e, q] += dg


@njit(cache=True, parallel=True)
def stress_kernel(x, rest, conn, dNdX, model, params, fp_inv, ep, plastic):
    """Von Mises equivalent of the Cauchy stress (n_elem, n_qp) at state x (with the trial
    return map at the committed plastic state)."""
    out = np.zeros(dNdX.shape[:2])
    for e in prange(conn.shape[0]):
        for q in range(dNdX.shape[1]):
            if plastic:
                G = _deformation_gradient(x, rest, conn[e], dNdX[e, q] @ fp_inv[e, q],
                                          fp_inv[e, q])
            else:
                G = _deformation_gradient(x, rest, conn[e], dNdX[e, q], np.eye(3))
            U, s, V, ok = polar_svd(G)
            if not ok:
                continue
            W, g, H, sym, twist = principal(model, s, params, ep[e, q] if plastic else 0.0)
            tau = g * s  # principal Kirchhoff stress
            dev = tau - tau.mean()
            J = s[0] * s[1] * s[2]  # det G = det F: the plastic part is isochoric
            out[e, q] = np.sqrt(1.5 * (dev @ dev)) / J
    return out


class Elasticity(Term):
    """Stored energy of the shell. ``material``: (model id, params array); ``plastic`` state is
    ``fp_inv (n_elem, n_qp, 3, 3)`` and ``ep (n_elem, n_qp)``, or None for an elastic scene."""

    name = "elasticity"

    def __init__(self, shell, rule, model: int, params: np.ndarray, pattern, project: int,
                 plastic: bool = False):
        _, dN = shell.element.basis(rule.points)
        self.rule = rule
        self.conn = shell.conn
        self.rest = shell.rest
        self.dNdX, self.wdetJ = reference_gradients(shell.rest, shell.conn, dN, rule.weights)
        self.model, self.params = model, np.asarray(params, float)
        self.pattern, self.project = pattern, project
        n_e, n_q = self.wdetJ.shape
        self.plastic = plastic
        if plastic:
            self.fp_inv = np.tile(np.eye(3), (n_e, n_q, 1, 1))
            self.ep = np.zeros((n_e, n_q))
        else:  # an elastic scene allocates no plastic state
            self.fp_inv = np.zeros((n_e, 0, 3, 3))
            self.ep = np.zeros((n_e, 0))
        self._colors = np.concatenate(pattern.colors)
        self._color_ptr = np.concatenate([[0], np.cumsum([len(c) for c in pattern.colors])])

    def _run(self, x, want, grad, data):
        return elastic_kernel(x, self.rest, self.conn, self.dNdX, self.wdetJ, self.model,
                              self.params, self.fp_inv, self.ep, self.plastic, want,
                              self.project, self._colors, self._color_ptr,
                              self.pattern.elem_slots, grad, data, 4 * get_num_threads())

    def energy(self, x):
        return self._run(x, 0, np.zeros((0, 3)), np.zeros(0))

    def add_gradient(self, x, g):
        return self._run(x, 1, g, np.zeros(0))

    def add_hessian(self, x, data):
        return self._run(x, 2, np.zeros(x.shape), data)

    def add_gradient_hessian(self, x, g, data):
        return self._run(x, 2, g, data)

    def commit(self, x):
        if self.plastic:
            plastic_commit_kernel(x, self.rest, self.conn, self.dNdX, self.params, self.fp_inv,
                                  self.ep)

    def von_mises(self, x) -> np.ndarray:
        """Von Mises stress (Pa) per element and quadrature point ``(n_elem, n_qp)``."""
        return stress_kernel(x, self.rest, self.conn, self.dNdX, self.model, self.params,
                             self.fp_inv, self.ep, self.plastic)

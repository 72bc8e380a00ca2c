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
from numba import njit

from sim.geometry.quadrature import Rule
from sim.geometry.shell import Shell
from sim.materials.hill import (
    HILL48,
    hill_energy_h,
    hill_flow,
    hill_kirchhoff,
    hill_stress_tangent_h,
)
from sim.materials.isotropic import (
    NEO_HOOKEAN,
    clamp_psd,
    det3,
    neo_hookean_h,
    polar_svd,
    principal,
    stress_tangent_h,
)
from sim.materials.plasticity import plastic_flow
from sim.solve.assembly import Pattern, drain_element_gradient
from sim.solve.threads import over_colours, over_ranges, total
from sim.terms import PROJECT_ELEMENT, PROJECT_QP, Term
from sim.terms.ans import (
    Tying,
    ans_commit_kernel,
    ans_kernel,
    ans_stress_kernel,
    ans_volume_kernel,
)


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


# the element kernel, inlined into the loop over a block's elements (_elastic_block): its
# scratch arrays come from the caller so no element allocates, and its branches (material law,
# plastic state, what is wanted, projection) are one loop body the compiler specialises; split
# into calls or given its scratch as a tuple it would allocate or lose that inlining in the
# innermost loop
@njit(cache=True, inline='always')
def _element(x: np.ndarray, rest: np.ndarray, nodes: np.ndarray, dNdX: np.ndarray,  # noqa: C901
             wdetJ: np.ndarray, model: int, params: np.ndarray, fp_inv: np.ndarray,
             ep: np.ndarray, frame: np.ndarray, plastic: bool, want: int, project: int,
             g: np.ndarray,
             Kp: np.ndarray, Kf: np.ndarray, pos: np.ndarray, CB: np.ndarray, G: np.ndarray,
             P: np.ndarray, C: np.ndarray, bT: np.ndarray, u: np.ndarray,
             FiT: np.ndarray) -> float:
    """Energy of one element; adds its gradient into ``g (n_en*3,)`` (want >= 1) and writes the
    upper triangle of its Hessian, packed row by row, into ``Kp (k (k+1) / 2,)`` (want == 2).
    The element: its ``nodes (n_en,)`` in x and rest ``(n_nodes, 3)``, ``dNdX (n_qp, n_en, 3)``,
    ``wdetJ (n_qp,)``, material ``params`` (sim.materials.isotropic) and plastic state
    ``fp_inv (n_qp, 3, 3)``, ``ep (n_qp,)`` (read when ``plastic``), its material axes
    ``frame (3, 3)`` (read by an anisotropic material, sim.materials.hill).
    Scratch, reused from element to element: ``Kf (k*k,)``, ``CB (3, 9, k)``,
    ``G, P, FiT (3, 3)``, ``C (9, 9)``, ``bT (3, 3, n_en)``, ``u (n_en, 3)``; ``pos`` maps a
    packed entry to its place in Kf (:func:`packed_positions`).

    The Hessian sum_q w_q B_q^T C_q B_q runs in component-major order (DoF i n_en + a for
    component i of node a), three quadrature points at a time: row block i, columns from
    block i on, so that the column loops are long and contiguous (27, 18, 9 for Q3T) and
    vectorise, and each entry is loaded and stored once per three points. Against one point at
    a time on the packed node-major triangle, this cut the Q3T beam's Hessian arithmetic by
    more than a third (q3t bench).

    Inlined into the kernel's blocks (as are the helpers it calls per quadrature point): a call
    passes each array as a reference-counted struct, and those calls took 55 % of the Q3T beam's
    gradient and 30 % of its Hessian evaluation. numba's cache keys a kernel on its own file
    only; sim/__init__.py therefore keys the cache folder on all of sim's sources, so an edit
    of an inlined helper in another module (sim.materials.isotropic) recompiles this kernel.
    """
    n_en = nodes.shape[0]
    k = 3 * n_en
    ue = np.uint64(n_en)
    E = 0.0
    # Neo-Hookean's closed form serves energy, gradient and exact Hessian; a projected tangent
    # needs the principal frame, whose energy and gradient agree with the closed form's to
    # round-off only: a line search after a projected assembly reads the closed form's
    # energy, not the assembly's (its change within that noise is judged by the residual,
    # sim.solve.newton's line search)
    closed = model == NEO_HOOKEAN and not (want == 2 and project == PROJECT_QP)
    mu, lam = params[0], params[1]
    for a in range(n_en):
        for i in range(3):
            u[a, i] = x[nodes[a], i] - rest[nodes[a], i]
    if want == 2:
        for p in range(np.uint64(k * k)):
            Kf[p] = 0.0
    n_q = dNdX.shape[0]
    for q0 in range(0, n_q, 3):
        m = min(3, n_q - q0)
        for j in range(m):
            q = q0 + j
            for a in range(n_en):
                for J in range(3):
                    if plastic:  # b = dN/dX Fp^-1
                        bT[j, J, a] = (dNdX[q, a, 0] * fp_inv[q, 0, J]
                                       + dNdX[q, a, 1] * fp_inv[q, 1, J]
                                       + dNdX[q, a, 2] * fp_inv[q, 2, J])
                    else:
                        bT[j, J, a] = dNdX[q, a, J]
            # G - I = sum_a u_a (x) b_a: the displacement part, plus Fp^-1 - I under a
            # plastic state (zero before it flows, so an unyielded plastic scene runs on the
            # elastic bits)
            _displacement_gradient(u, bT[j], G)
            if plastic:
                for i in range(3):
                    for J in range(3):
                        G[i, J] += fp_inv[q, i, J] - (1.0 if i == J else 0.0)
            if closed:
                W = neo_hookean_h(G, mu, lam, want == 2, P, C, FiT)
            elif model == HILL48 and want == 0:  # a line search's: W alone
                W = hill_energy_h(G, params, frame, ep[q])
            elif model == HILL48:
                W = hill_stress_tangent_h(G, params, frame, ep[q], want == 2,
                                          want == 2 and project == PROJECT_QP, P, C)
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
                    g[3 * a + i] += w * (P[i, 0] * bT[j, 0, a] + P[i, 1] * bT[j, 1, a]
                                         + P[i, 2] * bT[j, 2, a])
            if want < 2:
                continue
            # CB[i, 3 j + J, kk n_en + bn] = (C_q B_q)[(i, J), (bn, kk)]: contiguous in bn
            for i in range(3):
                for J in range(3):
                    r = 3 * i + J
                    cr = CB[i, 3 * j + J]
                    for kk in range(3):
                        c0, c1, c2 = C[r, 3 * kk], C[r, 3 * kk + 1], C[r, 3 * kk + 2]
                        o = np.uint64(kk) * ue
                        for bn in range(ue):
                            cr[o + bn] = (c0 * bT[j, 0, bn] + c1 * bT[j, 1, bn]
                                          + c2 * bT[j, 2, bn])
        if want < 2:
            continue
        w0 = wdetJ[q0]
        w1 = wdetJ[q0 + 1] if m > 1 else 0.0
        w2 = wdetJ[q0 + 2] if m > 2 else 0.0
        for i in range(3):
            cs = CB[i]  # one base pointer for the nine rows: the column loop vectorises
            lo = np.uint64(i) * ue
            for a in range(n_en):
                kr = Kf[(i * n_en + a) * k:]
                a0, a1, a2 = w0 * bT[0, 0, a], w0 * bT[0, 1, a], w0 * bT[0, 2, a]
                # unsigned column indices: numba then adds no negative-index wraparound
                # test, which keeps these loops scalar
                if m == 3:
                    d0, d1, d2 = w1 * bT[1, 0, a], w1 * bT[1, 1, a], w1 * bT[1, 2, a]
                    e0, e1, e2 = w2 * bT[2, 0, a], w2 * bT[2, 1, a], w2 * bT[2, 2, a]
                    for col in range(lo, np.uint64(k)):
                        kr[col] = (((kr[col] + (a0 * cs[0, col] + a1 * cs[1, col]
                                                + a2 * cs[2, col]))
                                    + (d0 * cs[3, col] + d1 * cs[4, col] + d2 * cs[5, col]))
                                   + (e0 * cs[6, col] + e1 * cs[7, col] + e2 * cs[8, col]))
                elif m == 2:
                    d0, d1, d2 = w1 * bT[1, 0, a], w1 * bT[1, 1, a], w1 * bT[1, 2, a]
                    for col in range(lo, np.uint64(k)):
                        kr[col] = ((kr[col] + (a0 * cs[0, col] + a1 * cs[1, col]
                                               + a2 * cs[2, col]))
                                   + (d0 * cs[3, col] + d1 * cs[4, col] + d2 * cs[5, col]))
                else:
                    for col in range(lo, np.uint64(k)):
                        kr[col] += a0 * cs[0, col] + a1 * cs[1, col] + a2 * cs[2, col]
    if want < 2:
        return E
    for p in range(np.uint64(Kp.shape[0])):
        Kp[p] = Kf[np.uint64(pos[p])]
    if project == PROJECT_ELEMENT:
        K = np.empty((k, k))
        off = 0
        for row in range(k):
            for col in range(row, k):
                K[row, col] = K[col, row] = Kp[off + col - row]
            off += k - row
        clamp_psd(K)
        off = 0
        for row in range(k):
            for col in range(row, k):
                Kp[off + col - row] = K[row, col]
            off += k - row
    return E


def packed_positions(n_en: int) -> np.ndarray:
    """For each entry (r, c), r <= c, of the node-major packed upper triangle (DoF 3 a + i),
    its index in the component-major Hessian ``Kf (k, k)`` of :func:`_element` (DoF
    i n_en + a), which holds column blocks from the row's block on: the entry itself when the
    column's component is not below the row's, else its mirror."""
    k = 3 * n_en
    r, c = np.triu_indices(k)
    a, i, bn, kk = r // 3, r % 3, c // 3, c % 3
    row, col = i * n_en + a, kk * n_en + bn
    return np.where(i <= kk, row * k + col, col * k + row).astype(np.uint64)


def elastic_kernel(x: np.ndarray, rest: np.ndarray, conn: np.ndarray, dNdX: np.ndarray,
                   wdetJ: np.ndarray, model: int, params: np.ndarray, fp_inv: np.ndarray,
                   ep: np.ndarray, frames: np.ndarray, plastic: bool, want: int, project: int,
                   order: np.ndarray,
                   block_ptr: np.ndarray, color_ptr: np.ndarray, slots: np.ndarray, pos: np.ndarray,
                   grad: np.ndarray, data: np.ndarray) -> float:
    """Total energy; adds the gradient into ``grad (n_nodes, 3)`` (want >= 1) and the Hessian
    into ``data (nnz,)`` through the packed upper-triangle ``slots (n_elem, k (k+1) / 2)``
    (want == 2). Blocks of one colour share no node (:class:`sim.solve.assembly.Schedule`), so
    each colour's blocks are shared among the threads without races (sim.solve.threads).
    Returns inf on inversion.
    x, rest ``(n_nodes, 3)``; conn ``(n_elem, n_en)``; dNdX ``(n_elem, n_qp, n_en, 3)``; wdetJ
    ``(n_elem, n_qp)``; fp_inv ``(n_elem, n_qp, 3, 3)`` and ep ``(n_elem, n_qp)``, or their
    empty ``(n_elem, 0, ...)`` versions when not ``plastic``; frames ``(n_elem, 3, 3)`` the
    material axes of an anisotropic material, else ``(n_elem, 0, 0)``; pos as in
    :func:`_element`."""
    energies = np.zeros(conn.shape[0])
    over_colours(_elastic_block, order, block_ptr, color_ptr, x, rest, conn, dNdX, wdetJ, model,
                 params, fp_inv, ep, frames, plastic, want, project, slots, pos, grad, data,
                 energies, scatter=want > 0)
    return total(energies)


@njit(cache=True, nogil=True)
def _elastic_block(x: np.ndarray, rest: np.ndarray, conn: np.ndarray, dNdX: np.ndarray,
                   wdetJ: np.ndarray, model: int, params: np.ndarray, fp_inv: np.ndarray,
                   ep: np.ndarray, frames: np.ndarray, plastic: bool, want: int, project: int,
                   slots: np.ndarray, pos: np.ndarray, grad: np.ndarray, data: np.ndarray,
                   energies: np.ndarray, elements: np.ndarray) -> None:
    """A thread's share of a colour's blocks in :func:`elastic_kernel`: its ``elements`` with
    their scratch, each element's energy into ``energies``, gradient and Hessian scattered."""
    k = 3 * conn.shape[1]
    # scratch per call, for the share's elements (numba's heap arrays, made per element, cost
    # as much as a linear prism's arithmetic); g is handed back zeroed by the scatter that
    # drains it
    g = np.zeros(k)
    Kp = np.empty(k * (k + 1) // 2 if want == 2 else 0)
    Kf = np.empty(k * k if want == 2 else 0)
    CB, C = np.empty((3, 9, k)), np.empty((9, 9))
    G, P = np.empty((3, 3)), np.empty((3, 3))
    bT, u, FiT = np.empty((3, 3, conn.shape[1])), np.empty((conn.shape[1], 3)), np.empty((3, 3))
    for e in elements:
        E = _element(x, rest, conn[e], dNdX[e], wdetJ[e], model, params, fp_inv[e],
                     ep[e], frames[e], plastic, want, project, g, Kp, Kf, pos, CB, G, P,
                     C, bT, u, FiT)
        energies[e] = E
        ok = np.isfinite(E)
        if want >= 1:
            drain_element_gradient(grad, conn[e], g, ok)
        if want == 2 and ok:
            s = slots[e]
            for p in range(Kp.shape[0]):
                # slots are >= 0: unsigned, numba skips the wraparound test
                data[np.uint64(s[p])] += Kp[p]


@njit(cache=True, inline='always')
def _displacement_gradient(u: np.ndarray, bT: np.ndarray, H: np.ndarray) -> None:
    """H = sum_a u_a (x) b_a into ``H (3, 3)``; u ``(n_en, 3)``, b transposed ``(3, n_en)``."""
    for i in range(3):
        for J in range(3):
            H[i, J] = 0.0
    for a in range(u.shape[0]):
        for i in range(3):
            for J in range(3):
                H[i, J] += u[a, i] * bT[J, a]


@njit(cache=True)
def _deformation_gradient(x: np.ndarray, rest: np.ndarray, nodes: np.ndarray, b: np.ndarray,
                          G0: np.ndarray) -> np.ndarray:
    """G = G0 + sum_a (x_a - X_a) (x) b_a, G0 the gradient at rest (I, or Fp^-1)."""
    u = np.empty((nodes.shape[0], 3))
    for a in range(nodes.shape[0]):
        for i in range(3):
            u[a, i] = x[nodes[a], i] - rest[nodes[a], i]
    G = np.empty((3, 3))
    _displacement_gradient(u, b.T, G)
    return G + G0


@njit(cache=True, nogil=True)
def plastic_commit_kernel(x: np.ndarray, rest: np.ndarray, conn: np.ndarray, dNdX: np.ndarray,
                          model: int, params: np.ndarray, frames: np.ndarray, fp_inv: np.ndarray,
                          ep: np.ndarray, e0: int, e1: int) -> None:
    """Return-map every quadrature point of elements e0 to e1 (a thread's share,
    sim.solve.threads) at the converged state x and update, in place,
    Fp^-1 (n_elem, n_qp, 3, 3) <- Fp_n^-1 V diag(exp(-deps_p)) V^T and ep (n_elem, n_qp) += dgamma
    (the flow is isochoric: det Fp^-1 stays 1 to round-off)."""
    mu, law, hp = params[0], int(params[2]), params[3:]
    for e in range(e0, e1):
        for q in range(dNdX.shape[1]):
            G = _deformation_gradient(x, rest, conn[e], dNdX[e, q] @ fp_inv[e, q], fp_inv[e, q])
            if model == HILL48:
                expm, dg = hill_flow(G, params, frames[e], ep[e, q])
                if dg > 0.0:
                    fp_inv[e, q] = fp_inv[e, q] @ expm
                    ep[e, q] += dg
                continue
            U, s, V, ok = polar_svd(G)
            if not ok:
                continue
            eps = np.log(s)
            dep, dg = plastic_flow(eps, ep[e, q], mu, law, hp)
            if dg == 0.0:
                continue
            fp_inv[e, q] = fp_inv[e, q] @ ((V * np.exp(-dep)) @ np.ascontiguousarray(V.T))
            ep[e, q] += dg


@njit(cache=True, nogil=True)
def stress_kernel(x: np.ndarray, rest: np.ndarray, conn: np.ndarray, dNdX: np.ndarray, model: int,
                  params: np.ndarray, frames: np.ndarray, fp_inv: np.ndarray, ep: np.ndarray,
                  plastic: bool, out: np.ndarray, e0: int, e1: int) -> None:
    """Von Mises equivalent of the Cauchy stress into ``out (n_elem, n_qp)``, elements e0 to
    e1, at state x (with the trial return map at the committed plastic state)."""
    for e in range(e0, e1):
        for q in range(dNdX.shape[1]):
            if plastic:
                G = _deformation_gradient(x, rest, conn[e], dNdX[e, q] @ fp_inv[e, q],
                                          fp_inv[e, q])
            else:
                G = _deformation_gradient(x, rest, conn[e], dNdX[e, q], np.eye(3))
            if model == HILL48:
                tau3 = hill_kirchhoff(G, params, frames[e], ep[e, q])
                dev3 = tau3 - np.trace(tau3) / 3.0 * np.eye(3)
                out[e, q] = np.sqrt(1.5 * np.sum(dev3 * dev3)) / det3(G)
                continue
            U, s, V, ok = polar_svd(G)
            if not ok:
                continue
            W, g, H, sym, twist = principal(model, s, params, ep[e, q] if plastic else 0.0)
            tau = g * s  # principal Kirchhoff stress
            dev = tau - tau.mean()
            J = s[0] * s[1] * s[2]  # det G = det F: the plastic part is isochoric
            out[e, q] = np.sqrt(1.5 * (dev @ dev)) / J


class Elasticity(Term):
    """Stored energy of the shell. ``material``: (model id, params array); ``plastic`` state is
    ``fp_inv (n_elem, n_qp, 3, 3)`` and ``ep (n_elem, n_qp)``, or None for an elastic scene;
    ``frames (n_elem, 3, 3)``: the material axes of an anisotropic material (sim.materials.hill)."""

    name = "elasticity"

    def __init__(self, shell: Shell, rule: Rule, model: int, params: np.ndarray, pattern: Pattern,
                 project: int, plastic: bool = False, frames: np.ndarray | None = None):
        _, dN = shell.element.basis(rule.points)
        self.rule = rule
        self.conn = shell.conn
        self.rest = shell.rest
        self.dNdX, self.wdetJ = reference_gradients(shell.rest, shell.conn, dN, rule.weights)
        self.model, self.params = model, np.asarray(params, float)
        self.pattern, self.project = pattern, project
        n_e, n_q = self.wdetJ.shape
        if model == HILL48 and not plastic:  # its kernels read the plastic state
            raise ValueError("Hill48 is a plastic law: its term needs plastic=True")
        self.plastic = plastic
        if plastic:
            self.fp_inv = np.tile(np.eye(3), (n_e, n_q, 1, 1))
            self.ep = np.zeros((n_e, n_q))
        else:  # an elastic scene allocates no plastic state
            self.fp_inv = np.zeros((n_e, 0, 3, 3))
            self.ep = np.zeros((n_e, 0))
        self._pos = packed_positions(self.conn.shape[1])
        # an assumed-strain element's strain comes from its tying points (sim.terms.ans)
        self.tying = Tying(shell, rule) if shell.element.assumed_strain else None
        self.frames = (np.zeros((n_e, 0, 0)) if frames is None
                       else np.ascontiguousarray(frames, dtype=float))

    def _tied(self) -> tuple:
        t = self.tying
        return (self.rest, self.conn, t.dNq, t.dNt, t.lev_ptr, t.rs, t.Gq, t.A0, t.Gt, t.dNc,
                t.Gw)

    def _run(self, x: np.ndarray, want: int, grad: np.ndarray, data: np.ndarray) -> float:
        sc = self.pattern.schedule
        if self.tying is not None:
            return ans_kernel(x, *self._tied(), self.wdetJ, self.model, self.params,
                              self.fp_inv, self.ep, self.frames, self.plastic, want,
                              self.project, sc.order,
                              sc.block_ptr, sc.color_ptr, self.pattern.elem_slots, grad, data)
        return elastic_kernel(x, self.rest, self.conn, self.dNdX, self.wdetJ, self.model,
                              self.params, self.fp_inv, self.ep, self.frames, self.plastic, want,
                              self.project, sc.order, sc.block_ptr, sc.color_ptr,
                              self.pattern.elem_slots, self._pos, grad, data)

    def energy(self, x: np.ndarray) -> float:
        return self._run(x, 0, np.zeros((0, 3)), np.zeros(0))

    def add_gradient(self, x: np.ndarray, g: np.ndarray) -> float:
        return self._run(x, 1, g, np.zeros(0))

    def add_hessian(self, x: np.ndarray, data: np.ndarray) -> float:
        return self._run(x, 2, np.zeros(x.shape), data)

    def add_gradient_hessian(self, x: np.ndarray, g: np.ndarray, data: np.ndarray) -> float:
        return self._run(x, 2, g, data)

    def commit(self, x: np.ndarray) -> None:
        n = len(self.conn)
        if self.plastic and self.tying is not None:
            over_ranges(ans_commit_kernel, 0, n, x, *self._tied(), self.model, self.params,
                        self.frames, self.fp_inv, self.ep)
        elif self.plastic:
            over_ranges(plastic_commit_kernel, 0, n, x, self.rest, self.conn, self.dNdX,
                        self.model, self.params, self.frames, self.fp_inv, self.ep)

    def volume_ratios(self, x: np.ndarray) -> np.ndarray:
        """The material's volume ratio J per element and quadrature point ``(n_elem, n_qp)``:
        det F of the interpolated field, or an assumed-strain element's J of its own strain,
        the volume its material keeps (on a bent sheet its interpolated geometry's columns
        are chords between fanned directors, sim.terms.ans)."""
        if self.tying is not None:
            out = np.zeros(self.wdetJ.shape)
            over_ranges(ans_volume_kernel, 0, len(self.conn), x, *self._tied(), out)
            return out
        F = np.einsum("ead,eqaj->eqdj", x[self.conn], self.dNdX)
        return np.linalg.det(F)

    def von_mises(self, x: np.ndarray) -> np.ndarray:
        """Von Mises stress (Pa) per element and quadrature point ``(n_elem, n_qp)``."""
        out = np.zeros(self.wdetJ.shape)
        if self.tying is not None:
            over_ranges(ans_stress_kernel, 0, len(self.conn), x, *self._tied(), self.model,
                        self.params, self.frames, self.fp_inv, self.ep, self.plastic, out)
        else:
            over_ranges(stress_kernel, 0, len(self.conn), x, self.rest, self.conn, self.dNdX,
                        self.model, self.params, self.frames, self.fp_inv, self.ep,
                        self.plastic, out)
        return out

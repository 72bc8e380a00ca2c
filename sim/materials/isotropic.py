"""Isotropic hyperelastic energies in principal stretches, and the 3x3 -> 9x9 lifting.

An isotropic energy psi(F) depends on the singular values s of F = U diag(s) V^T only. Its first
Piola-Kirchhoff stress is P = U diag(psi_i) V^T and its tangent dP/dF is block-diagonal in the
basis {u_a v_b^T} (Teran et al. 2005; Smith et al. 2019):
  - a 3x3 block psi_ab on the diagonal directions u_a v_a^T,
  - per pair i < j, a "symmetric" direction (u_i v_j^T + u_j v_i^T)/sqrt2 with eigenvalue
    (psi_i - psi_j)/(s_i - s_j) and a "twist" (u_i v_j^T - u_j v_i^T)/sqrt2 with eigenvalue
    (psi_i + psi_j)/(s_i + s_j).
Clamping the 3x3 block's eigenvalues and the six pair eigenvalues at zero gives the projection of
dP/dF to positive semi-definite at no extra cost. Divided differences are formed without
cancellation, so equal stretches (the rest state) are exact.

Models (``model`` integer): 0 compressible Neo-Hookean
  psi = mu/2 (tr F^T F - 3) - mu ln J + lam/2 ln^2 J,
1 Hencky: psi = mu |ln V|^2 + lam/2 tr^2(ln V) with ln V the principal log stretches,
2 Hencky elastoplastic (von Mises), whose principal energy is the incremental potential of
sim.materials.plasticity. ``params = [mu, lam, law, hp...]``; ``ep_n`` is the committed
equivalent plastic strain (0 for elastic models).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from sim.materials.plasticity import incremental_energy, return_map_into

NEO_HOOKEAN, HENCKY, HENCKY_PLASTIC = 0, 1, 2
PAIRS = np.array([[0, 1], [0, 2], [1, 2]])


@njit(cache=True)
def dlog(a: float, b: float) -> float:
    """(ln a - ln b) / (a - b), exact as a -> b; symmetric. ln(a / b) as log1p(r) with
    r = (a - b) / b >= 0 (the larger argument first): the difference of the two logarithms
    cancels, which lost up to 5e-12 of the value at r = 1e-4 with a, b near 4 (a stretch of
    2); log1p's is a few ulps, and from r >= 0 it stays so however far apart a and b are (r
    near -1 would carry its rounding into the logarithm)."""
    if a < b:
        a, b = b, a
    r = (a - b) / b
    if r < 1e-4:
        return (1.0 - r / 2 + r * r / 3 - r * r * r / 4) / b
    if r < np.inf:
        return np.log1p(r) / (a - b)
    return (np.log(a) - np.log(b)) / (a - b)  # a / b beyond the largest float


@njit(cache=True, inline='always')
def _from_log(s: np.ndarray, tau: np.ndarray, D: np.ndarray, a_dd: float,
              pr: np.ndarray) -> None:
    """Principal derivatives in stretches s (3,) from those in log strains (Kirchhoff
    tau = dW/deps (3,), D = dtau/deps (3, 3)) into ``pr`` (:func:`principal_into`)."""
    for i in range(3):
        pr[0, i] = tau[i] / s[i]
    for i in range(3):
        for j in range(3):
            pr[1 + i, j] = D[i, j] / (s[i] * s[j])
        pr[1 + i, i] -= tau[i] / (s[i] * s[i])
    for k in range(3):
        i, j = PAIRS[k, 0], PAIRS[k, 1]
        pr[4, k] = a_dd * dlog(s[i], s[j]) / s[i] - tau[j] / (s[i] * s[j])
    for k in range(3):  # after sym: tau may be pr[5] (principal_into)
        i, j = PAIRS[k, 0], PAIRS[k, 1]
        pr[5, k] = (pr[0, i] + pr[0, j]) / (s[i] + s[j])


@njit(cache=True)
def _sq_minus_log(s: float) -> float:
    """s^2 - 1 - 2 ln s without cancellation near s = 1 (it is O((s-1)^2) there)."""
    d = s - 1.0
    if abs(d) < 1e-2:  # series of d - log1p(d), truncation below 1e-20 relative
        t = d * d / 2 - d**3 / 3 + d**4 / 4 - d**5 / 5 + d**6 / 6 - d**7 / 7 + d**8 / 8
        return d * d + 2 * t
    return s * s - 1.0 - 2.0 * np.log(s)


@njit(cache=True, inline='always')
def _neo_hookean_energy(s0: float, s1: float, s2: float, mu: float,
                        lam: float) -> tuple[float, float]:
    """(W, ln J) at stretches s0, s1, s2."""
    lj = np.log(s0) + np.log(s1) + np.log(s2)
    # mu/2 (I1 - 3) - mu ln J summed per stretch: the two O(s-1) parts cancel analytically,
    # so energy differences near rest are not lost in round-off (the line search needs them)
    W = 0.5 * mu * (_sq_minus_log(s0) + _sq_minus_log(s1) + _sq_minus_log(s2))
    return W + 0.5 * lam * lj * lj, lj


@njit(cache=True, inline='always')
def _neo_hookean(s: np.ndarray, mu: float, lam: float, pr: np.ndarray) -> float:
    W, lj = _neo_hookean_energy(s[0], s[1], s[2], mu, lam)
    c = mu - lam * lj
    for i in range(3):
        pr[0, i] = mu * s[i] - c / s[i]
    for i in range(3):
        for j in range(3):
            pr[1 + i, j] = lam / (s[i] * s[j])
        pr[1 + i, i] += mu + c / (s[i] * s[i])
    for k in range(3):
        p = s[PAIRS[k, 0]] * s[PAIRS[k, 1]]
        pr[4, k] = mu + c / p
        pr[5, k] = mu - c / p
    return W


@njit(cache=True, inline='always')
def _hencky_energy(e0: float, e1: float, e2: float, mu: float, lam: float) -> float:
    """W at the principal log strains e0, e1, e2."""
    tr = e0 + e1 + e2
    return mu * (e0 * e0 + e1 * e1 + e2 * e2) + 0.5 * lam * tr * tr


@njit(cache=True)
def principal_energy(model: int, s0: float, s1: float, s2: float, params: np.ndarray,
                     ep_n: float) -> float:
    """W of :func:`principal` alone, at stretches s0, s1, s2: a line search's energy, with no
    stress, tangent or array."""
    mu, lam = params[0], params[1]
    if model == NEO_HOOKEAN:
        return _neo_hookean_energy(s0, s1, s2, mu, lam)[0]
    e0, e1, e2 = np.log(s0), np.log(s1), np.log(s2)
    if model == HENCKY:
        return _hencky_energy(e0, e1, e2, mu, lam)
    return incremental_energy(e0, e1, e2, ep_n, mu, lam, int(params[2]), params[3:])


@njit(cache=True)
def principal_into(model: int, s: np.ndarray, params: np.ndarray, ep_n: float,
                   pr: np.ndarray) -> float:
    """:func:`principal` into the scratch ``pr (7, 3)``: rows 0 dW/ds, 1-3 d2W/ds2, 4 sym,
    5 twist (6 scratch): a quadrature point's law with no array made. Returns W. The log
    strains' tau and D are formed in the rows of twist and d2W/ds2, which _from_log turns
    into them in place."""
    mu, lam = params[0], params[1]
    if model == NEO_HOOKEAN:
        return _neo_hookean(s, mu, lam, pr)
    eps = pr[6]
    for i in range(3):
        eps[i] = np.log(s[i])
    if model == HENCKY:
        W = _hencky_energy(eps[0], eps[1], eps[2], mu, lam)
        tr = eps[0] + eps[1] + eps[2]
        tau = pr[5]
        for i in range(3):
            tau[i] = 2 * mu * eps[i] + lam * tr
        for i in range(3):
            for j in range(3):
                pr[1 + i, j] = lam + (2 * mu if i == j else 0.0)
        _from_log(s, tau, pr[1:4], 2 * mu, pr)
        return W
    return _plastic_principal(s, eps, params, ep_n, pr)


@njit(cache=True, inline='always')
def _plastic_principal(s: np.ndarray, eps: np.ndarray, params: np.ndarray, ep_n: float,
                       pr: np.ndarray) -> float:
    tau, D = pr[5], pr[1:4]
    W, a_dd, _ = return_map_into(eps, ep_n, params[0], params[1], int(params[2]), params[3:],
                                 tau, D)
    _from_log(s, tau, D, a_dd, pr)
    return W


@njit(cache=True)
def principal(model: int, s: np.ndarray, params: np.ndarray,
              ep_n: float) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Principal energy at stretches s (3,): (W, dW/ds (3,), d2W/ds2 (3,3), sym (3,),
    twist (3,)) for pairs (0,1), (0,2), (1,2)."""
    pr = np.empty((7, 3))
    W = principal_into(model, s, params, ep_n, pr)
    return W, pr[0].copy(), pr[1:4].copy(), pr[4].copy(), pr[5].copy()


@njit(cache=True)
def eigh3_into(A: np.ndarray, a: np.ndarray, w: np.ndarray, V: np.ndarray,
               vectors: bool) -> None:
    """Eigen-decomposition of a symmetric 3x3 ``A`` by cyclic Jacobi rotations into ``w (3,)``
    ascending and, when ``vectors``, ``V (3, 3)``; ``a (3, 3)`` scratch. About 20x cheaper
    than a LAPACK call from numba at this size, and accurate to round-off relative to |A|.
    The rotations do not depend on V, so the eigenvalues alone (an energy's) are the same
    numbers as with the vectors."""
    for i in range(3):
        for j in range(3):
            a[i, j] = A[i, j]
            if vectors:
                V[i, j] = 1.0 if i == j else 0.0
    for _ in range(12):
        off = a[0, 1] ** 2 + a[0, 2] ** 2 + a[1, 2] ** 2
        if off <= 1e-40 * (a[0, 0] ** 2 + a[1, 1] ** 2 + a[2, 2] ** 2) or off == 0.0:
            break
        for p, q in ((0, 1), (0, 2), (1, 2)):
            _jacobi_rotation(a, V, vectors, p, q)
    w[0], w[1], w[2] = a[0, 0], a[1, 1], a[2, 2]
    _ascending(w, V, vectors)


@njit(cache=True, inline='always')
def _jacobi_rotation(a: np.ndarray, V: np.ndarray, vectors: bool, p: int, q: int) -> None:
    """The rotation that zeroes a[p, q], applied to a and (``vectors``) to V's columns."""
    apq = a[p, q]
    if apq == 0.0:
        return
    _, c, s = _rotation(a[p, p], a[q, q], apq)
    for k in range(3):  # a <- a J
        akp, akq = a[k, p], a[k, q]
        a[k, p] = c * akp - s * akq
        a[k, q] = s * akp + c * akq
    for k in range(3):  # a <- J^T a
        apk, aqk = a[p, k], a[q, k]
        a[p, k] = c * apk - s * aqk
        a[q, k] = s * apk + c * aqk
    if vectors:
        _rotate_columns(V, p, q, c, s)


@njit(cache=True, inline='always')
def _jacobi_settled(a00: float, a11: float, a22: float, a01: float, a02: float,
                    a12: float) -> bool:
    off = a01 * a01 + a02 * a02 + a12 * a12
    return off <= 1e-40 * (a00 * a00 + a11 * a11 + a22 * a22) or off == 0.0


@njit(cache=True, inline='always')
def _jacobi_sweep(a00: float, a11: float, a22: float, a01: float, a02: float, a12: float,
                  V: np.ndarray, vectors: bool) -> tuple[float, float, float, float, float,
                                                         float]:
    """One cyclic sweep on the six entries (the rotated ones by the symmetric update, the
    zeroed one set to zero), V's columns rotated with it (``vectors``)."""
    if a01 != 0.0:  # (p, q, r) = (0, 1, 2)
        a00, a11, a02, a12, c, s = _rotated(a00, a11, a01, a02, a12)
        a01 = 0.0
        if vectors:
            _rotate_columns(V, 0, 1, c, s)
    if a02 != 0.0:  # (0, 2, 1)
        a00, a22, a01, a12, c, s = _rotated(a00, a22, a02, a01, a12)
        a02 = 0.0
        if vectors:
            _rotate_columns(V, 0, 2, c, s)
    if a12 != 0.0:  # (1, 2, 0)
        a11, a22, a01, a02, c, s = _rotated(a11, a22, a12, a01, a02)
        a12 = 0.0
        if vectors:
            _rotate_columns(V, 1, 2, c, s)
    return a00, a11, a22, a01, a02, a12


@njit(cache=True)
def jacobi3_lanes_into(A: np.ndarray, n: int, w: np.ndarray, V: np.ndarray,
                       vectors: bool) -> None:
    """:func:`eigh3_into`'s cyclic Jacobi rotations for the symmetric ``A[l] (3, 3)`` of up to
    three lanes l < n at once, each on its six entries held as scalars, no scratch:
    eigenvalues ``w[l] (3,)`` ascending, the same numbers with or without the vectors
    ``V[l] (3, 3)`` (``A, V (>= 3, 3, 3)``, ``w (>= 3, 3)``). An assumed-strain point
    decomposes E^ at every evaluation, and each rotation is a chain of square roots and
    divisions that waits on the one before; the lanes' chains are independent, and
    interleaved the processor overlaps them (docs/elements-ans.md has the measurements). Each
    lane's arithmetic is the one it would take alone."""
    x0 = (A[0, 0, 0], A[0, 1, 1], A[0, 2, 2], A[0, 0, 1], A[0, 0, 2], A[0, 1, 2])
    x1, x2 = x0, x0
    if n > 1:
        x1 = (A[1, 0, 0], A[1, 1, 1], A[1, 2, 2], A[1, 0, 1], A[1, 0, 2], A[1, 1, 2])
    if n > 2:
        x2 = (A[2, 0, 0], A[2, 1, 1], A[2, 2, 2], A[2, 0, 1], A[2, 0, 2], A[2, 1, 2])
    if vectors:
        for lane in range(n):
            for i in range(3):
                for j in range(3):
                    V[lane, i, j] = 1.0 if i == j else 0.0
    d0, d1, d2 = False, n < 2, n < 3
    for _ in range(12):
        d0 = d0 or _jacobi_settled(x0[0], x0[1], x0[2], x0[3], x0[4], x0[5])
        d1 = d1 or _jacobi_settled(x1[0], x1[1], x1[2], x1[3], x1[4], x1[5])
        d2 = d2 or _jacobi_settled(x2[0], x2[1], x2[2], x2[3], x2[4], x2[5])
        if d0 and d1 and d2:
            break
        if not d0:
            x0 = _jacobi_sweep(x0[0], x0[1], x0[2], x0[3], x0[4], x0[5], V[0], vectors)
        if not d1:
            x1 = _jacobi_sweep(x1[0], x1[1], x1[2], x1[3], x1[4], x1[5], V[1], vectors)
        if not d2:
            x2 = _jacobi_sweep(x2[0], x2[1], x2[2], x2[3], x2[4], x2[5], V[2], vectors)
    for lane in range(n):
        x = x0 if lane == 0 else (x1 if lane == 1 else x2)
        w[lane, 0], w[lane, 1], w[lane, 2] = x[0], x[1], x[2]
        _ascending(w[lane], V[lane], vectors)


@njit(cache=True, inline='always')
def _rotated(app: float, aqq: float, apq: float, arp: float,
             arq: float) -> tuple[float, float, float, float, float, float]:
    """The entries (pp, qq, rp, rq) after the rotation (c, s) that zeroes a[p, q]."""
    t, c, s = _rotation(app, aqq, apq)
    return app - t * apq, aqq + t * apq, c * arp - s * arq, s * arp + c * arq, c, s


@njit(cache=True, inline='always')
def _rotation(app: float, aqq: float, apq: float) -> tuple[float, float, float]:
    """Jacobi's rotation zeroing a[p, q] (apq != 0): its tangent t, cosine c and sine s."""
    theta = (aqq - app) / (2.0 * apq)
    t = np.sign(theta) / (abs(theta) + np.sqrt(theta * theta + 1.0))
    if theta == 0.0:
        t = 1.0
    c = 1.0 / np.sqrt(t * t + 1.0)
    return t, c, t * c


@njit(cache=True, inline='always')
def _rotate_columns(V: np.ndarray, p: int, q: int, c: float, s: float) -> None:
    for k in range(3):
        vkp, vkq = V[k, p], V[k, q]
        V[k, p] = c * vkp - s * vkq
        V[k, q] = s * vkp + c * vkq


@njit(cache=True, inline='always')
def _ascending(w: np.ndarray, V: np.ndarray, vectors: bool) -> None:
    """w (3,) sorted by swaps, V's columns with it: no argsort and fancy-index copies."""
    for i in range(2):
        for j in range(2 - i):
            if w[j] > w[j + 1]:
                w[j], w[j + 1] = w[j + 1], w[j]
                if vectors:
                    for k in range(3):
                        V[k, j], V[k, j + 1] = V[k, j + 1], V[k, j]


@njit(cache=True)
def eigh3(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`eigh3_into`, allocating: (w (3,), V (3, 3)), ascending."""
    w, V = np.empty(3), np.empty((3, 3))
    eigh3_into(A, np.empty((3, 3)), w, V, True)
    return w, V


@njit(cache=True)
def det3(F: np.ndarray) -> float:
    return (F[0, 0] * (F[1, 1] * F[2, 2] - F[1, 2] * F[2, 1])
            - F[0, 1] * (F[1, 0] * F[2, 2] - F[1, 2] * F[2, 0])
            + F[0, 2] * (F[1, 0] * F[2, 1] - F[1, 1] * F[2, 0]))


@njit(cache=True)
def polar_svd(F: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """F (3, 3) = U diag(s) V^T with s > 0 for det F > 0, via the eigen-decomposition of F^T F.

    Returns (U, s, V, ok); ok is False for det F <= 0 (inverted or flat), where the energies are
    +inf by definition.
    """
    det = det3(F)
    if not det > 0.0:
        return np.eye(3), np.ones(3), np.eye(3), False
    A = np.empty((3, 3))  # F^T F, written out: numba sends 3x3 @ to BLAS at ~10x the cost
    for i in range(3):
        for j in range(3):
            A[i, j] = F[0, i] * F[0, j] + F[1, i] * F[1, j] + F[2, i] * F[2, j]
    lam2, V = eigh3(A)
    s = np.sqrt(np.maximum(lam2, 1e-300))
    U = np.empty((3, 3))
    for i in range(3):
        for a in range(3):
            U[i, a] = (F[i, 0] * V[0, a] + F[i, 1] * V[1, a] + F[i, 2] * V[2, a]) / s[a]
    return U, s, V, True


@njit(cache=True)
def _y_minus_log1p(y: float) -> float:
    """y - ln(1 + y) without cancellation near y = 0 (it is O(y^2) there)."""
    if abs(y) < 1e-2:  # alternating series, truncation below 1e-20 relative
        return y * y * (1 / 2 - y * (1 / 3 - y * (1 / 4 - y * (1 / 5 - y * (1 / 6 - y * (
            1 / 7 - y * (1 / 8 - y / 9)))))))
    return y - np.log1p(y)


@njit(cache=True, inline='always')
def neo_hookean_green(Eh: np.ndarray, mu: float, lam: float) -> tuple[float, float]:
    """Neo-Hookean W and ln J from the Green-Lagrange strain ``Eh (3, 3)`` (C = I + 2 Eh), for
    elements whose strain is not the gradient of a displacement (assumed strains): the same
    cancellation-free form as :func:`neo_hookean_h` in E = 2 Eh. W = inf when det C <= 0."""
    e00, e11, e22 = 2.0 * Eh[0, 0], 2.0 * Eh[1, 1], 2.0 * Eh[2, 2]
    e01, e02, e12 = 2.0 * Eh[0, 1], 2.0 * Eh[0, 2], 2.0 * Eh[1, 2]
    c2 = e00 * e11 - e01 ** 2 + e00 * e22 - e02 ** 2 + e11 * e22 - e12 ** 2
    d3 = (e00 * (e11 * e22 - e12 ** 2) - e01 * (e01 * e22 - e12 * e02)
          + e02 * (e01 * e12 - e11 * e02))
    y = e00 + e11 + e22 + c2 + d3  # det C - 1 = J^2 - 1
    if not y > -1.0:
        return np.inf, 0.0
    lj = 0.5 * np.log1p(y)
    return 0.5 * mu * (_y_minus_log1p(y) - c2 - d3) + 0.5 * lam * lj * lj, lj


@njit(cache=True, inline='always')
def neo_hookean_h(H: np.ndarray, mu: float, lam: float, want_tangent: bool, P: np.ndarray,
                  C: np.ndarray, FiT: np.ndarray) -> float:
    """Neo-Hookean W, P and dP/dF at F = I + H from the displacement gradient H (3, 3) (no SVD,
    about 5x cheaper): the exact tangent only, since its PSD projection needs the principal frame.
    ``FiT (3, 3)`` is scratch (it receives F^-T), so that no array is made per call.

    The energy goes through E = F^T F - I = H + H^T + H^T H and J - 1 = tr H + c2(H) + det H
    (c2: the sum of the principal 2x2 minors), both formed from H so a strain keeps its relative
    digits however small it is. E is O(strain) whatever the rotation (F - I is not, for a bent
    shell): with y = det(I + E) - 1, I1 - 3 - 2 ln J = tr E - ln(1 + y) =
    (y - ln(1 + y)) - c2(E) - det E. Every part is O(|E|^2) and its round-off O(|E| eps), as in
    the principal-stretch form, so small strains under large rotations keep their digits (the
    line search needs them).
    P = mu F + (lam ln J - mu) F^-T,
    C[iJ, kL] = mu d_ik d_JL + lam Fi[J, i] Fi[L, k] + (mu - lam ln J) Fi[J, k] Fi[L, i].
    """
    jm1 = (H[0, 0] + H[1, 1] + H[2, 2]
           + H[0, 0] * H[1, 1] - H[0, 1] * H[1, 0] + H[0, 0] * H[2, 2] - H[0, 2] * H[2, 0]
           + H[1, 1] * H[2, 2] - H[1, 2] * H[2, 1] + det3(H))
    if not jm1 > -1.0:
        for i in range(3):
            for j in range(3):
                P[i, j] = 0.0
        return np.inf
    # no temporaries: one evaluation runs per quadrature point, and numba's heap arrays cost
    # as much as this arithmetic (with the element's own, about a third of the Q3T beam's
    # energy and gradient; q3t bench measures it)
    e00 = 2.0 * H[0, 0] + H[0, 0] * H[0, 0] + H[1, 0] * H[1, 0] + H[2, 0] * H[2, 0]
    e11 = 2.0 * H[1, 1] + H[0, 1] * H[0, 1] + H[1, 1] * H[1, 1] + H[2, 1] * H[2, 1]
    e22 = 2.0 * H[2, 2] + H[0, 2] * H[0, 2] + H[1, 2] * H[1, 2] + H[2, 2] * H[2, 2]
    e01 = H[0, 1] + H[1, 0] + H[0, 0] * H[0, 1] + H[1, 0] * H[1, 1] + H[2, 0] * H[2, 1]
    e02 = H[0, 2] + H[2, 0] + H[0, 0] * H[0, 2] + H[1, 0] * H[1, 2] + H[2, 0] * H[2, 2]
    e12 = H[1, 2] + H[2, 1] + H[0, 1] * H[0, 2] + H[1, 1] * H[1, 2] + H[2, 1] * H[2, 2]
    c2 = e00 * e11 - e01 ** 2 + e00 * e22 - e02 ** 2 + e11 * e22 - e12 ** 2
    d3 = (e00 * (e11 * e22 - e12 ** 2) - e01 * (e01 * e22 - e12 * e02)
          + e02 * (e01 * e12 - e11 * e02))
    y = jm1 * (2.0 + jm1)  # J^2 - 1
    lj = np.log1p(jm1)
    W = 0.5 * mu * (_y_minus_log1p(y) - c2 - d3) + 0.5 * lam * lj * lj
    J = 1.0 + jm1
    f00, f01, f02 = 1.0 + H[0, 0], H[0, 1], H[0, 2]
    f10, f11, f12 = H[1, 0], 1.0 + H[1, 1], H[1, 2]
    f20, f21, f22 = H[2, 0], H[2, 1], 1.0 + H[2, 2]
    # F^-T = cof(F) / J
    FiT[0, 0] = (f11 * f22 - f12 * f21) / J
    FiT[1, 0] = (f02 * f21 - f01 * f22) / J
    FiT[2, 0] = (f01 * f12 - f02 * f11) / J
    FiT[0, 1] = (f12 * f20 - f10 * f22) / J
    FiT[1, 1] = (f00 * f22 - f02 * f20) / J
    FiT[2, 1] = (f02 * f10 - f00 * f12) / J
    FiT[0, 2] = (f10 * f21 - f11 * f20) / J
    FiT[1, 2] = (f01 * f20 - f00 * f21) / J
    FiT[2, 2] = (f00 * f11 - f01 * f10) / J
    a = lam * lj - mu
    if want_tangent:  # Fi[J, i] = FiT[i, J]
        for i in range(3):
            for jj in range(3):
                r = 3 * i + jj
                for k in range(3):
                    for ll in range(3):
                        C[r, 3 * k + ll] = (lam * FiT[i, jj] * FiT[k, ll]
                                            - a * FiT[k, jj] * FiT[i, ll])
                C[r, r] += mu
    for i in range(3):  # P = mu F + a F^-T, rounded as mu (H + I) + a F^-T
        for j in range(3):
            P[i, j] = mu * (H[i, j] + (1.0 if i == j else 0.0)) + a * FiT[i, j]
    return W


@njit(cache=True)
def stress_tangent(model: int, F: np.ndarray, params: np.ndarray, ep_n: float, want_tangent: bool,
                   project: bool) -> tuple[float, np.ndarray, np.ndarray]:
    """Energy density W, first Piola-Kirchhoff P (3,3) and tangent C = dP/dF (9,9) at F (3,3), in
    row-major vec(F) order. ``project`` clamps C to positive semi-definite. W = inf when
    det F <= 0."""
    P = np.zeros((3, 3))
    C = np.zeros((9, 9))
    W = stress_tangent_into(model, F, params, ep_n, want_tangent, project, P, C)
    return W, P, C


@njit(cache=True)
def stress_tangent_into(model: int, F: np.ndarray, params: np.ndarray, ep_n: float,
                        want_tangent: bool, project: bool, P: np.ndarray, C: np.ndarray) -> float:
    """:func:`stress_tangent` writing P and C (when ``want_tangent``) into the given arrays
    (the element loop reuses them: allocation per quadrature point costs as much as the
    arithmetic). Returns W."""
    if model == NEO_HOOKEAN:
        H = F.copy()
        for i in range(3):
            H[i, i] -= 1.0
        return stress_tangent_h(model, H, params, ep_n, want_tangent, project, P, C)
    return principal_stress_tangent_into(model, F, params, ep_n, want_tangent, project, P, C)


@njit(cache=True)
def stress_tangent_h(model: int, H: np.ndarray, params: np.ndarray, ep_n: float, want_tangent: bool,
                     project: bool, P: np.ndarray, C: np.ndarray) -> float:
    """:func:`stress_tangent_into` at F = I + H, from H = F - I. Neo-Hookean's W and P always
    come from the closed form in H (so an energy or a gradient does not depend on whether the
    Hessian is projected); only a projected tangent goes through the principal frame."""
    if model == NEO_HOOKEAN:
        W = neo_hookean_h(H, params[0], params[1], want_tangent and not project, P, C,
                          np.empty((3, 3)))
        if want_tangent and project and np.isfinite(W):
            F = H.copy()
            for i in range(3):
                F[i, i] += 1.0
            Pp = np.empty((3, 3))
            principal_stress_tangent_into(model, F, params, 0.0, True, True, Pp, C)
        return W
    F = H.copy()
    for i in range(3):
        F[i, i] += 1.0
    return principal_stress_tangent_into(model, F, params, ep_n, want_tangent, project, P, C)


@njit(cache=True)
def clamp_psd(K: np.ndarray) -> None:
    """K (n x n, symmetric, both triangles) <- its projection to positive semi-definite: its
    eigenvalues clamped at zero. A K whose Cholesky factorisation goes through (positive
    definite) is its own projection to round-off and takes no eigen-decomposition: the
    factorisation costs a small part of one (n^3 / 6 multiplications against LAPACK's call
    and its work arrays), and a point's tangent under tension mostly is definite."""
    n = K.shape[0]
    if _cholesky_ok(K, np.empty((n, n))):
        return
    ev, Q = np.linalg.eigh(K)
    K[:, :] = (Q * np.maximum(ev, 0.0)) @ Q.T


@njit(cache=True, inline='always')
def _cholesky_ok(K: np.ndarray, L: np.ndarray) -> bool:
    """Whether K's Cholesky factorisation (into the scratch ``L``) goes through."""
    n = K.shape[0]
    for j in range(n):
        d = K[j, j]
        for m in range(j):
            d -= L[j, m] * L[j, m]
        if not d > 0.0:
            return False
        L[j, j] = np.sqrt(d)
        for i in range(j + 1, n):
            v = K[i, j]
            for m in range(j):
                v -= L[i, m] * L[j, m]
            L[i, j] = v / L[j, j]
    return True


@njit(cache=True)
def clamp_psd_into(K: np.ndarray, Q: np.ndarray, d: np.ndarray, e: np.ndarray) -> None:
    """:func:`clamp_psd` for the small matrices of an element's loop, on scratch ``Q (n, n)``,
    ``d, e (n,)``: the eigen-decomposition by Householder tridiagonalisation and implicit QL
    (:func:`sym_eig_into`), not LAPACK's, whose call and work arrays cost more than its
    arithmetic at this size (LAPACK's where the QL iteration does not converge)."""
    if _cholesky_ok(K, Q):
        return
    for i in range(K.shape[0]):
        for j in range(K.shape[0]):
            Q[i, j] = K[i, j]
    if not sym_eig_into(Q, d, e):
        clamp_psd(K)
        return
    n = K.shape[0]
    for i in range(n):
        d[i] = max(d[i], 0.0)
    for i in range(n):
        for j in range(i, n):
            acc = 0.0
            for m in range(n):
                acc += Q[i, m] * d[m] * Q[j, m]
            K[i, j] = acc
            K[j, i] = acc


@njit(cache=True)
def sym_eig_into(Q: np.ndarray, d: np.ndarray, e: np.ndarray) -> bool:
    """Eigenvalues ``d (n,)`` and eigenvectors (Q's columns) of the symmetric ``Q (n, n)``,
    overwritten: Householder reduction to tridiagonal form, then the QL algorithm with
    implicit shifts (tred2 and tqli, Numerical Recipes 11.2-11.3); ``e (n,)`` scratch. False
    where an eigenvalue takes over 30 iterations (Q then not its eigenvectors)."""
    _tridiagonalise(Q, d, e)
    return _tql(Q, d, e)


@njit(cache=True, inline='always')
def _tridiagonalise(a: np.ndarray, d: np.ndarray, e: np.ndarray) -> None:
    """a <- Q of a = Q T Q^T, T's diagonal in d and its subdiagonal in e[1:] (e[0] = 0)."""
    n = a.shape[0]
    for i in range(n - 1, 0, -1):
        d[i] = _householder(a, e, i) if i > 1 else 0.0
        if i == 1:
            e[i] = a[i, i - 1]
    d[0] = 0.0
    e[0] = 0.0
    for i in range(n):  # Q from the reflections, last first
        if d[i] != 0.0:
            for j in range(i):
                g = 0.0
                for k in range(i):
                    g += a[i, k] * a[k, j]
                for k in range(i):
                    a[k, j] -= g * a[k, i]
        d[i] = a[i, i]
        a[i, i] = 1.0
        for j in range(i):
            a[j, i] = 0.0
            a[i, j] = 0.0


@njit(cache=True, inline='always')
def _householder(a: np.ndarray, e: np.ndarray, i: int) -> float:
    """The reflection that zeroes row i of a left of its subdiagonal, applied to a's leading
    i x i block; e[i] the subdiagonal, the reflection kept in row i and column i. Returns its
    h (0: none)."""
    h = 0.0
    scale = 0.0
    for k in range(i):
        scale += abs(a[i, k])
    if scale == 0.0:
        e[i] = a[i, i - 1]
        return 0.0
    for k in range(i):
        a[i, k] /= scale
        h += a[i, k] * a[i, k]
    f = a[i, i - 1]
    g = -np.sqrt(h) if f >= 0.0 else np.sqrt(h)
    e[i] = scale * g
    h -= f * g
    a[i, i - 1] = f - g
    f = 0.0
    for j in range(i):
        a[j, i] = a[i, j] / h
        g = 0.0
        for k in range(j + 1):
            g += a[j, k] * a[i, k]
        for k in range(j + 1, i):
            g += a[k, j] * a[i, k]
        e[j] = g / h
        f += e[j] * a[i, j]
    hh = f / (h + h)
    for j in range(i):
        f = a[i, j]
        g = e[j] - hh * f
        e[j] = g
        for k in range(j + 1):
            a[j, k] -= f * e[k] + g * a[i, k]
    return h


@njit(cache=True, inline='always')
def _tql(z: np.ndarray, d: np.ndarray, e: np.ndarray) -> bool:
    """The tridiagonal (d, e) of :func:`_tridiagonalise` diagonalised by implicit QL, its
    rotations applied to z's columns."""
    n = d.shape[0]
    for i in range(1, n):
        e[i - 1] = e[i]
    e[n - 1] = 0.0
    for ll in range(n):
        it = 0
        while True:
            m = ll
            while m < n - 1:
                dd = abs(d[m]) + abs(d[m + 1])
                if abs(e[m]) <= 2.2e-16 * dd:
                    break
                m += 1
            if m == ll:
                break
            if it == 30:
                return False
            it += 1
            g = (d[ll + 1] - d[ll]) / (2.0 * e[ll])
            r = np.sqrt(g * g + 1.0)  # not hypot, a libm call: |g| is below 1e16 here
            g = d[m] - d[ll] + e[ll] / (g + (r if g >= 0.0 else -r))
            s, c, p = 1.0, 1.0, 0.0
            underflow = False
            i = m - 1
            while i >= ll:
                f = s * e[i]
                b = c * e[i]
                r = np.sqrt(f * f + g * g)
                e[i + 1] = r
                if r == 0.0:
                    d[i + 1] -= p
                    e[m] = 0.0
                    underflow = True
                    break
                s = f / r
                c = g / r
                g = d[i + 1] - p
                r = (d[i] - g) * s + 2.0 * c * b
                p = s * r
                d[i + 1] = g + p
                g = c * r - b
                for k in range(n):
                    f = z[k, i + 1]
                    z[k, i + 1] = s * z[k, i] + c * f
                    z[k, i] = c * z[k, i] - s * f
                i -= 1
            if underflow:
                continue
            d[ll] -= p
            e[ll] = g
            e[m] = 0.0
    return True


@njit(cache=True, inline='always')
def project3_into(D: np.ndarray, a: np.ndarray, w: np.ndarray, Q: np.ndarray) -> None:
    """D[:3, :3] (symmetric) <- its projection to positive semi-definite: its eigenvalues
    clamped at zero; ``a, Q (3, 3)``, ``w (3,)`` scratch. A block positive definite by its
    leading minors is its own projection (to round-off) and takes no eigen-decomposition,
    which most points of a formed sheet skip so."""
    m2 = D[0, 0] * D[1, 1] - D[0, 1] * D[1, 0]
    det = (D[0, 0] * (D[1, 1] * D[2, 2] - D[1, 2] * D[2, 1])
           - D[0, 1] * (D[1, 0] * D[2, 2] - D[1, 2] * D[2, 0])
           + D[0, 2] * (D[1, 0] * D[2, 1] - D[1, 1] * D[2, 0]))
    if D[0, 0] > 0.0 and m2 > 0.0 and det > 0.0:
        return
    eigh3_into(D[:3, :3], a, w, Q, True)
    e0, e1, e2 = max(w[0], 0.0), max(w[1], 0.0), max(w[2], 0.0)
    for i in range(3):
        for j in range(3):
            D[i, j] = Q[i, 0] * e0 * Q[j, 0] + Q[i, 1] * e1 * Q[j, 1] + Q[i, 2] * e2 * Q[j, 2]


@njit(cache=True, inline='always')
def project3(D: np.ndarray) -> None:
    """:func:`project3_into`, its scratch made here."""
    project3_into(D, np.empty((3, 3)), np.empty(3), np.empty((3, 3)))


@njit(cache=True)
def principal_stress_tangent_into(model: int, F: np.ndarray, params: np.ndarray,  # noqa: C901
                                  ep_n: float,
                                  want_tangent: bool, project: bool, P: np.ndarray,
                                  C: np.ndarray) -> float:
    """W, P and C through the principal stretches of F (any model)."""
    U, s, V, ok = polar_svd(F)
    if not ok:
        P[:] = 0.0
        return np.inf
    W, g, H, sym, twist = principal(model, s, params, ep_n)
    for i in range(3):
        for j in range(3):
            P[i, j] = U[i, 0] * g[0] * V[j, 0] + U[i, 1] * g[1] * V[j, 1] + U[i, 2] * g[2] * V[j, 2]
    if not want_tangent:
        return W
    if project:
        project3(H)
        sym = np.maximum(sym, 0.0)
        twist = np.maximum(twist, 0.0)
    # C = sum_ab H_ab d_a d_b^T + sum_k sym_k s_k s_k^T + twist_k t_k t_k^T with d_a = u_a v_a^T,
    # s_k, t_k = (u_i v_j^T +- u_j v_i^T)/sqrt2, written out to avoid temporaries
    M = np.empty((3, 3, 9))  # M[a, b] = vec(u_a v_b^T)
    for a in range(3):
        for b in range(3):
            for i in range(3):
                for j in range(3):
                    M[a, b, 3 * i + j] = U[i, a] * V[j, b]
    for r in range(9):
        for c in range(r, 9):
            acc = 0.0
            for a in range(3):
                for b in range(3):
                    acc += H[a, b] * M[a, a, r] * M[b, b, c]
            for k in range(3):
                i, j = PAIRS[k, 0], PAIRS[k, 1]
                sr = M[i, j, r] + M[j, i, r]
                sc = M[i, j, c] + M[j, i, c]
                tr = M[i, j, r] - M[j, i, r]
                tc = M[i, j, c] - M[j, i, c]
                acc += 0.5 * (sym[k] * sr * sc + twist[k] * tr * tc)
            C[r, c] = acc
            C[c, r] = acc
    return W

"""Hill's 1948 orthotropic yield criterion in the variational return mapping of
sim.materials.plasticity, on the full logarithmic strain tensor in the sheet's material frame.

Kinematics as for von Mises: F = Fe Fp, the trial elastic deformation G = F Fp_n^-1 and its
Hencky strain E = 1/2 ln(G^T G) (symmetric, in the intermediate configuration, where the
orthotropy axes stay fixed: zero plastic spin). ``frame (3, 3)`` holds the material axes as
columns (rolling, transverse, normal direction) in scene coordinates; E_m = frame^T E frame.

Tensors in the material frame are Mandel 6-vectors (11, 22, 33, sqrt2 23, sqrt2 13, sqrt2 12),
orthonormal: A : B = a . b. Hill's equivalent stress phi(T)^2 = T . Hm T with

    phi^2 = F (T22 - T33)^2 + G (T33 - T11)^2 + H (T11 - T22)^2 + 2 L T23^2 + 2 M T13^2
            + 2 N T12^2,

von Mises for F = G = H = 1/2, L = M = N = 3/2. Hm is positive semidefinite with the hydrostatic
direction as null space; its eigen-decomposition Hm = Q diag(h) Q^T (h[0] = 0 on the hydrostatic
unit vector) is computed once per material (:func:`hill_params`).

Incremental potential (isotropic Hencky elasticity, associated flow dEp = dg dphi/dT, isotropic
hardening Y(ep) of sim.materials.plasticity):
    W(E) = min_{dEp} psi_e(E - dEp) + Phi(|dEp|_*),   Phi(dg) = int_{ep_n}^{ep_n + dg} Y ds,
|.|_* the dual norm of phi, convex in E for a nondecreasing Y. In Hm's eigenbasis (a = Q^T E_m)
the return decouples: with c = 2 mu dg / Y and b_i = 1 + c h_i,
    T_i = 2 mu a_i / b_i (i >= 1),  T_0 = 3 kappa a_0,  kappa = lam + 2 mu / 3,
    W   = mu sum_i (a_i / b_i)^2 + 3 kappa / 2 a_0^2 + Phi(dg),
and dg >= 0 is the root of the consistency condition phi(T) = Y(ep_n + dg), written as
    R(dg) = 1 - sum_i h_i (2 mu a_i)^2 / (Y + 2 mu h_i dg)^2 = 0,
increasing in dg and concave for the nonsoftening, concave-or-linear laws of plasticity.py, so
Newton from dg = 0 converges monotonically. Tangent (symmetric, rank-one update):
    dT_i/da_j = 2 mu d_ij / b_i - beta w_i w_j,   w_i = h_i a_i / b_i^2,
    beta = 32 mu^4 (Y - dg H) / (Y^4 R'(dg)),  R' = 2 sum_i h_i (2 mu a_i)^2 (H + 2 mu h_i)
                                                     / (Y b_i)^3.
The plastic increment is dEp_i = a_i c h_i / b_i; the commit sets Fp^-1 <- Fp^-1 exp(-dEp)
(in scene coordinates). For von Mises dEp is coaxial with E and this is exactly the principal
return of plasticity.py; otherwise exp(-dEp) does not commute with G^T G and the next trial
strain differs from E - dEp by O(|Ee| |dEp|), the usual small-elastic-strain approximation of
the logarithmic-strain return (Eterovic and Bathe 1990; Miehe, Apel and Lambrecht 2002).

Chain to G: with C = G^T G = V diag(l) V^T (l = s^2), T' = V^T T V and the divided differences
f1_ab = f[l_a, l_b], f2_abc = f[l_a, l_b, l_c] of f = 1/2 ln (Daleckii-Krein),
    P = U P' V^T,  P'_ab = 2 s_a f1_ab T'_ab,
and the Hessian in the basis u_a v_b^T (dG = U A V^T) is the sum of
    D-term   g_ab g_cd D'[m(ab), m(cd)]    (g_ab = s_a f1_ab times 2 on the diagonal, sqrt2 off)
    C-term   2 d_ac T'_bd f1_bd            (the second derivative of C = G^T G)
    log-term 2 s_a s_c (d_bc T'_ad f2_abd + d_bd T'_ac f2_abc + d_ac T'_bd f2_abd
                        + d_ad T'_bc f2_abc)
with D' the material tangent rotated to V's frame.

``params`` of a Hill material: [mu, lam, law, hp (3, zero-padded), h (6), Q (36, row-major)];
the hardening functions read only hp's leading entries.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from sim.materials.isotropic import PAIRS, clamp_psd, dlog, eigh3, polar_svd
from sim.materials.plasticity import bracketed_step, hardening_work, yield_stress

HILL48 = 3  # model id beside sim.materials.isotropic's
N_PARAMS = 48
_R2 = math.sqrt(2.0)
# Mandel index of the tensor component (i, j)
MANDEL = np.array([[0, 5, 4], [5, 1, 3], [4, 3, 2]])
_PAIRS = np.array([[1, 2], [0, 2], [0, 1]])  # off-diagonal component of Mandel index 3, 4, 5
# the unique components of a symmetric tensor (the diagonal, then isotropic.PAIRS) as (a, b), and
# their Mandel indices: constant tables, not made at every point
_ENDS = np.array([[0, 0], [1, 1], [2, 2], *PAIRS.tolist()])
_M = np.array([MANDEL[a, b] for a, b in _ENDS])


def coefficients(r0: float, r45: float, r90: float) -> tuple[float, float, float, float]:
    """Hill's F, G, H, N from the r-values, normalised G + H = 1 (so the flow stress Y is the
    uniaxial yield stress along the rolling direction): r0 = H/G, r90 = H/F,
    r45 = N/(F + G) - 1/2."""
    G = 1.0 / (1.0 + r0)
    H = r0 * G
    F = H / r90
    N = (r45 + 0.5) * (F + G)
    return F, G, H, N


def r_values(F: float, G: float, H: float, N: float) -> tuple[float, float, float]:
    """The r-values at 0, 45 and 90 degrees of Hill's coefficients (inverse of coefficients)."""
    return H / G, N / (F + G) - 0.5, H / F


def hill_matrix(F: float, G: float, H: float, N: float, L: float = 1.5,
                M: float = 1.5) -> np.ndarray:
    """Hm (6, 6) in Mandel components: phi^2 = T . Hm T."""
    Hm = np.zeros((6, 6))
    Hm[:3, :3] = [[G + H, -H, -G], [-H, F + H, -F], [-G, -F, F + G]]
    Hm[3, 3], Hm[4, 4], Hm[5, 5] = L, M, N
    return Hm


def hill_params(mu: float, lam: float, law: int, hp: list[float], Hm: np.ndarray) -> np.ndarray:
    """The kernel's parameter array (module docstring). The hydrostatic eigenvector is set
    exactly, so that h[0] = 0 and pressure never flows; the deviatoric normal block's two
    eigenvectors come from its 2x2 restriction to an orthonormal deviatoric basis."""
    one = np.array([1.0, 1.0, 1.0]) / math.sqrt(3.0)
    dev = np.array([[1.0, -1.0, 0.0], [1.0, 1.0, -2.0]])
    dev /= np.linalg.norm(dev, axis=1)[:, None]
    h2, q2 = np.linalg.eigh(dev @ Hm[:3, :3] @ dev.T)
    Q = np.zeros((6, 6))
    Q[:3, 0] = one
    Q[:3, 1:3] = dev.T @ q2
    Q[3:, 3:] = np.eye(3)
    h = np.array([0.0, h2[0], h2[1], Hm[3, 3], Hm[4, 4], Hm[5, 5]])
    if not np.all(h[1:] > 0.0):
        raise ValueError("Hill's criterion is not positive definite on the deviatoric stresses")
    return np.concatenate([[mu, lam, float(law)], np.pad(hp, (0, 3 - len(hp))), h, Q.ravel()])


def sheet_frames(normals: np.ndarray, rolling: np.ndarray) -> np.ndarray:
    """Material frames ``(n, 3, 3)``, columns (rolling, transverse, normal), from unit mid-surface
    normals ``(n, 3)`` and the rolling direction ``(3,)`` projected on each tangent plane.
    Raises where the rolling direction is within 1 degree of the normal (no projection)."""
    d = rolling / np.linalg.norm(rolling)
    t = d - (normals @ d)[:, None] * normals
    size = np.linalg.norm(t, axis=1)
    bad = np.nonzero(size < math.sin(math.radians(1.0)))[0]
    if len(bad):
        raise ValueError(f"parallel to the sheet normal at {len(bad)} element(s) (first: "
                         f"{bad[:5].tolist()}): it has no direction in the sheet's plane there")
    t /= size[:, None]
    return np.stack([t, np.cross(normals, t), normals], axis=2)


@njit(cache=True, inline='always')
def _mm(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """A @ B by loops: numba hands every small @ to BLAS, whose call costs more than these
    3x3 to 9x9 products."""
    n, m, k = A.shape[0], B.shape[1], A.shape[1]
    out = np.zeros((n, m))
    for i in range(n):
        for p in range(k):
            a = A[i, p]
            for j in range(m):
                out[i, j] += a * B[p, j]
    return out


@njit(cache=True)
def _solve(a: np.ndarray, h: np.ndarray, ep_n: float, mu: float, law: int,
           hp: np.ndarray) -> float:
    """Root dg of R (module docstring) in [0, phi_tr / (2 mu h_min)]: Newton inside a shrinking
    bracket, bisection when a step leaves it; converged at a step below 1e-14 of the bracket."""
    phi2, hmin = 0.0, np.inf
    for i in range(1, 6):
        phi2 += h[i] * (2.0 * mu * a[i]) ** 2
        hmin = min(hmin, h[i])
    scale = math.sqrt(phi2) / (2.0 * mu * hmin)
    lo, hi, x = 0.0, scale, 0.0
    for _ in range(200):
        y, dy = yield_stress(law, hp, ep_n + x)
        res, der = 1.0, 0.0
        for i in range(1, 6):
            t2 = h[i] * (2.0 * mu * a[i]) ** 2
            den = y + 2.0 * mu * h[i] * x
            res -= t2 / (den * den)
            der += 2.0 * t2 * (dy + 2.0 * mu * h[i]) / (den * den * den)
        if res == 0.0:
            return x
        x, lo, hi, done = bracketed_step(x, -res / der, res < 0.0, lo, hi, scale)
        if done:
            return x
    return x


@njit(cache=True, inline='always')
def _eigen_strain(e6: np.ndarray, params: np.ndarray, a: np.ndarray) -> None:
    """a = Q^T e6 (6,): the trial strain in Hm's eigenbasis, Q read from ``params`` in place."""
    for i in range(6):
        acc = 0.0
        for k in range(6):
            acc += params[12 + 6 * k + i] * e6[k]
        a[i] = acc


@njit(cache=True, inline='always')
def _return_dg(a: np.ndarray, ep_n: float, params: np.ndarray) -> float:
    """The return's dg at ``a`` (:func:`_eigen_strain`): 0 in the elastic branch."""
    mu, law = params[0], int(params[2])
    hp, h = params[3:6], params[6:12]
    phi2 = 0.0
    for i in range(1, 6):
        phi2 += h[i] * (2.0 * mu * a[i]) ** 2
    y_n, _ = yield_stress(law, hp, ep_n)
    if math.sqrt(phi2) - y_n > 1e-12 * abs(y_n):
        return _solve(a, h, ep_n, mu, law, hp)
    return 0.0


@njit(cache=True, inline='always')
def _potential(a: np.ndarray, ep_n: float, dg: float, params: np.ndarray) -> float:
    """W (module docstring) at ``a`` after the return ``dg``."""
    mu, lam, law = params[0], params[1], int(params[2])
    hp, h = params[3:6], params[6:12]
    kappa = lam + 2.0 * mu / 3.0
    y, _ = yield_stress(law, hp, ep_n + dg)
    c = 2.0 * mu * dg / y
    W = 1.5 * kappa * a[0] * a[0]
    for i in range(1, 6):
        W += mu * (a[i] / (1.0 + c * h[i])) ** 2
    if dg > 0.0:
        W += hardening_work(law, hp, ep_n, ep_n + dg)
    return W


@njit(cache=True)
def hill_return(e6: np.ndarray, ep_n: float, params: np.ndarray
                ) -> tuple[float, np.ndarray, np.ndarray, float, np.ndarray]:
    """Incremental potential at one point: trial log strain ``e6 (6,)`` (material frame,
    Mandel), ``ep_n`` the committed equivalent plastic strain. Returns (W, T (6,),
    D = dT/de (6, 6), dg, dEp (6,)), all in the material frame. D is formed as
    Q (diag - beta w w^T) Q^T by loops, symmetric by construction: this runs at every point of
    a Hill sheet, where small temporaries cost more than the arithmetic."""
    mu, lam, law = params[0], params[1], int(params[2])
    hp, h = params[3:6], params[6:12]
    kappa = lam + 2.0 * mu / 3.0
    work = np.zeros((4, 6))
    a, Ta, dEa, w = work[0], work[1], work[2], work[3]
    _eigen_strain(e6, params, a)
    dg = _return_dg(a, ep_n, params)
    W = _potential(a, ep_n, dg, params)
    y, dy = yield_stress(law, hp, ep_n + dg)
    c = 2.0 * mu * dg / y
    Ta[0] = 3.0 * kappa * a[0]
    diag = np.empty(6)
    diag[0] = 3.0 * kappa
    beta, der = 0.0, 0.0
    for i in range(1, 6):
        b = 1.0 + c * h[i]
        Ta[i] = 2.0 * mu * a[i] / b
        dEa[i] = a[i] * c * h[i] / b
        diag[i] = 2.0 * mu / b
        if dg > 0.0:
            der += 2.0 * h[i] * (2.0 * mu * a[i]) ** 2 * (dy + 2.0 * mu * h[i]) / (y * b) ** 3
            w[i] = h[i] * a[i] / (b * b)
    if dg > 0.0:
        beta = 32.0 * mu**4 * (y - dg * dy) / (y**4 * der)
    T, dE, D = np.zeros(6), np.zeros(6), np.empty((6, 6))
    Qw = np.zeros(6)
    for i in range(6):
        for k in range(6):
            q = params[12 + 6 * i + k]
            T[i] += q * Ta[k]
            dE[i] += q * dEa[k]
            Qw[i] += q * w[k]
    for i in range(6):
        for j in range(i, 6):
            acc = 0.0
            for k in range(6):
                acc += params[12 + 6 * i + k] * diag[k] * params[12 + 6 * j + k]
            D[i, j] = D[j, i] = acc - beta * Qw[i] * Qw[j]
    return W, T, D, dg, dE


@njit(cache=True)
def mandel_rotation(R: np.ndarray) -> np.ndarray:
    """``Mr (6, 6)``: the Mandel vector of R X R^T is Mr @ (that of X), for a rotation R (3, 3)."""
    Mr = np.empty((6, 6))
    for k in range(6):  # column k: R B_k R^T of the Mandel basis tensor B_k
        for m in range(6):
            if m < 3:
                p, q = m, m
            else:
                p, q = _PAIRS[m - 3, 0], _PAIRS[m - 3, 1]
            if k < 3:
                y = R[p, k] * R[q, k]
            else:
                i, j = _PAIRS[k - 3, 0], _PAIRS[k - 3, 1]
                y = (R[p, i] * R[q, j] + R[p, j] * R[q, i]) / _R2
            Mr[m, k] = y if m < 3 else _R2 * y
    return Mr


@njit(cache=True)
def unmandel(v: np.ndarray) -> np.ndarray:
    """The symmetric tensor (3, 3) of a Mandel vector (6,)."""
    A = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            k = MANDEL[i, j]
            A[i, j] = v[k] if i == j else v[k] / _R2
    return A


# the second divided difference of 1/2 ln by its Taylor series up to this spread (of the mean),
# by the recursion over the widest pair beyond it: the series' twenty terms are exact to a few
# ulps up to 0.3 (|y| <= 0.2: truncation 0.2^21), while the recursion divides two differences
# of logarithms (dlog) by the spread and loses 1e-11 of its value at 1e-2, 1e-13 from 0.3 on
SERIES_SPREAD, SERIES_TERMS = 0.3, 20


@njit(cache=True)
def _half_log_dd2(x0: float, x1: float, x2: float) -> float:
    """Second divided difference of f = 1/2 ln at the three positive numbers x0, x1, x2:
    within ``SERIES_SPREAD`` of the mean the Taylor series about it,
    sum_k f^(k+2)(m) / (k+2)! h_k(y) with y = (x - m) / m and h_k the complete homogeneous
    polynomials, those by h_k(y0, y1, y2) = h_k(y1, y2) + y0 h_{k-1}(y0, y1, y2) and
    h_k(y1, y2) = y2^k + y1 h_{k-1}(y1, y2) (scalars only: this runs ten times at every point
    of a Hill sheet); wider, the recursion over the widest pair."""
    lo, hi = min(x0, min(x1, x2)), max(x0, max(x1, x2))
    mid = x0 + x1 + x2 - lo - hi
    m = (x0 + x1 + x2) / 3.0
    if hi - lo > SERIES_SPREAD * m:
        return 0.5 * (dlog(hi, mid) - dlog(mid, lo)) / (hi - lo)
    y0, y1, y2 = (x0 - m) / m, (x1 - m) / m, (x2 - m) / m
    h2, h12, h012 = 1.0, 1.0, 1.0  # h_k(y2), h_k(y1, y2), h_k(y0, y1, y2) at k = 0
    total, sign = -0.25, 0.5
    for k in range(1, SERIES_TERMS + 1):
        h2 *= y2
        h12 = h2 + y1 * h12
        h012 = h12 + y0 * h012
        total += sign / (k + 2) * h012
        sign = -sign
    return total / (m * m)


@njit(cache=True, inline='always')
def _strain6_into(V: np.ndarray, e: np.ndarray, frame: np.ndarray, Vm: np.ndarray,
                  e6: np.ndarray) -> None:
    """``Vm (3, 3)`` = frame^T V and ``e6 (6,)``, the Mandel vector in the material frame of
    the log strain V diag(e) V^T."""
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for p in range(3):
                acc += frame[p, i] * V[p, j]
            Vm[i, j] = acc
    for m in range(6):
        i, j = (m, m) if m < 3 else (_PAIRS[m - 3, 0], _PAIRS[m - 3, 1])
        acc = 0.0
        for p in range(3):
            acc += Vm[i, p] * e[p] * Vm[j, p]
        e6[m] = acc if m < 3 else _R2 * acc


@njit(cache=True)
def hill_strain6(V: np.ndarray, e: np.ndarray,
                 frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(Vm = frame^T V, the Mandel vector (6,) in the material frame) of the log strain
    V diag(e) V^T."""
    Vm, e6 = np.empty((3, 3)), np.empty(6)
    _strain6_into(V, e, frame, Vm, e6)
    return Vm, e6


@njit(cache=True)
def _frame_strain(G: np.ndarray, frame: np.ndarray
                  ) -> tuple[bool, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(ok, U, s, V, Vm = frame^T V, e6 the Mandel trial log strain in the material frame)."""
    U, s, V, ok = polar_svd(G)
    if not ok:
        return False, U, s, V, _mm(frame.T, V), np.zeros(6)
    Vm, e6 = hill_strain6(V, np.log(s), frame)
    return True, U, s, V, Vm, e6


@njit(cache=True)
def hill_stress_tangent(G: np.ndarray, params: np.ndarray, frame: np.ndarray, ep_n: float,
                        want_tangent: bool, project: bool, P: np.ndarray,
                        C: np.ndarray) -> float:
    """W, first Piola-Kirchhoff ``P (3, 3)`` and ``C = dP/dG (9, 9)`` (row-major vec, written
    when ``want_tangent``; clamped to positive semidefinite when ``project``) at the trial
    elastic deformation ``G (3, 3)``; W = inf when det G <= 0."""
    ok, U, s, V, Vm, e6 = _frame_strain(G, frame)
    if not ok:
        P[:] = 0.0
        return np.inf
    W, T6, D6, _, _ = hill_return(e6, ep_n, params)
    Tp = _mm(_mm(Vm.T, unmandel(T6)), Vm)  # T in V's frame
    lam = s * s
    f1 = np.empty((3, 3))
    for a in range(3):
        for b in range(3):
            f1[a, b] = 0.5 * dlog(lam[a], lam[b])
    Pp = np.empty((3, 3))
    for a in range(3):
        for b in range(3):
            Pp[a, b] = 2.0 * s[a] * f1[a, b] * Tp[a, b]
    P[:, :] = _mm(_mm(U, Pp), V.T)
    if not want_tangent:
        return W
    K = _hessian_uv(s, lam, f1, Tp, D6, Vm)
    if project:
        clamp_psd(K)
    M = np.empty((9, 9))  # M[3a + b, 3i + j] = U[i, a] V[j, b]
    for a in range(3):
        for b in range(3):
            for i in range(3):
                for j in range(3):
                    M[3 * a + b, 3 * i + j] = U[i, a] * V[j, b]
    C[:, :] = _mm(_mm(M.T, K), M)
    for r in range(9):  # exactly symmetric, as the isotropic tangent is
        for c in range(r + 1, 9):
            C[r, c] = C[c, r] = 0.5 * (C[r, c] + C[c, r])
    return W


@njit(cache=True)
def hill_stress_tangent_h(H: np.ndarray, params: np.ndarray, frame: np.ndarray, ep_n: float,
                          want_tangent: bool, project: bool, P: np.ndarray,
                          C: np.ndarray) -> float:
    """:func:`hill_stress_tangent` at G = I + H, from ``H (3, 3)`` (the element kernel's form)."""
    G = H.copy()
    for i in range(3):
        G[i, i] += 1.0
    return hill_stress_tangent(G, params, frame, ep_n, want_tangent, project, P, C)


@njit(cache=True)
def _hessian_uv(s: np.ndarray, lam: np.ndarray, f1: np.ndarray, Tp: np.ndarray,
                D6: np.ndarray, Vm: np.ndarray) -> np.ndarray:
    """d2W/dA2 ``(9, 9)`` for dG = U A V^T, A's entries row-major (module docstring)."""
    Mr = mandel_rotation(Vm)  # V-frame Mandel -> material-frame Mandel
    Dv = _mm(_mm(Mr.T, D6), Mr)
    f2 = _half_log_dd2_table(lam)
    g = np.empty((3, 3))
    for a in range(3):
        for b in range(3):
            g[a, b] = s[a] * f1[a, b] * (2.0 if a == b else _R2)
    K = np.zeros((9, 9))
    for a in range(3):
        for b in range(3):
            r = 3 * a + b
            for c in range(3):
                for d in range(3):
                    v = g[a, b] * g[c, d] * Dv[MANDEL[a, b], MANDEL[c, d]]
                    t = 0.0
                    if b == c:
                        t += Tp[a, d] * f2[a, b, d]
                    if b == d:
                        t += Tp[a, c] * f2[a, b, c]
                    if a == c:
                        t += Tp[b, d] * f2[a, b, d]
                        v += 2.0 * Tp[b, d] * f1[b, d]
                    if a == d:
                        t += Tp[b, c] * f2[a, b, c]
                    K[r, 3 * c + d] = v + 2.0 * s[a] * s[c] * t
    return 0.5 * (K + K.T)


@njit(cache=True)
def _half_log_dd2_table(lam: np.ndarray) -> np.ndarray:
    """f2[i, j, k] = the second divided difference of f = 1/2 ln at lam[i], lam[j], lam[k]."""
    f2 = np.empty((3, 3, 3))
    for i in range(3):  # symmetric in its arguments: ten distinct values
        for j in range(i, 3):
            for k in range(j, 3):
                v = _half_log_dd2(lam[i], lam[j], lam[k])
                f2[i, j, k] = f2[i, k, j] = f2[j, i, k] = v
                f2[j, k, i] = f2[k, i, j] = f2[k, j, i] = v
    return f2


@njit(cache=True)
def hill_green(lam: np.ndarray, V: np.ndarray, params: np.ndarray, frame: np.ndarray,
               ep_n: float, want: int, Sp: np.ndarray, Dp: np.ndarray) -> float:
    """Hill48 as a function of C^ = V diag(lam) V^T = I + 2 E^, the form of the assumed-strain
    kernel (sim.terms.ans), which has the Green-Lagrange strain, not G: W; for want >= 1 the
    stress ``Sp (3, 3)`` = V^T (dW/dE^) V; for want == 2 ``Dp (6, 6)``, d2W = x^T Dp x over the
    unique components x of X = V^T dE^ V (the diagonal, then the pairs of
    sim.materials.isotropic.PAIRS).

    With L = 1/2 ln C^ (in V's frame dL = f1 o dC^, f1 the divided differences of 1/2 ln at
    lam; d2L[dC^, dC^]_ab = 2 sum_c f2_acb dC^_ac dC^_cb, Daleckii-Krein) and dC^ = 2 dE^:
        S' = 2 f1 o T',   d2W = (2 f1 o X) : D' : (2 f1 o X) + 8 sum_abc T'_ab f2_abc X_ac X_cb,
    T' and D' Hill's stress and tangent (:func:`hill_return`) in V's frame."""
    if want == 0:
        return hill_energy(0.5 * np.log(lam), V, params, frame, ep_n, np.empty((3, 3)),
                           np.empty((2, 6)))
    Vm, e6 = hill_strain6(V, 0.5 * np.log(lam), frame)
    W, T6, D6, _, _ = hill_return(e6, ep_n, params)
    Tp = _mm(_mm(Vm.T, unmandel(T6)), Vm)
    f1 = np.empty((3, 3))
    for a in range(3):
        for b in range(3):
            f1[a, b] = 0.5 * dlog(lam[a], lam[b])
            Sp[a, b] = 2.0 * f1[a, b] * Tp[a, b]
    if want < 2:
        return W
    Mr = mandel_rotation(Vm)
    Dv = _mm(_mm(Mr.T, D6), Mr)
    f2 = _half_log_dd2_table(lam)
    # x's unit directions B_p = e_a e_b^T + e_b e_a^T (_ENDS[p] = (a, b)); dL along B_p is
    # the single Mandel component _M[p] = MANDEL[a, b], of size size[p]
    size = np.empty(6)
    for p in range(6):
        a, b = _ENDS[p, 0], _ENDS[p, 1]
        size[p] = 2.0 * f1[a, b] * (1.0 if a == b else _R2)
    for p in range(6):
        for q in range(p, 6):
            t = _log_term(_ENDS[p], _ENDS[q], Tp, f2) + _log_term(_ENDS[q], _ENDS[p], Tp, f2)
            Dp[p, q] = Dp[q, p] = size[p] * size[q] * Dv[_M[p], _M[q]] + 4.0 * t
    return W


@njit(cache=True, inline='always')
def hill_energy(e: np.ndarray, V: np.ndarray, params: np.ndarray, frame: np.ndarray,
                ep_n: float, Vm: np.ndarray, w6: np.ndarray) -> float:
    """W alone at the log strain V diag(``e``) V^T, with no temporary array: a line search
    evaluates it at every point of a Hill sheet, where the stress's and the tangent's
    allocations and arithmetic cost more than the return. The same bits as the W of
    :func:`hill_green` and :func:`hill_stress_tangent` given the e they form. Scratch: Vm
    (3, 3), w6 (2, 6)."""
    e6, a = w6[0], w6[1]
    _strain6_into(V, e, frame, Vm, e6)
    _eigen_strain(e6, params, a)
    return _potential(a, ep_n, _return_dg(a, ep_n, params), params)


@njit(cache=True)
def hill_energy_h(H: np.ndarray, params: np.ndarray, frame: np.ndarray, ep_n: float) -> float:
    """:func:`hill_energy` at G = I + H (``H (3, 3)``, the element kernel's form), the W of
    :func:`hill_stress_tangent_h` to the bit; inf when det G <= 0."""
    G = H.copy()
    for i in range(3):
        G[i, i] += 1.0
    _, s, V, ok = polar_svd(G)
    if not ok:
        return np.inf
    return hill_energy(np.log(s), V, params, frame, ep_n, np.empty((3, 3)), np.empty((2, 6)))


@njit(cache=True, inline='always')
def _log_term(ep: np.ndarray, eq: np.ndarray, Tp: np.ndarray, f2: np.ndarray) -> float:
    """sum_abc T'_ab f2_abc (B_p)_ac (B_q)_cb over the non-zero entries of the unit
    directions B_p, B_q (ends ``ep``, ``eq``: (a, b) of e_a e_b^T + e_b e_a^T, one entry where
    a == b)."""
    t = 0.0
    for i in range(1 if ep[0] == ep[1] else 2):
        a, c = (ep[0], ep[1]) if i == 0 else (ep[1], ep[0])
        for j in range(1 if eq[0] == eq[1] else 2):
            c2, b = (eq[0], eq[1]) if j == 0 else (eq[1], eq[0])
            if c == c2:
                t += Tp[a, b] * f2[a, b, c]
    return t


@njit(cache=True)
def hill_flow(G: np.ndarray, params: np.ndarray, frame: np.ndarray,
              ep_n: float) -> tuple[np.ndarray, float]:
    """The commit's return: exp(-dEp) (3, 3) in scene coordinates, and dg (identity and 0 in the
    elastic branch)."""
    ok, _, _, _, _, e6 = _frame_strain(G, frame)
    if not ok:
        return np.eye(3), 0.0
    return hill_flow_strain(e6, params, frame, ep_n)


@njit(cache=True)
def hill_flow_strain(e6: np.ndarray, params: np.ndarray, frame: np.ndarray,
                     ep_n: float) -> tuple[np.ndarray, float]:
    """:func:`hill_flow` from the trial log strain ``e6`` (Mandel, material frame)."""
    _, _, _, dg, dE6 = hill_return(e6, ep_n, params)
    if dg == 0.0:
        return np.eye(3), 0.0
    dE = frame @ unmandel(dE6) @ np.ascontiguousarray(frame.T)
    w, Qe = eigh3(dE)
    w -= (w[0] + w[1] + w[2]) / 3.0  # isochoric to round-off
    return (Qe * np.exp(-w)) @ np.ascontiguousarray(Qe.T), dg


@njit(cache=True)
def hill_kirchhoff(G: np.ndarray, params: np.ndarray, frame: np.ndarray,
                   ep_n: float) -> np.ndarray:
    """Kirchhoff stress tau = P G^T (3, 3) at the trial state (zero if det G <= 0)."""
    P = np.zeros((3, 3))
    W = hill_stress_tangent(G, params, frame, ep_n, False, False, P, np.empty((9, 9)))
    if not np.isfinite(W):
        return np.zeros((3, 3))
    return P @ np.ascontiguousarray(G.T)

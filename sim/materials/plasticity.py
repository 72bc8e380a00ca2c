"""Principal-space return mapping of finite-strain von Mises plasticity as an incremental potential.

Variational form after Li, Li & Jiang (2022), "Energetically consistent inelasticity for
optimization time integration". At a quadrature point the caller forms the trial elastic
deformation Fe_tr = F Fp_n^-1 = U diag(sigma) V^T and passes the principal trial Hencky strains
eps_tr = ln(sigma), shape (3,). Everything below lives in that principal frame (SI units).

Notation: 1 = (1, 1, 1), P = I - 1 1^T / 3, e_tr = P eps_tr, r = |e_tr|, n = e_tr / r,
N = sqrt(3/2) n (so |N| = sqrt(3/2)), kappa = lam + 2 mu / 3, H = dY/dep.

Hencky energy and Kirchhoff stress (principal):
    psi_e(eps) = mu |P eps|^2 + kappa/2 (tr eps)^2 = mu eps:eps + lam/2 (tr eps)^2
    tau = d psi_e / d eps = 2 mu P eps + kappa tr(eps) 1
Yield: f = sqrt(3/2) |dev tau| - Y(ep); trial equivalent stress q_tr = sqrt(6) mu r.

Incremental potential:
    W(eps_tr; ep_n) = min_{dg >= 0} psi_e(eps_tr - dg N) + Phi(dg),
    Phi(dg) = int_{ep_n}^{ep_n + dg} Y(s) ds
N is parallel to e_tr, hence psi_e(eps_tr - dg N) = mu (r - sqrt(3/2) dg)^2 + kappa/2 (tr eps_tr)^2
and stationarity in dg is the scalar consistency equation
    R(dg) = q_tr - 3 mu dg - Y(ep_n + dg) = 0,   R' = -(3 mu + H) < 0 for H > -3 mu,
whose root is the unique minimiser (the objective is convex in dg when Y is nondecreasing).

Elastic branch (f_tr = q_tr - Y(ep_n) <= 1e-12 Y(ep_n), or r = 0): dg = 0 and
    W = psi_e(eps_tr),  tau = tau_tr,  D = lam 1 1^T + 2 mu I,  a_dd = 2 mu.
Plastic branch, with s = 1 - 3 mu dg / q_tr = Y / q_tr in (0, 1] (evaluated as Y / q_tr, free of
cancellation at large strain) and H = Y'(ep_n + dg):
    W    = mu s^2 r^2 + kappa/2 (tr eps_tr)^2 + Phi(dg)
    tau  = kappa tr(eps_tr) 1 + 2 mu s e_tr          (= tau_tr - 2 mu dg N; envelope theorem)
    D    = kappa 1 1^T + 2 mu s (P - n n^T) + 2 mu H / (3 mu + H) n n^T
    a_dd = 2 mu s
D follows from dr = n.deps, dn = (P - n n^T) deps / r, d(dg) = sqrt(6) mu / (3 mu + H) n.deps.
Since tau_i - tau_j = 2 mu s (eps_tr_i - eps_tr_j), a_dd is the common divided difference
(tau_i - tau_j) / (eps_tr_i - eps_tr_j) the caller needs when principal stretches coincide.
D is symmetric, positive semidefinite for H >= 0 (definite for H > 0 and kappa > 0), so W is
convex in eps_tr for the nonsoftening laws below.

Plastic update after a converged step: deps_p = dg N (traceless), ep_{n+1} = ep_n + dg,
Fp_{n+1} = V diag(exp(deps_p)) V^T Fp_n, which gives Fe_{n+1} = U diag(exp(eps_tr - deps_p)) V^T.

Hardening laws: integer `law`, float64 parameter array `hp`:
    0 perfect  Y = Y0                                   hp = [Y0]
    1 linear   Y = Y0 + H ep                            hp = [Y0, H]
    2 Swift    Y = K (e0 + ep)^n                        hp = [K, e0, n]   (e0 > 0, 0 <= n)
    3 Voce     Y = Y0 + (Ysat - Y0)(1 - exp(-C ep))     hp = [Y0, Ysat, C]
Requirements: Y > 0 and H > -3 mu along the path for the return to be unique, H >= 0 for W to be
convex; sim.scene.sheet.Hardening admits only nonsoftening parameters (K, e0 > 0, n >= 0,
Ysat >= Y0, C > 0, H >= 0), and derives Swift's e0 = (Y0 / K)^(1/n) from the yield stress.
"""

from __future__ import annotations

import math

import numba
import numpy as np

PERFECT, LINEAR, SWIFT, VOCE = 0, 1, 2, 3
# the scene's hardening law by name
LAWS = {"perfect": PERFECT, "linear": LINEAR, "swift": SWIFT, "voce": VOCE}

_SQRT6 = math.sqrt(6.0)
_SQRT3_2 = math.sqrt(1.5)


@numba.njit(cache=True)
def yield_stress(law: int, hp: np.ndarray, ep: float) -> tuple[float, float]:
    """Flow stress and its slope at equivalent plastic strain ep: returns (Y, dY/dep)."""
    if law == PERFECT:
        return hp[0], 0.0
    if law == LINEAR:
        return hp[0] + hp[1] * ep, hp[1]
    if law == SWIFT:
        y = hp[0] * (hp[1] + ep) ** hp[2]
        return y, hp[2] * y / (hp[1] + ep)
    if law == VOCE:
        d = (hp[1] - hp[0]) * math.exp(-hp[2] * ep)
        return hp[1] - d, hp[2] * d
    raise ValueError("unknown hardening law")


@numba.njit(cache=True)
def hardening_work(law: int, hp: np.ndarray, ep_a: float, ep_b: float) -> float:
    """Closed-form integral of Y(s) ds from ep_a to ep_b (cancellation-free for ep_b ~ ep_a)."""
    d = ep_b - ep_a
    if law == PERFECT:
        return hp[0] * d
    if law == LINEAR:
        return d * (hp[0] + 0.5 * hp[1] * (ep_a + ep_b))
    if law == SWIFT:
        base, m = hp[1] + ep_a, hp[2] + 1.0
        return hp[0] * base**m / m * math.expm1(m * math.log1p(d / base))
    if law == VOCE:
        if hp[2] == 0.0:
            return hp[0] * d
        decay = math.exp(-hp[2] * ep_a) * math.expm1(-hp[2] * d)
        return hp[1] * d + (hp[1] - hp[0]) / hp[2] * decay
    raise ValueError("unknown hardening law")


@numba.njit(cache=True, inline='always')
def _trial3(e0: float, e1: float, e2: float) -> tuple[float, float, float, float, float]:
    """Trace, deviator and deviator norm of the trial strain (e0, e1, e2): scalars, so that
    a quadrature point's return map allocates nothing."""
    tr = e0 + e1 + e2
    d0, d1, d2 = e0 - tr / 3.0, e1 - tr / 3.0, e2 - tr / 3.0
    return tr, d0, d1, d2, math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)


@numba.njit(cache=True)
def _trial(eps_tr: np.ndarray) -> tuple[float, np.ndarray, float]:
    """Trace, deviator (3,) and deviator norm of the trial strain."""
    tr, d0, d1, d2, r = _trial3(eps_tr[0], eps_tr[1], eps_tr[2])
    return tr, np.array([d0, d1, d2]), r


@numba.njit(cache=True)
def _solve_dgamma(q_tr: float, ep_n: float, mu: float, law: int, hp: np.ndarray) -> float:
    """Root of q_tr - 3 mu dg - Y(ep_n + dg) = 0 on [0, q_tr / (3 mu)] (R(0) > 0 >= R(hi)).

    Newton kept inside a shrinking bracket, bisection when a step leaves it. Converged when the
    Newton step is below 1e-14 of the bracket scale q_tr / (3 mu), i.e. a stress error ~1e-14 q_tr
    before the last step, round-off after it.
    """
    scale = q_tr / (3.0 * mu)
    lo, hi, x = 0.0, scale, 0.0
    for _ in range(200):
        y, h = yield_stress(law, hp, ep_n + x)
        res = q_tr - 3.0 * mu * x - y
        if res == 0.0:
            return x
        x, lo, hi, done = bracketed_step(x, res / (3.0 * mu + h), res > 0.0, lo, hi, scale)
        if done:
            return x
    return x


@numba.njit(cache=True, inline='always')
def bracketed_step(x: float, step: float, root_above: bool, lo: float, hi: float,
                   scale: float) -> tuple[float, float, float, bool]:
    """One step of a scalar root's Newton iteration kept inside a shrinking bracket: x
    becomes the bracket's lower end when the root lies above it (``root_above``), else its
    upper end; the Newton ``step`` from x, or the bracket's middle when the step leaves it.
    Done (the returned x the root) when the step is below 1e-14 of ``scale``, the bracket's
    first width, or the bracket below 1e-16 of it."""
    if root_above:
        lo = x
    else:
        hi = x
    if abs(step) <= 1e-14 * scale:
        return x + step, lo, hi, True
    xn = x + step
    if not (lo < xn < hi):
        xn = 0.5 * (lo + hi)
    return xn, lo, hi, hi - lo <= 1e-16 * scale


@numba.njit(cache=True, inline='always')
def _dgamma_r(r: float, ep_n: float, mu: float, law: int, hp: np.ndarray) -> float:
    """Plastic multiplier dg >= 0 for a trial deviator of norm r (0 in the elastic branch)."""
    q_tr = _SQRT6 * mu * r
    y_n, _ = yield_stress(law, hp, ep_n)
    if r == 0.0 or q_tr - y_n <= 1e-12 * abs(y_n):
        return 0.0
    return _solve_dgamma(q_tr, ep_n, mu, law, hp)


@numba.njit(cache=True)
def _dgamma(eps_tr: np.ndarray, ep_n: float, mu: float, law: int, hp: np.ndarray) -> float:
    """Plastic multiplier dg >= 0 for trial strain eps_tr (0 in the elastic branch)."""
    _, _, _, _, r = _trial3(eps_tr[0], eps_tr[1], eps_tr[2])
    return _dgamma_r(r, ep_n, mu, law, hp)


@numba.njit(cache=True, inline='always')
def _branch(r: float, ep_n: float, mu: float, law: int,
            hp: np.ndarray) -> tuple[float, float, float, float]:
    """(dg, s, c, work) of the return at a trial deviator of norm r: s the deviatoric scaling
    of tau, c the extra n n^T coefficient of D, work the hardening's (module docstring)."""
    dg = _dgamma_r(r, ep_n, mu, law, hp)
    if not dg > 0.0:
        return dg, 1.0, 0.0, 0.0
    y, h = yield_stress(law, hp, ep_n + dg)
    s = y / (_SQRT6 * mu * r)  # = 1 - 3 mu dg / q_tr at the root, free of cancellation
    return dg, s, 2.0 * mu * (h / (3.0 * mu + h) - s), hardening_work(law, hp, ep_n, ep_n + dg)


@numba.njit(cache=True)
def incremental_energy(e0: float, e1: float, e2: float, ep_n: float, mu: float, lam: float,
                       law: int, hp: np.ndarray) -> float:
    """W of :func:`return_map` alone, at the principal trial log strains (e0, e1, e2): what a
    line search needs, without the stress, the tangent or an array."""
    kappa = lam + 2.0 * mu / 3.0
    tr, _, _, _, r = _trial3(e0, e1, e2)
    _, s, _, work = _branch(r, ep_n, mu, law, hp)
    return mu * (s * r) ** 2 + 0.5 * kappa * tr * tr + work


@numba.njit(cache=True)
def return_map_into(eps_tr: np.ndarray, ep_n: float, mu: float, lam: float, law: int,
                    hp: np.ndarray, tau: np.ndarray, D: np.ndarray) -> tuple[float, float, float]:
    """:func:`return_map` into ``tau (3,)`` and ``D (3, 3)``: returns (W, a_dd, dgamma)."""
    kappa = lam + 2.0 * mu / 3.0
    tr, d0, d1, d2, r = _trial3(eps_tr[0], eps_tr[1], eps_tr[2])
    dg, s, c, work = _branch(r, ep_n, mu, law, hp)
    a = 2.0 * mu * s
    W = mu * (s * r) ** 2 + 0.5 * kappa * tr * tr + work
    tau[0], tau[1], tau[2] = a * d0 + kappa * tr, a * d1 + kappa * tr, a * d2 + kappa * tr
    for i in range(3):
        di = d0 if i == 0 else (d1 if i == 1 else d2)
        for j in range(3):
            dj = d0 if j == 0 else (d1 if j == 1 else d2)
            D[i, j] = kappa - a / 3.0 + (a if i == j else 0.0)
            if c != 0.0:
                D[i, j] += c * (di * dj) / (r * r)  # exactly symmetric
    return W, a, dg


@numba.njit(cache=True)
def return_map(eps_tr: np.ndarray, ep_n: float, mu: float, lam: float, law: int,
               hp: np.ndarray) -> tuple[float, np.ndarray, np.ndarray, float, float]:
    """Incremental potential at one quadrature point.

    eps_tr (3,) principal trial log strains, ep_n equivalent plastic strain at step start.
    Returns (W, tau (3,), D (3, 3) = dtau/deps_tr, a_dd, dgamma); see the module docstring.
    """
    tau, D = np.empty(3), np.empty((3, 3))
    W, a, dg = return_map_into(eps_tr, ep_n, mu, lam, law, hp, tau, D)
    return W, tau, D, a, dg


def net_plastic_strain(fp_inv: np.ndarray) -> np.ndarray:
    """Equivalent net (retained) plastic strain sqrt(2/3) |ln U_p| with Fp = R_p U_p, from
    Fp^-1 of shape (..., 3, 3); shape (...). Unlike the accumulated ep, which also counts flow
    that was later reversed, this measures the plastic deformation the material keeps."""
    c = np.einsum("...ji,...jk->...ik", fp_inv, fp_inv)  # Fp^-T Fp^-1: eigenvalues U_p^-2
    e = -0.5 * np.log(np.linalg.eigvalsh(c))
    return np.sqrt(2.0 / 3.0) * np.linalg.norm(e, axis=-1)


@numba.njit(cache=True)
def plastic_flow(eps_tr: np.ndarray, ep_n: float, mu: float, law: int,
                 hp: np.ndarray) -> tuple[np.ndarray, float]:
    """Principal plastic log-strain increment dg N, shape (3,), trace zero to round-off, and dg:
    the one return the commit needs (the multiplier is solved once)."""
    dg = _dgamma(eps_tr, ep_n, mu, law, hp)
    out = np.zeros(3)
    if dg > 0.0:
        _, e, r = _trial(eps_tr)
        out = (dg * _SQRT3_2 / r) * e
        out -= (out[0] + out[1] + out[2]) / 3.0
    return out, dg


@numba.njit(cache=True)
def plastic_strain_increment(eps_tr: np.ndarray, ep_n: float, mu: float, lam: float, law: int,
                             hp: np.ndarray) -> np.ndarray:
    """Principal plastic log-strain increment dg N, shape (3,), trace zero to round-off."""
    return plastic_flow(eps_tr, ep_n, mu, law, hp)[0]

"""Hill48 plasticity (sim.materials.hill): finite differences of the return's energy, stress and
tangent, von Mises as its r = 1 case, and the r-values given back in uniaxial tension."""

import math
from decimal import Decimal, localcontext

import numpy as np
import pytest

from sim.materials.hill import (
    SERIES_SPREAD,
    _half_log_dd2,
    coefficients,
    hill_energy_h,
    hill_flow,
    hill_green,
    hill_matrix,
    hill_return,
    hill_stress_tangent,
    hill_stress_tangent_h,
    r_values,
)
from sim.materials.isotropic import dlog, polar_svd, stress_tangent
from sim.materials.plasticity import plastic_flow, yield_stress
from tests.support.hill import (
    LAM,
    LAWS,
    MU,
    R_AA5754,
    params,
    rotation_z,
    tension,
)

RNG = np.random.default_rng(18)


def evaluate(G, prm, frame, ep_n, tangent=True, project=False):
    P, C = np.zeros((3, 3)), np.zeros((9, 9))
    W = hill_stress_tangent(G, prm, frame, ep_n, tangent, project, P, C)
    return W, P, C


def test_coefficients_and_r_values_are_inverse():
    F, G, H, N = coefficients(*R_AA5754)
    assert G + H == pytest.approx(1.0, rel=1e-15)
    np.testing.assert_allclose(r_values(F, G, H, N), R_AA5754, rtol=1e-14)
    np.testing.assert_allclose(coefficients(1.0, 1.0, 1.0), (0.5, 0.5, 0.5, 1.5), rtol=1e-15)


def exact_dd2(x0: float, x1: float, x2: float) -> float:
    """The second divided difference of 1/2 ln at three distinct floats, in 60-digit decimals:
    the recursion's cancellation (a spread s of the mean loses about 2 log10(1/s) digits)
    leaves over 30 exact digits at the spreads tested."""
    with localcontext() as ctx:
        ctx.prec = 60
        a, b, c = (Decimal(x) for x in (x0, x1, x2))
        f = [v.ln() / 2 for v in (a, b, c)]
        ab, bc = (f[0] - f[1]) / (a - b), (f[1] - f[2]) / (b - c)
        return float((ab - bc) / (a - c))


@pytest.mark.parametrize("b", [1e-10, 0.3, 1.0, 4.0, 100.0, 1e10])
def test_divided_difference_of_the_log_is_exact(b):
    """dlog (every principal law's and Hill's first divided difference of the log) against the
    exact value about b, at relative spreads from 1e-9 to 1e9 either way, in both orders (the
    laws call it with the smaller argument first): within 2e-15, a few ulps (log1p's, the
    division's and r's rounding). The difference of two logarithms it replaced lost up to
    5e-12 of the value near a spread of 1e-4 away from 1 (2e-12 at b = 4)."""
    with localcontext() as ctx:
        ctx.prec = 50
        for r in np.geomspace(1e-9, 1e9, 90):
            for a in (b * (1.0 + r), b / (1.0 + r)):
                exact = float((Decimal(a).ln() - Decimal(b).ln()) / (Decimal(a) - Decimal(b)))
                assert dlog(a, b) == pytest.approx(exact, rel=2e-15), (a, b)
                assert dlog(b, a) == dlog(a, b)
    assert dlog(1e300, 1e-10) == pytest.approx(
        float((Decimal(1e300).ln() - Decimal(1e-10).ln()) / Decimal(1e300)), rel=2e-15)


@pytest.mark.parametrize("spread", [1e-9, 1e-6, 1e-4, 5e-3, 2e-2, 0.1, 0.5])
def test_second_divided_difference_of_the_log_is_exact(spread):
    """Both branches of _half_log_dd2 (the Taylor series within SERIES_SPREAD of the mean, the
    recursion beyond) against the exact value, about a mean of 1.3 (a sheet's elastic C is
    near 1: nearly every point of a Hill sheet takes the series): the series within 1e-14 (a
    few ulps of its sum, its truncation under 1e-15), the recursion within 5e-13 (its two
    differences of logarithms lose 1e-16 of their size over the spread)."""
    for _ in range(20):
        x = 1.3 * (1.0 + spread * RNG.uniform(-1.0, 1.0, 3))
        got = _half_log_dd2(*x)
        series = x.max() - x.min() <= SERIES_SPREAD * x.mean()
        assert got == pytest.approx(exact_dd2(*x), rel=1e-14 if series else 5e-13)
        # symmetric in its arguments, to the ulp or two another order of the sums gives
        assert _half_log_dd2(x[2], x[0], x[1]) == pytest.approx(got, rel=1e-15)


@pytest.mark.parametrize("law", list(LAWS))
@pytest.mark.parametrize("size", [0.5, 3.0])  # trial strain in units of the yield strain
def test_return_finite_differences(law, size):
    prm = params(law=law)
    y = yield_stress(LAWS[law][0], np.array(LAWS[law][1]), 0.02)[0]
    d = RNG.standard_normal(6)
    Hm = hill_matrix(*coefficients(*R_AA5754))
    e6 = size * y / (2 * MU * math.sqrt(d @ Hm @ d)) * d  # Hill's trial stress: size * Y
    W, T, D, dg, _ = hill_return(e6, 0.02, prm)
    assert (dg > 0) == (size > 1)
    h = 1e-5 * np.linalg.norm(e6)
    gfd, Dfd = np.empty(6), np.empty((6, 6))
    for k in range(6):
        d = np.zeros(6)
        d[k] = h
        Wp, Tp = hill_return(e6 + d, 0.02, prm)[:2]
        Wm, Tm = hill_return(e6 - d, 0.02, prm)[:2]
        gfd[k], Dfd[:, k] = (Wp - Wm) / (2 * h), (Tp - Tm) / (2 * h)
    # central differences: truncation (h/|e|)^2 ~ 1e-10, round-off 1e-16 |W| / h ~ 1e-11
    # relative; 1e-7 leaves a wide margin and still catches any inconsistent (O(1)) term
    assert np.abs(gfd - T).max() <= 1e-7 * np.abs(T).max()
    assert np.abs(Dfd - D).max() <= 1e-7 * np.abs(D).max()
    # the potential is convex: its tangent positive semidefinite (to round-off of 2 mu)
    assert np.linalg.eigvalsh(D).min() >= -1e-9 * MU


@pytest.mark.parametrize("kind", ["rest", "elastic", "plastic", "large"])
def test_stress_and_tangent_finite_differences(kind):
    """W, P = dW/dG and C = dP/dG of the full chain (log strain, frame, return) at a rotated,
    sheared G; 'rest' and 'elastic' have (nearly) equal stretches, where the divided
    differences of the logarithm take their limits."""
    prm, frame = params(), rotation_z(30.0)
    scale = {"rest": 0.0, "elastic": 5e-4, "plastic": 5e-3, "large": 0.3}[kind]
    Q, _ = np.linalg.qr(RNG.standard_normal((3, 3)))
    Q *= np.sign(np.linalg.det(Q))
    G = Q @ (np.eye(3) + scale * RNG.standard_normal((3, 3)))
    W, P, C = evaluate(G, prm, frame, 0.01)
    h = 1e-7
    for k in range(9):
        dG = np.zeros(9)
        dG[k] = h
        dG = dG.reshape(3, 3)
        Wp, Pp, _ = evaluate(G + dG, prm, frame, 0.01, False)
        Wm, Pm, _ = evaluate(G - dG, prm, frame, 0.01, False)
        # stresses ~1e8 Pa, moduli ~1e11 Pa: central differences at h = 1e-7 carry round-off
        # 1e-16 |W| / h (W <= 1e7 J/m^3) ~ 1e-2 Pa and truncation h^2 |C'| ~ 1e-3 Pa
        assert abs((Wp - Wm) / (2 * h) - P.ravel()[k]) <= 1e-6 * MU
        assert np.abs((Pp - Pm).ravel() / (2 * h) - C[:, k]).max() <= 1e-6 * MU
    assert np.array_equal(C, C.T)
    _, _, Cp = evaluate(G, prm, frame, 0.01, project=True)
    assert np.linalg.eigvalsh(Cp).min() >= -1e-9 * MU


@pytest.mark.parametrize("kind", ["rest", "elastic", "plastic", "large", "inverted"])
def test_energy_alone_is_the_stress_pass_energy_to_the_bit(kind):
    """A line search compares energies taken without the stress (hill_energy_h; hill_green
    with want 0) with the one its Newton step's evaluation gave: the same bits, or its
    decrease near equilibrium would measure the two paths' round-off."""
    prm, frame = params(), rotation_z(30.0)
    scale = {"rest": 0.0, "elastic": 5e-4, "plastic": 5e-3, "large": 0.3, "inverted": 0.0}[kind]
    for _ in range(20):
        Q, _ = np.linalg.qr(RNG.standard_normal((3, 3)))
        Q *= np.sign(np.linalg.det(Q))
        G = Q @ (np.eye(3) + scale * RNG.standard_normal((3, 3)))
        if kind == "inverted":
            G = -G
        ep_n = 0.05 * RNG.random()
        H = G - np.eye(3)  # the element kernel's form
        W = hill_stress_tangent_h(H, prm, frame, ep_n, True, False, np.empty((3, 3)),
                                  np.empty((9, 9)))
        assert np.isinf(W) == (kind == "inverted")
        assert hill_energy_h(H, prm, frame, ep_n) == W
        if kind == "inverted":
            continue
        C = G.T @ G
        lam, V = np.linalg.eigh(C)
        Sp, Dp = np.empty((3, 3)), np.empty((6, 6))
        assert hill_green(lam, V, prm, frame, ep_n, 0, Sp, Dp) == \
            hill_green(lam, V, prm, frame, ep_n, 2, Sp, Dp)


@pytest.mark.parametrize("law", list(LAWS))
@pytest.mark.parametrize("scale", [1e-4, 3e-3, 0.2])
def test_von_mises_is_the_r_one_case(law, scale):
    """r0 = r45 = r90 = 1 is the isotropic law: the same W, P, C and plastic update, to
    round-off, in any material frame."""
    code, hp = LAWS[law]
    prm = params((1.0, 1.0, 1.0), law)
    iso = np.array([MU, LAM, code, *hp])
    G = np.eye(3) + scale * RNG.standard_normal((3, 3))
    W, P, C = evaluate(G, prm, rotation_z(37.0), 0.03)
    Wi, Pi, Ci = stress_tangent(2, G, iso, 0.03, True, False)
    # the same quantities by another arithmetic: a few ulps of the largest entry
    assert W == pytest.approx(Wi, rel=1e-12)
    assert np.abs(P - Pi).max() <= 1e-12 * np.abs(Pi).max()
    assert np.abs(C - Ci).max() <= 1e-12 * np.abs(Ci).max()
    expm, dg = hill_flow(G, prm, rotation_z(37.0), 0.03)
    U, s, V, _ = polar_svd(G)
    dep, dgi = plastic_flow(np.log(s), 0.03, MU, code, np.array(hp))
    assert dg == pytest.approx(dgi, rel=1e-12, abs=0.0)
    np.testing.assert_allclose(expm, (V * np.exp(-dep)) @ V.T, rtol=0, atol=1e-14)


def uniaxial(angle, r=R_AA5754):
    """:func:`tension` at ``angle`` degrees to the rolling direction, of the material alone.
    Returns the plastic log strain tensor (3, 3) in the loading axes."""
    prm, frame = params(r), rotation_z(angle)
    state = {"fp_inv": np.eye(3), "ep": 0.0}

    def kirchhoff(F):
        G = F @ state["fp_inv"]
        _, P, _ = evaluate(G, prm, frame, state["ep"], False)
        return P @ G.T

    def commit(F):
        expm, dg = hill_flow(F @ state["fp_inv"], prm, frame, state["ep"])
        state["fp_inv"], state["ep"] = state["fp_inv"] @ expm, state["ep"] + dg

    tension(kirchhoff, commit)
    fp_inv = state["fp_inv"]
    w, V = np.linalg.eigh(np.linalg.inv(fp_inv).T @ np.linalg.inv(fp_inv))
    return (V * (0.5 * np.log(w))) @ V.T


@pytest.mark.parametrize("angle, r", [(0.0, R_AA5754[0]), (45.0, R_AA5754[1]),
                                      (90.0, R_AA5754[2])])
def test_uniaxial_tension_gives_the_r_value(angle, r):
    Ep = uniaxial(angle)
    assert abs(np.trace(Ep)) <= 1e-12  # isochoric flow
    assert Ep[0, 0] > 0.09  # mostly plastic at 10 % strain
    # width over thickness plastic strain (the issue asks for 1 %): at 0 and 90 degrees the
    # flow is coaxial with the strain and the commit exact (round-off); at 45 the commit's
    # exp(-dEp) does not commute with the elastic strain (module docstring), an O(|Ee| |dEp|)
    # error per step, measured 1.3e-7 relative over the 20 steps
    assert Ep[1, 1] / Ep[2, 2] == pytest.approx(r, rel=1e-5)

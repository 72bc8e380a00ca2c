"""Point-wise checks of the principal-space von Mises return mapping (sim.materials.plasticity)."""

import math

import numpy as np
import pytest
from scipy.integrate import quad, solve_ivp

from sim.materials.plasticity import (
    hardening_work,
    plastic_strain_increment,
    return_map,
    yield_stress,
)

# steel-like elastic constants, SI
E_MOD, NU = 210e9, 0.3
MU = E_MOD / (2.0 * (1.0 + NU))
LAM = E_MOD * NU / ((1.0 + NU) * (1.0 - 2.0 * NU))

LAWS = {
    "perfect": (0, np.array([250e6])),
    "linear": (1, np.array([250e6, 2.0e9])),
    "swift": (2, np.array([550e6, 0.01, 0.22])),
    "voce": (3, np.array([250e6, 450e6, 15.0])),
}

# unit deviatoric direction with three distinct components
DIR = np.array([1.0, -0.3, -0.7])
DIR = DIR / np.linalg.norm(DIR)


def rm(eps, ep_n, law, hp):
    return return_map(np.asarray(eps, dtype=np.float64), float(ep_n), MU, LAM, law, hp)


def q_of(tau):
    dev = tau - tau.mean()
    return math.sqrt(1.5) * np.linalg.norm(dev)


def state(law, hp, kind):
    """(eps_tr, ep_n, r_yield): trial strain placed relative to the current yield surface."""
    ep_n = {"elastic": 0.05, "just": 0.0, "plastic": 0.05, "large": 0.5}[kind]
    r_y = yield_stress(law, hp, ep_n)[0] / (math.sqrt(6.0) * MU)
    r = {"elastic": 0.5 * r_y, "just": (1.0 + 1e-3) * r_y, "plastic": 3.0 * r_y, "large": 0.3}[kind]
    return 2e-4 * np.ones(3) + r * DIR, ep_n, r_y


KINDS = ["elastic", "just", "plastic", "large"]


@pytest.mark.parametrize("name", list(LAWS))
def test_hardening_law_derivative_and_work(name):
    law, hp = LAWS[name]
    for ep in [0.0, 1e-3, 0.1, 1.0]:
        y, dy = yield_stress(law, hp, ep)
        h = 1e-7
        fd = (yield_stress(law, hp, ep + h)[0] - y) / h
        # forward difference (ep = 0 is the lower end of the domain): error ~ h Y'' / 2 with
        # |Y''| <= Y'/e0 (Swift, e0 = 0.01) -> 1e-5 of Y'; round-off 1e-16 Y / h ~ 1e-9 Y
        assert abs(fd - dy) <= 1e-4 * abs(dy) + 1e-8 * y
        for d in [1e-9, 0.3]:
            ref = quad(lambda s: yield_stress(law, hp, s)[0], ep, ep + d, epsabs=0, epsrel=1e-13)[0]
            # quad is exact to ~1e-13 on these smooth integrands; closed forms use expm1/log1p so
            # even the tiny interval d = 1e-9 keeps full relative precision
            assert hardening_work(law, hp, ep, ep + d) == pytest.approx(ref, rel=1e-11)


def test_unknown_law_raises():
    with pytest.raises(ValueError):
        yield_stress(7, np.array([1.0]), 0.0)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("name", list(LAWS))
def test_finite_differences(name, kind):
    law, hp = LAWS[name]
    eps, ep_n, r_y = state(law, hp, kind)
    W, tau, D, a_dd, dg = rm(eps, ep_n, law, hp)
    assert (dg > 0) == (kind != "elastic")
    r = np.linalg.norm(eps - eps.mean())
    # perturbing one component by h moves r by at most h: stay strictly inside one branch
    h = min(1e-4 * r, 0.1 * abs(r - r_y))
    g_fd, D_fd = np.empty(3), np.empty((3, 3))
    for k in range(3):
        dp, dm = eps.copy(), eps.copy()
        dp[k] += h
        dm[k] -= h
        Wp, tp = rm(dp, ep_n, law, hp)[:2]
        Wm, tm = rm(dm, ep_n, law, hp)[:2]
        g_fd[k] = (Wp - Wm) / (2 * h)
        D_fd[:, k] = (tp - tm) / (2 * h)
    # central FD: truncation ~ (h/r)^2 / 6 ~ 2e-9 relative (measured <= 1.2e-9), round-off
    # ~ 1e-16 |W| / h and 1e-16 |tau| / h, both < 1e-11 relative; dg is solved to round-off.
    # 1e-7 keeps a ~100x margin while still catching any inconsistent term (those are O(1))
    assert np.max(np.abs(g_fd - tau)) <= 1e-7 * np.max(np.abs(tau))
    assert np.max(np.abs(D_fd - D)) <= 1e-7 * np.max(np.abs(D))
    # symmetric by construction (the n n^T term is formed as c * (e_i * e_j)): exact
    assert np.array_equal(D, D.T)


@pytest.mark.parametrize("name", list(LAWS))
def test_elastic_branch_is_pure_hencky(name):
    law, hp = LAWS[name]
    eps, ep_n, _ = state(law, hp, "elastic")
    W, tau, D, a_dd, dg = rm(eps, ep_n, law, hp)
    tr = eps.sum()
    assert dg == 0.0
    assert not plastic_strain_increment(eps, ep_n, MU, LAM, law, hp).any()
    # same formula, differently arranged: round-off only
    assert W == pytest.approx(MU * eps @ eps + 0.5 * LAM * tr**2, rel=1e-13)
    np.testing.assert_allclose(tau, 2 * MU * eps + LAM * tr, rtol=1e-13, atol=1e-13 * MU * 1e-3)
    np.testing.assert_allclose(D, LAM + 2 * MU * np.eye(3), rtol=1e-13)
    assert a_dd == pytest.approx(2 * MU, rel=1e-15)


@pytest.mark.parametrize("kind", ["just", "plastic", "large"])
@pytest.mark.parametrize("name", list(LAWS))
def test_consistency_and_plastic_increment(name, kind):
    law, hp = LAWS[name]
    eps, ep_n, _ = state(law, hp, kind)
    W, tau, D, a_dd, dg = rm(eps, ep_n, law, hp)
    y = yield_stress(law, hp, ep_n + dg)[0]
    # s = Y / q_tr puts tau on the surface by construction; q recomputed from tau: a few ulps
    assert q_of(tau) == pytest.approx(y, rel=1e-13)
    deps_p = plastic_strain_increment(eps, ep_n, MU, LAM, law, hp)
    assert abs(deps_p.sum()) <= 1e-14
    # |deps_p| = sqrt(3/2) dg and deps_p is parallel to the trial deviator (round-off)
    assert np.linalg.norm(deps_p) == pytest.approx(math.sqrt(1.5) * dg, rel=1e-13)
    tau_tr = 2 * MU * eps + LAM * eps.sum()
    # tau_tr - 2 mu dg N: cancellation when |tau| << |tau_tr| costs ~1e-16 |tau_tr| per term
    atol = 1e-13 * np.abs(tau_tr).max()
    np.testing.assert_allclose(tau, tau_tr - 2 * MU * deps_p, rtol=0, atol=atol)
    # a_dd is the divided difference of tau over the (distinct) trial strains
    q_tr = q_of(tau_tr)
    # 1 - 3 mu dg / q_tr cancels to s = Y / q_tr ~ 4e-3 in the "large" state: ~1e-16 / s relative
    assert a_dd == pytest.approx(2 * MU * (1 - 3 * MU * dg / q_tr), rel=1e-12)
    for i, j in [(0, 1), (0, 2), (1, 2)]:
        assert (tau[i] - tau[j]) / (eps[i] - eps[j]) == pytest.approx(a_dd, rel=1e-9)
    # W is the minimum over dg of the incremental objective (variational structure)
    n_vec = math.sqrt(1.5) * (eps - eps.mean()) / np.linalg.norm(eps - eps.mean())

    def objective(g):
        ee = eps - g * n_vec
        return MU * ee @ ee + 0.5 * LAM * ee.sum() ** 2 + hardening_work(law, hp, ep_n, ep_n + g)

    assert W == pytest.approx(objective(dg), rel=1e-12)
    for g in [0.0, dg * (1 - 1e-3), dg * (1 + 1e-3), 2 * dg]:
        assert objective(g) >= W * (1 - 1e-14)


def uniaxial_history(law, hp, eps_end=0.1, n_inc=200, unload=0.5):
    """Uniaxial Kirchhoff stress in principal space, proper incremental history.

    Axial total log strain eps1 is ramped; lateral total strain x (= eps2 = eps3) is found by Newton
    on tau2 = 0 with the consistent tangent; ep_n and eps_p are carried from increment to increment.
    A final elastic unloading step of `unload * Y / E` in axial strain is appended.
    """
    ep, eps_p, x = 0.0, np.zeros(3), 0.0
    out = []
    path = list(np.linspace(0.0, eps_end, n_inc + 1)[1:])
    y_end = None
    for k in range(len(path) + 1):
        if k == len(path):
            y_end = yield_stress(law, hp, ep)[0]
            eps1 = path[-1] - unload * y_end / E_MOD
        else:
            eps1 = path[k]
        for _ in range(50):
            eps_tr = np.array([eps1, x, x]) - eps_p
            _, tau, D, _, dg = rm(eps_tr, ep, law, hp)
            if abs(tau[1]) <= 1e-13 * E_MOD * 1e-3:
                break
            x -= tau[1] / (D[1, 1] + D[1, 2])
        else:
            raise AssertionError("lateral Newton did not converge")
        assert abs(tau[2]) <= 1e-13 * E_MOD * 1e-3
        eps_p = eps_p + plastic_strain_increment(eps_tr, ep, MU, LAM, law, hp)
        ep += dg
        out.append((eps1, tau[0], ep, dg, eps_p.copy()))
    return out, y_end


@pytest.mark.parametrize("name", list(LAWS))
def test_uniaxial_stress_history(name):
    law, hp = LAWS[name]
    hist, y_end = uniaxial_history(law, hp)

    def rhs(_, z):  # z = (sigma, ep): 1-D rate form, tangent modulus E H / (E + H)
        h = yield_stress(law, hp, z[1])[1]
        return [E_MOD * h / (E_MOD + h), E_MOD / (E_MOD + h)]

    y0 = yield_stress(law, hp, 0.0)[0]
    sol = solve_ivp(rhs, (y0 / E_MOD, 0.1), [y0, 0.0], method="DOP853", rtol=1e-12, atol=1e-14,
                    dense_output=True)
    n_plastic = 0
    for eps1, t1, ep, dg, eps_p in hist[:-1]:
        if dg == 0.0:
            # elastic: uniaxial Kirchhoff stress is E times the axial log strain (round-off)
            assert ep == 0.0 and t1 == pytest.approx(E_MOD * eps1, rel=1e-12)
            continue
        n_plastic += 1
        # lateral tau ~ 1e-13 Y and the return is converged to ~1e-14: 1e-8 is generous
        assert t1 == pytest.approx(yield_stress(law, hp, ep)[0], rel=1e-8)
        # isochoric flow along N = (1, -1/2, -1/2): eps_p1 = ep exactly (summed round-off)
        np.testing.assert_allclose(eps_p, [ep, -ep / 2, -ep / 2], rtol=1e-10)
        # backward-Euler radial return is exact for this proportional 1-D path, so the only error is
        # the ODE tolerance (1e-12): far inside the required 1 %
        assert t1 == pytest.approx(sol.sol(eps1)[0], rel=1e-8)
        # closed form of the 1-D law: eps1 = Y(ep)/E + ep
        assert eps1 == pytest.approx(yield_stress(law, hp, ep)[0] / E_MOD + ep, rel=1e-9)
    assert n_plastic > 150
    eps1, t1, ep, dg, _ = hist[-1]
    # elastic unloading by half the yield stress
    assert dg == 0.0 and t1 == pytest.approx(0.5 * y_end, rel=1e-8)


@pytest.mark.parametrize("name", list(LAWS))
def test_convex_along_random_lines(name):
    law, hp = LAWS[name]
    rng = np.random.default_rng(1234 + law)
    t = np.linspace(-0.05, 0.05, 201)
    for _ in range(8):
        a = rng.normal(scale=0.01, size=3)
        b = rng.normal(size=3)
        b /= np.linalg.norm(b)
        ep_n = rng.uniform(0.0, 0.3)
        res = [rm(a + ti * b, ep_n, law, hp) for ti in t]
        W = np.array([r[0] for r in res])
        # exact convexity: second differences >= 0 up to round-off of W (few ulps of max |W|)
        assert np.min(W[:-2] - 2 * W[1:-1] + W[2:]) >= -1e-13 * np.abs(W).max()
        # the directional derivative tau.b is nondecreasing along the line (same round-off)
        slope = np.array([r[1] @ b for r in res])
        assert np.min(np.diff(slope)) >= -1e-12 * np.abs(slope).max()
        for r in res:  # consistent tangent positive semidefinite (eigen round-off ~ 1e-15 |D|)
            assert np.linalg.eigvalsh(r[2]).min() >= -1e-12 * np.abs(r[2]).max()


@pytest.mark.parametrize("name", list(LAWS))
def test_no_nan_at_extremes(name):
    law, hp = LAWS[name]
    cases = [
        np.zeros(3),
        0.5 * np.ones(3),
        -0.7 * np.ones(3),
        np.array([3.0, -1.5, -1.5]),
        np.array([3.0, -3.0, 0.7]),
        np.array([-2.9, 1.2, 1.2]),
        np.array([1e-300, 0.0, -1e-300]),
    ]
    for eps in cases:
        for ep_n in [0.0, 2.0]:
            W, tau, D, a_dd, dg = rm(eps, ep_n, law, hp)
            deps_p = plastic_strain_increment(eps, ep_n, MU, LAM, law, hp)
            vals = np.concatenate([[W, a_dd, dg], tau, D.ravel(), deps_p])
            assert np.all(np.isfinite(vals)) and dg >= 0.0 and W >= 0.0
            if dg > 0.0:  # huge strains still return exactly onto the yield surface
                assert q_of(tau) == pytest.approx(yield_stress(law, hp, ep_n + dg)[0], rel=1e-10)
                assert abs(deps_p.sum()) <= 1e-14


@pytest.mark.parametrize(
    "law, hp",
    [
        (2, np.array([550e6, 1e-6, 0.9])),
        (3, np.array([100e6, 900e6, 1000.0])),
        (0, np.array([0.0])),
    ],
)
def test_return_converges_for_stiff_hardening(law, hp):
    # near-singular Swift slope at ep = 0, very fast Voce saturation, zero yield stress
    for ep_n in [0.0, 1e-3, 0.5]:
        y_n = yield_stress(law, hp, ep_n)[0]
        r_y = max(y_n, 1e6) / (math.sqrt(6.0) * MU)
        for f in np.concatenate([1 + np.logspace(-10, 0, 11), np.logspace(0.5, 3.5, 7)]):
            eps = -1e-3 + f * r_y * DIR
            W, tau, D, a_dd, dg = rm(eps, ep_n, law, hp)
            y = yield_stress(law, hp, ep_n + dg)[0]
            # Newton converged to round-off of the residual q_tr - 3 mu dg - Y (~1e-16 q_tr)
            q_tr = math.sqrt(6.0) * MU * np.linalg.norm(eps - eps.mean())
            assert abs(q_tr - 3 * MU * dg - y) <= 1e-14 * q_tr
            assert np.all(np.isfinite(D)) and dg > 0.0

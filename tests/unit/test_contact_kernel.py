"""Penalty contact and smoothed Coulomb friction kernels (sim.terms.contact_kernels) against SDF
tools.

Scales: tools ~ 1e-2 m, contact layer delta = 1 mm, k = 1e6 N/m, slip length eps_v = 1e-5 m.
Central finite differences:
* E -> grad with h = 1e-8 m: truncation h^2 / 6 |e'''| (e''' ~ k / R, R >= 1 mm the smallest
  radius, or 0 for the quadratic penalty on flat parts) ~ 2e-5 N, round-off eps |E| / h ~
  2e-16 * 1 J / 1e-8 m ~ 2e-8 N: tolerance 1e-6 relative + 1e-4 N.
* grad -> hess, same h: truncation h^2 |e''''| ~ h^2 k / R^2 ~ 1e-4 N/m, round-off
  eps |grad| / h ~ 2e-5 N/m, against |hess| ~ k = 1e6 N/m: tolerance 1e-6 relative + 1 N/m.
Friction uses h = 1e-10 m (2e-5 of eps_v): errors h^2 |D'''| ~ h^2 mu lam / eps^2 and
eps mu lam y / h are ~1e-6 of |grad| = mu lam and of |hess| ~ mu lam / eps.
Nodes within 10 h of the kink at d = delta (Hessian jump of the quadratic penalty) or of
|u_T| = eps (Hessian jump of f0) are excluded from the FD comparisons.
"""

import numpy as np
import pytest

from sim.terms import contact_kernels as contact
from sim.tools import builders, evaluate, pose

K = 1.0e6
DELTA = 1.0e-3
R_POSE = pose.rotation([0.2, 1.0, -0.3], 0.5)
T_POSE = np.array([0.01, -0.02, 0.03])
PUNCH = builders.punch(0.03, 0.05, 0.005)


def _nodes_in_layer(prog, R, t, n, seed, spread=2.5e-3):
    """Nodes around the tool surface (flat nose, rounded rim, wall), world frame."""
    from sim.tools.surface import tool_mesh

    rng = np.random.default_rng(seed)
    V, _ = tool_mesh(prog, R, t, n_segments=32, n_arc=8)
    X = V[rng.choice(len(V), n, replace=False)] + rng.normal(scale=spread, size=(n, 3))
    d = evaluate.sdf_world_distance(prog, R, t, X)
    return X[np.abs(d - DELTA) > 1e-6]


def _energy_per_node(X, **kw):
    return np.array([contact.penalty_contact(X[i:i + 1], PUNCH, R_POSE, T_POSE, K, DELTA,
                                             **kw)[0] for i in range(len(X))])


@pytest.mark.parametrize("c2", [False, True])
def test_penalty_fd_energy_gradient_hessian(c2):
    X = _nodes_in_layer(PUNCH, R_POSE, T_POSE, 60, seed=0)
    E, grad, hess, active, gap = contact.penalty_contact(X, PUNCH, R_POSE, T_POSE, K, DELTA,
                                                         c2=c2)
    assert active.sum() > 20 and (~active).sum() > 5
    assert E == pytest.approx(_energy_per_node(X, c2=c2).sum(), rel=1e-14)
    h = 1e-8
    g_fd = np.empty_like(grad)
    H_fd = np.empty_like(hess)
    for i in range(3):
        e = np.zeros(3)
        e[i] = h
        g_fd[:, i] = (_energy_per_node(X + e, c2=c2) - _energy_per_node(X - e, c2=c2)) / (2 * h)
        gp = contact.penalty_contact(X + e, PUNCH, R_POSE, T_POSE, K, DELTA, c2=c2)[1]
        gm = contact.penalty_contact(X - e, PUNCH, R_POSE, T_POSE, K, DELTA, c2=c2)[1]
        H_fd[:, :, i] = (gp - gm) / (2 * h)
    np.testing.assert_allclose(grad, g_fd, rtol=1e-6, atol=1e-4)
    np.testing.assert_allclose(hess, H_fd, rtol=1e-6, atol=1.0)
    # nodes outside the layer cost nothing
    assert np.all(grad[~active] == 0) and np.all(hess[~active] == 0)
    np.testing.assert_array_equal(active, gap < DELTA)


def test_curvature_term_on_rounded_rim():
    # a node inside the layer near the punch rim: hess = k g g^T + e'(d) H, and the curvature
    # part is what differs from the flat-face Gauss-Newton form k g g^T
    r_rim, re = 0.03, 0.005
    phi = -0.25 * np.pi
    s = 0.6 * DELTA  # d = delta - s
    rho = r_rim - re + (re + DELTA - s) * np.cos(phi)
    z = re + (re + DELTA - s) * np.sin(phi)
    X = np.array([[rho, 0.0, z]])
    _, grad, hess, active, gap = contact.penalty_contact(X, PUNCH, None, None, K, DELTA)
    d, g, H = evaluate.sdf_eval(PUNCH, X)
    assert active[0] and gap[0] == pytest.approx(DELTA - s, abs=1e-15)
    np.testing.assert_allclose(grad[0], -K * s * g[0], rtol=1e-12)
    np.testing.assert_allclose(hess[0], K * np.outer(g[0], g[0]) - K * s * H[0], rtol=1e-10,
                               atol=1e-6)
    assert np.abs(K * s * H[0]).max() > 1.0  # the curvature term is there


def test_plane_push_force_and_far_nodes():
    n = np.array([0.3, -0.4, 1.0])
    n /= np.linalg.norm(n)
    p0 = np.array([0.01, 0.02, -0.005])
    tool = builders.plane(p0, n)
    s = np.array([0.2e-3, 1.0e-3, 2.5e-3])  # into the layer, to the surface, through it
    X = p0 + (DELTA - s)[:, None] * n
    X = np.concatenate([X, p0 + np.array([[0.0, 0.0, 0.0]]) + 5 * DELTA * n])
    E, grad, hess, active, gap = contact.penalty_contact(X, tool, None, None, K, DELTA)
    force = -grad
    np.testing.assert_allclose(force[:3], K * s[:, None] * n, rtol=1e-12)
    np.testing.assert_allclose(hess[:3], np.tile(K * np.outer(n, n), (3, 1, 1)), rtol=1e-12)
    assert E == pytest.approx(0.5 * K * np.sum(s**2), rel=1e-12)
    np.testing.assert_array_equal(active, [True, True, True, False])
    assert np.all(force[3] == 0) and np.all(hess[3] == 0)
    np.testing.assert_allclose(gap, np.r_[DELTA - s, 5 * DELTA], atol=1e-16)
    # a pose moves the plane with the tool
    R = pose.rotation([1, 0, 0], 0.3)
    t = np.array([0.0, 0.01, 0.02])
    E2, grad2, *_ = contact.penalty_contact(pose.transform(X, R, t), tool, R, t, K, DELTA)
    assert E2 == pytest.approx(E, rel=1e-12)
    np.testing.assert_allclose(grad2, grad @ R.T, rtol=1e-10, atol=1e-9)
    # all nodes far away: zero energy and the cheap path
    E, grad, hess, active, _ = contact.penalty_contact(X + n, tool, None, None, K, DELTA)
    assert E == 0.0 and not active.any() and not grad.any() and not hess.any()
    # the C2 variant is continuous in value, force and stiffness and k (s - delta / 2) deep in
    E, grad, hess, *_ = contact.penalty_contact(X[:3], tool, None, None, K, DELTA, c2=True)
    np.testing.assert_allclose(-grad[2], K * (s[2] - DELTA / 2) * n, rtol=1e-12)
    np.testing.assert_allclose(-grad[0], K * s[0] ** 2 / (2 * DELTA) * n, rtol=1e-12)
    eps = 1e-12
    Xe = p0 + np.array([-eps, eps])[:, None] * n  # both sides of s = delta
    _, ge, he, *_ = contact.penalty_contact(Xe, tool, None, None, K, DELTA, c2=True)
    np.testing.assert_allclose(ge[0], ge[1], atol=1e-5)
    np.testing.assert_allclose(he[0], he[1], atol=1e-2)


def test_psd_projection():
    X = _nodes_in_layer(PUNCH, R_POSE, T_POSE, 60, seed=1)
    _, _, hess, active, _ = contact.penalty_contact(X, PUNCH, R_POSE, T_POSE, K, DELTA)
    _, _, hp, _, _ = contact.penalty_contact(X, PUNCH, R_POSE, T_POSE, K, DELTA,
                                             project_psd=True)
    w = np.linalg.eigvalsh(hess[active])
    wp = np.linalg.eigvalsh(hp[active])
    assert w.min() < 0  # the exact Hessian is indefinite on the rounded rim
    assert wp.min() >= -1e-9 * K
    ok = w.min(axis=1) >= 0  # already PSD blocks are left alone
    np.testing.assert_allclose(hp[active][ok], hess[active][ok], atol=1e-6)


def test_auto_stiffness_rule():
    E, t, h = 210e9, 1.0e-3, 2.0e-3
    k = contact.auto_stiffness(E, t, h * h)
    p = 4e-3 * E
    assert k == pytest.approx(p * h * h / (0.01 * t))
    # a node loaded by p h^2 on a plane settles at a penetration of 1 % of the thickness
    tool = builders.plane([0, 0, 0], [0, 0, 1])
    s = p * h * h / k
    _, grad, *_ = contact.penalty_contact(np.array([[0, 0, -s]]), tool, None, None, k, 0.0)
    assert -grad[0, 2] == pytest.approx(p * h * h)
    assert s == pytest.approx(0.01 * t)
    assert contact.auto_stiffness(E, t, h * h, pressure=5e6, penetration=0.05) == pytest.approx(
        5e6 * h * h / (0.05 * t))
    # penalty / sheet through-thickness stiffness = p / (alpha E) = 0.4 by default
    assert k / (E * h * h / t) == pytest.approx(0.4)


def test_normal_forces_for_lagging():
    tool = builders.plane([0, 0, 0], [0, 0, 1])
    X = np.array([[0, 0, 0.5e-3], [0, 0, -1e-3], [0, 0, 5e-3]])
    lam, nrm = contact.normal_forces(X, tool, None, None, K, DELTA)
    np.testing.assert_allclose(lam, [K * 0.5e-3, K * 2e-3, 0.0])
    np.testing.assert_allclose(nrm, [[0, 0, 1], [0, 0, 1], [0, 0, 0]])
    _, grad, *_ = contact.penalty_contact(X, tool, None, None, K, DELTA)
    np.testing.assert_allclose(np.linalg.norm(grad, axis=1), lam)


# ----------------------------------------------------------------------------------------------
# friction
# ----------------------------------------------------------------------------------------------

MU = 0.15
EPS_V = 1.0e-5


def _friction_setup(n, seed, slip_scale):
    rng = np.random.default_rng(seed)
    nrm = rng.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    X0 = rng.uniform(-0.05, 0.05, (n, 3))
    U_tool = rng.normal(scale=1e-4, size=(n, 3))
    lam = rng.uniform(10.0, 500.0, n)
    u = rng.normal(size=(n, 3)) * (slip_scale * rng.uniform(0.05, 3.0, n))[:, None]
    X = X0 + U_tool + u
    return X, X0, U_tool, lam, nrm


def _friction_per_node(X, X0, U, lam, nrm):
    return np.array([contact.friction(X[i:i + 1], X0[i:i + 1], U[i:i + 1], lam[i:i + 1],
                                      nrm[i:i + 1], MU, EPS_V)[0] for i in range(len(X))])


def test_friction_fd():
    X, X0, U, lam, nrm = _friction_setup(80, seed=0, slip_scale=EPS_V)
    uT = X - X0 - U
    uT -= np.sum(uT * nrm, axis=1, keepdims=True) * nrm
    y = np.linalg.norm(uT, axis=1)
    keep = np.abs(y - EPS_V) > 1e-3 * EPS_V
    X, X0, U, lam, nrm, y = X[keep], X0[keep], U[keep], lam[keep], nrm[keep], y[keep]
    assert (y < EPS_V).sum() > 10 and (y > EPS_V).sum() > 10  # both regimes
    E, grad, hess = contact.friction(X, X0, U, lam, nrm, MU, EPS_V)
    assert E == pytest.approx(_friction_per_node(X, X0, U, lam, nrm).sum(), rel=1e-13)
    h = 1e-10
    g_fd = np.empty_like(grad)
    H_fd = np.empty_like(hess)
    for i in range(3):
        e = np.zeros(3)
        e[i] = h
        g_fd[:, i] = (_friction_per_node(X + e, X0, U, lam, nrm)
                      - _friction_per_node(X - e, X0, U, lam, nrm)) / (2 * h)
        gp = contact.friction(X + e, X0, U, lam, nrm, MU, EPS_V)[1]
        gm = contact.friction(X - e, X0, U, lam, nrm, MU, EPS_V)[1]
        H_fd[:, :, i] = (gp - gm) / (2 * h)
    scale = (MU * lam)[:, None]
    np.testing.assert_allclose(grad / scale, g_fd / scale, atol=1e-5)
    np.testing.assert_allclose(hess / scale[:, :, None] * EPS_V,
                               H_fd / scale[:, :, None] * EPS_V, atol=1e-5)
    # exact Hessian is PSD (eigenvalues f1/y, f1' in the tangent plane, 0 along n)
    w = np.linalg.eigvalsh(hess)
    assert w.min() >= -1e-9 * (MU * lam.max() / EPS_V)
    np.testing.assert_allclose(np.einsum("nij,nj->ni", hess, nrm), 0.0,
                               atol=1e-9 * MU * lam.max() / EPS_V)


def test_friction_force_saturates_and_opposes_slip():
    X, X0, U, lam, nrm = _friction_setup(50, seed=1, slip_scale=1e3 * EPS_V)
    E, grad, _ = contact.friction(X, X0, U, lam, nrm, MU, EPS_V)
    uT = X - X0 - U
    uT -= np.sum(uT * nrm, axis=1, keepdims=True) * nrm
    force = -grad
    np.testing.assert_allclose(np.linalg.norm(force, axis=1), MU * lam, rtol=1e-12)
    np.testing.assert_allclose(force, -MU * lam[:, None] * uT / np.linalg.norm(uT, axis=1)[:, None],
                               rtol=1e-12)
    np.testing.assert_allclose(np.sum(force * nrm, axis=1), 0.0, atol=1e-9)
    # D = mu lam |u_T| beyond eps_v
    assert E == pytest.approx(np.sum(MU * lam * np.linalg.norm(uT, axis=1)), rel=1e-12)
    # sticking (no slip relative to the moving tool) costs mu lam eps / 3 and no force;
    # zero normal force means no friction at all
    E0, g0, H0 = contact.friction(X0 + U, X0, U, lam, nrm, MU, EPS_V)
    assert E0 == pytest.approx(np.sum(MU * lam * EPS_V / 3))
    # (x0 + u) - x0 - u is a round-off residue ~1e-17 m, times mu lam 2 / eps
    np.testing.assert_allclose(g0, 0.0, atol=1e-9 * MU * lam.max())
    np.testing.assert_allclose(
        H0, MU * lam[:, None, None] * 2 / EPS_V * (np.eye(3) - nrm[:, :, None] * nrm[:, None, :]))
    E0, g0, H0 = contact.friction(X, X0, U, np.zeros_like(lam), nrm, MU, EPS_V)
    assert E0 == 0 and not g0.any() and not H0.any()


def test_tool_displacement_and_reaction():
    rng = np.random.default_rng(5)
    X0 = rng.uniform(-0.05, 0.05, (20, 3))
    R0, t0 = pose.rotation([0, 0, 1], 0.1), np.array([0.0, 0.0, 0.1])
    R1, t1 = pose.rotation([0, 0, 1], 0.3), np.array([0.0, 0.0, 0.09])
    U = contact.tool_displacement(X0, R0, t0, R1, t1)
    # the tool point at X0 has local coordinates R0^T (X0 - t0) before and after the step
    np.testing.assert_allclose(pose.to_local(X0 + U, R1, t1), pose.to_local(X0, R0, t0),
                               atol=1e-15)
    np.testing.assert_allclose(contact.tool_displacement(X0, None, t0, None, t1),
                               np.tile(t1 - t0, (20, 1)), atol=1e-15)
    # a node carried along with the tool does not slip
    lam, nrm = np.full(20, 100.0), np.tile([0, 0, 1.0], (20, 1))
    _, g, _ = contact.friction(X0 + U, X0, U, lam, nrm, MU, EPS_V)
    np.testing.assert_allclose(g, 0.0, atol=1e-9 * MU * lam.max())
    # reaction on the tool = minus the sum of the contact forces on the nodes
    tool = builders.plane([0, 0, 0], [0, 0, 1])
    Xc = np.array([[0.0, 0.0, -1e-4], [0.01, 0.0, 2e-4], [0.0, 0.0, 0.1]])
    _, gp, *_ = contact.penalty_contact(Xc, tool, None, None, K, DELTA)
    lam, nrm = contact.normal_forces(Xc, tool, None, None, K, DELTA)
    slip = np.array([[1e-3, 0, 0]] * 3)
    _, gf, _ = contact.friction(Xc + slip, Xc, np.zeros((3, 3)), lam, nrm, MU, EPS_V)
    F = contact.reaction_force(gp, gf)
    np.testing.assert_allclose(F, -(-gp - gf).sum(axis=0))
    assert F[2] < 0 and F[0] > 0  # pushed down, dragged along the slip
    assert F[2] == pytest.approx(-K * (1.1e-3 + 0.8e-3))
    assert F[0] == pytest.approx(MU * (-F[2]))
    M = contact.reaction_moment(Xc, [0, 0, 0], gp, gf)
    np.testing.assert_allclose(M, np.cross(Xc, gp + gf).sum(axis=0))

"""Finite-difference checks of every energy term's gradient and Hessian, and of the material
tangents (exact and projected)."""

import numpy as np
import pytest

from sim.elements import ROUTINE
from sim.materials.isotropic import (
    clamp_psd,
    jacobi3_lanes_into,
    principal_stress_tangent_into,
    project3,
    stress_tangent,
)
from sim.scene.load import load_scene
from sim.stepping.simulation import Simulation
from tests.support.fd import fd_check_term

RNG = np.random.default_rng(7)


@pytest.mark.parametrize("model", [0, 1])
@pytest.mark.parametrize("kind", ["rest", "general", "compressed", "equal"])
def test_material_tangent(model, kind):
    F = {"rest": np.eye(3), "general": np.eye(3) + 0.3 * RNG.standard_normal((3, 3)),
         "compressed": np.diag([0.7, 0.8, 1.1]) @ np.array([[1, 0.2, 0], [0, 1, 0], [0, 0, 1]]),
         "equal": np.diag([1.1, 1.1, 0.9])}[kind]
    if np.linalg.det(F) <= 0:
        F[:, 0] *= -1
    params = np.array([2.0, 5.0])
    W, P, C = stress_tangent(model, F, params, 0.0, True, False)
    h = 1e-6
    for k in range(9):
        dF = np.zeros(9)
        dF[k] = h
        dF = dF.reshape(3, 3)
        Wp, Pp, _ = stress_tangent(model, F + dF, params, 0.0, False, False)
        Wm, Pm, _ = stress_tangent(model, F - dF, params, 0.0, False, False)
        # O(1) moduli: central differences with h = 1e-6 are good to ~1e-9
        assert abs((Wp - Wm) / (2 * h) - P.ravel()[k]) < 1e-7
        assert np.abs((Pp - Pm).ravel() / (2 * h) - C[:, k]).max() < 1e-7
    _, _, Cp = stress_tangent(model, F, params, 0.0, True, True)
    assert np.linalg.eigvalsh(Cp).min() > -1e-10  # projected tangent is PSD
    if np.linalg.eigvalsh(C).min() >= 0:
        assert np.allclose(Cp, C, atol=1e-10)  # and equal to the exact one where that is PSD


def test_project3_is_the_eigenvalue_clamp():
    """project3 clamps a 3 x 3 block's eigenvalues at zero in place, inside a larger tangent
    (a 6 x 6's leading block, as q3t_ans's point tangent holds it): on random symmetric
    blocks, half of them shifted to definite, it gives Q max(ev, 0) Q^T to round-off (1e-12 of
    the block's largest entry: a 3 x 3 eigen-decomposition's), leaves a definite block
    exactly as it was (its leading minors say so, no decomposition) and touches nothing
    outside the block."""
    definite = 0
    for i in range(2000):
        A = RNG.standard_normal((3, 3))
        A = A + A.T + (4.0 * np.eye(3) if i % 2 else 0.0)
        D = RNG.standard_normal((6, 6))
        D[:3, :3] = A
        before = D.copy()
        project3(D)
        ev, Q = np.linalg.eigh(A)
        assert np.abs(D[:3, :3] - (Q * np.maximum(ev, 0.0)) @ Q.T).max() \
            <= 1e-12 * np.abs(A).max(), A
        assert np.array_equal(D[3:], before[3:]) and np.array_equal(D[:3, 3:], before[:3, 3:])
        if ev[0] > 1e-9 * np.abs(A).max():
            assert np.array_equal(D, before), A
            definite += 1
    assert 500 < definite < 1500


def test_jacobi_lanes_decompose_each_matrix_as_it_would_be_alone():
    """jacobi3_lanes_into, E^'s eigen-decomposition at q3t_ans's points three at a time:
    each lane's eigenvalues and vectors are those of that matrix decomposed alone (n = 1),
    bit for bit, whatever its neighbours (a diagonal one that takes no rotation, a nearly
    diagonal one, a general one), with and without the vectors; they are the eigenvalues in
    ascending order and A V = V diag(w) to round-off (1e-14 of |A|: a few rotations'), V
    orthogonal."""
    kinds = [np.diag([0.3, -0.1, 0.2]), np.diag([0.01, 0.02, -0.03]) + 1e-9,
             0.01 * RNG.standard_normal((3, 3)), RNG.standard_normal((3, 3))]
    mats = [0.5 * (K + K.T) for K in kinds]
    for n in (1, 2, 3):
        for trial in range(20):
            pick = [mats[(trial + i) % len(mats)] for i in range(n)] if trial < 4 else \
                [0.5 * (B + B.T) for B in RNG.standard_normal((n, 3, 3))]
            A = np.zeros((3, 3, 3))
            A[:n] = pick
            for vectors in (True, False):
                w, V = np.zeros((3, 3)), np.zeros((3, 3, 3))
                jacobi3_lanes_into(A, n, w, V, vectors)
                for lane in range(n):
                    w1, V1 = np.zeros((3, 3)), np.zeros((3, 3, 3))
                    jacobi3_lanes_into(A[lane:lane + 1].copy().repeat(3, 0), 1, w1, V1,
                                       vectors)
                    assert np.array_equal(w[lane], w1[0])
                    assert np.array_equal(w[lane], np.sort(w[lane]))
                    scale = np.abs(A[lane]).max()
                    assert np.abs(w[lane] - np.linalg.eigvalsh(A[lane])).max() \
                        <= 1e-14 * scale
                    if vectors:
                        assert np.array_equal(V[lane], V1[0])
                        Vl = V[lane]
                        assert np.abs(A[lane] @ Vl - Vl * w[lane]).max() <= 1e-14 * scale
                        assert np.abs(Vl.T @ Vl - np.eye(3)).max() <= 1e-14


@pytest.mark.parametrize("n", [6, 9, 27])
def test_clamp_psd_is_the_eigenvalue_clamp(n):
    """clamp_psd, the projection of a point's Hill48 tangent (6 x 6 or 9 x 9), of an
    initial-stress term (9 x 9) and of an element's Hessian (27 x 27): Q max(ev, 0) Q^T to
    round-off (1e-12 of the largest entry, an eigen-decomposition's at these sizes), and a
    positive definite matrix, which its Cholesky factorisation recognises, left exactly as it
    was (no eigen-decomposition), as is a semi-definite one's clamp to round-off."""
    definite = 0
    for i in range(400):
        B = RNG.standard_normal((n, n))
        K = B + B.T + (3.0 * np.sqrt(n) * np.eye(n) if i % 2 else 0.0)
        if i % 5 == 4:  # rank-deficient semi-definite, as an element's rigid motions make it
            K = B[:, : n // 2] @ B[:, : n // 2].T
        before = K.copy()
        clamp_psd(K)
        ev, Q = np.linalg.eigh(before)
        scale = np.abs(before).max()
        assert np.abs(K - (Q * np.maximum(ev, 0.0)) @ Q.T).max() <= 1e-12 * scale
        assert np.allclose(K, K.T, rtol=0, atol=1e-14 * scale)
        if ev[0] > 1e-8 * scale:
            assert np.array_equal(K, before)
            definite += 1
    assert 100 < definite < 300


def _rotation(axis, angle):
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * Kx + (1 - np.cos(angle)) * Kx @ Kx


@pytest.mark.parametrize("kind", ["rest", "general", "compressed", "equal"])
def test_neo_hookean_direct_matches_principal_form(kind):
    """The exact Neo-Hookean W, P and tangent are computed from H = F - I directly, the
    projected tangent in the principal frame: both forms must give the same W, P and C."""
    F = {"rest": np.eye(3), "general": np.eye(3) + 0.3 * RNG.standard_normal((3, 3)),
         "compressed": np.diag([0.7, 0.8, 1.1]),
         "equal": _rotation([1, 2, 3], 0.7) @ np.diag([1.1, 1.1, 0.9])}[kind]
    if np.linalg.det(F) <= 0:
        F[:, 0] *= -1
    params = np.array([2.0, 5.0])
    W, P, C = stress_tangent(0, F, params, 0.0, True, False)
    Pp, Cp = np.zeros((3, 3)), np.zeros((9, 9))
    Wp = principal_stress_tangent_into(0, F, params, 0.0, True, False, Pp, Cp)
    # two evaluations of the same closed forms: they differ by round-off of O(1) quantities
    assert W == pytest.approx(Wp, rel=1e-12, abs=1e-14)
    np.testing.assert_allclose(P, Pp, atol=1e-12)
    np.testing.assert_allclose(C, Cp, atol=1e-10)
    _, P2, C2 = stress_tangent(0, F, params, 0.0, True, True)
    np.testing.assert_array_equal(P2, P)  # projecting changes only the tangent
    if np.linalg.eigvalsh(C).min() > 0:
        np.testing.assert_allclose(C2, C, atol=1e-10)


@pytest.mark.parametrize("model", [0, 1])
def test_small_strain_energy_keeps_its_digits_under_rotation(model):
    """A bent thin shell: strain 1e-6 under a rotation of 0.8 rad. The energy (1e-12 of the
    moduli) must not drown in the round-off of O(1) terms: both forms cancel the first-order
    parts analytically, leaving round-off of order eps * strain, 1e-10 of the energy."""
    e = 1e-6
    F = _rotation([0.3, -1.0, 0.2], 0.8) @ np.diag([1 + e, 1.0, 1.0])
    mu, lam = 2.0, 5.0
    # uniaxial stretch s = 1 + e, series to O(e^4): s^2 - 1 - 2 ln s and ln s
    sq_minus_log = 2 * e**2 - 2 * e**3 / 3 + e**4 / 2
    ln_s = e - e**2 / 2 + e**3 / 3
    exact = {0: 0.5 * mu * sq_minus_log + 0.5 * lam * ln_s**2,
             1: mu * ln_s**2 + 0.5 * lam * ln_s**2}[model]
    for project in (False, True):
        W, _, _ = stress_tangent(model, F, np.array([mu, lam]), 0.0, False, project)
        assert W == pytest.approx(exact, rel=1e-8)


def test_energy_is_infinite_for_inverted_elements():
    F = np.diag([1.0, 1.0, -0.5])
    for model in (0, 1):
        W, P, _ = stress_tangent(model, F, np.array([1.0, 1.0]), 0.0, False, False)
        assert W == np.inf and np.all(np.isfinite(P))


def _small(element, extra=None):
    o = {"mesh.edge_length": 0.035, "material.E": 1e6, "shell.element": element,
         "solver.hessian_projection": "none"}
    o.update(extra or {})
    return Simulation.from_scene(load_scene("scenes/cantilever.toml", o)).model


@pytest.mark.parametrize("element", ROUTINE)
@pytest.mark.parametrize("material", ["neo_hookean", "hencky"])
def test_elasticity_term_fd(element, material):
    m = _small(element, {"material.model": material})
    term = m.elasticity
    x = m.shell.rest + 2e-4 * RNG.standard_normal(m.shell.rest.shape)

    fd_check_term(term, m.pattern, x, 1e-3, RNG)


def test_external_force_and_inertia_fd():
    m = Simulation.from_scene(load_scene("scenes/cantilever.toml", {
        "mesh.edge_length": 0.035, "stepping.kind": "dynamic", "stepping.dt": 1e-3})).model
    assert "inertia" in m.built["terms"] and "external_force" in m.built["terms"]
    x = m.shell.rest + 1e-3 * RNG.standard_normal(m.shell.rest.shape)
    for term in (m.external, m.inertia):
        term.begin_step(0.5, 1e-3, m.shell.rest)

        def grad(y, term=term):
            g = np.zeros_like(y)
            term.add_gradient(y, g)
            return g

        if term is m.external:  # linear: zero Hessian, check the gradient only
            v = RNG.standard_normal(x.shape)
            fd = (term.energy(x + 1e-4 * v) - term.energy(x - 1e-4 * v)) / 2e-4
            assert np.isclose(fd, np.sum(grad(x) * v), rtol=1e-9)
        else:
            fd_check_term(term, m.pattern, x, 1e-3, RNG)


def test_loads_sum_to_applied_totals():
    """Consistent nodal forces integrate exactly: gravity sums to the weight, a traction to
    traction x rim area, a pressure to pressure x skin area, for every element."""
    for el in ROUTINE:
        m = _small(el)
        total = m.external.f.sum(0)
        weight = 1000.0 * 9.81 * 0.7 * 0.07 * 0.007
        assert np.allclose(total, [0, 0, -weight], rtol=1e-12, atol=1e-12)
        m2 = Simulation.from_scene(load_scene("scenes/cantilever.toml", {
            "mesh.edge_length": 0.035, "shell.element": el,
            "loads": [{"kind": "traction", "vector": [1e3, 0, 0], "region": "clamp"},
                      {"kind": "pressure", "value": 10.0}]})).model
        f = m2.external.f.sum(0)
        assert np.allclose(f, [1e3 * 0.07 * 0.007, 0, -10.0 * 0.7 * 0.07], rtol=1e-10)

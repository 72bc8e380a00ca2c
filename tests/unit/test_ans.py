"""The assumed-shear element q3t_ans (sim.terms.ans): energy, gradient and exact Hessian against
finite differences for every material (Neo-Hookean, Hencky, plastic), rest state, objectivity,
and the Hessian's definiteness check of its element projection."""

import numpy as np
import pytest

from sim.elements import get_element
from sim.geometry import shell
from sim.geometry import trimesh as mesh
from sim.materials.plasticity import LINEAR
from sim.solve import assembly
from sim.terms.elasticity import PROJECT_ELEMENT, PROJECT_NONE, Elasticity
from tests.support.fd import fd_check

RNG = np.random.default_rng(11)
MU, LAM = 3e6, 5e6
H = 0.004  # thickness; the in-plane size 0.01 makes the prisms as slender as a coarse sheet


def _term(model: int, project: int = PROJECT_NONE) -> Elasticity:
    """q3t_ans on a distorted 3 x 2 patch (12 prisms); plastic: a committed state with
    Fp^-1 away from I (det 1) and ep > 0, so the strain's plastic part is exercised."""
    e = get_element("q3t_ans")
    rng = np.random.default_rng(3)  # the same patch and state on every call
    m = mesh.rectangle((0.03, 0.02), 0.01)
    V = m.vertices.copy()
    V[:, :2] += 0.002 * rng.uniform(-1, 1, (len(V), 2))
    sh = shell.extrude(mesh.TriMesh(V, m.faces), H, e)
    pat = assembly.build_pattern(sh.conn, sh.n_nodes)
    plastic = model == 2
    # linear hardening from a yield stress the perturbed states below exceed
    params = np.array([MU, LAM, float(LINEAR), 1e4, 1e5]) if plastic else np.array([MU, LAM])
    el = Elasticity(sh, e.quadrature(), model, params, pat, project, plastic=plastic)
    if plastic:
        n_e, n_q = el.ep.shape
        for i in range(n_e):
            for q in range(n_q):
                A = np.eye(3) + 0.05 * rng.standard_normal((3, 3))
                el.fp_inv[i, q] = A / np.cbrt(np.linalg.det(A))
        el.ep[:] = 0.01 * rng.random(el.ep.shape)
    return el


def _rotation(axis, angle):
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * Kx + (1 - np.cos(angle)) * Kx @ Kx


def _grad(term):
    def grad(y):
        g = np.zeros_like(y)
        term.add_gradient(y, g)
        return g
    return grad


def _hv(term):
    def hv(y, v):
        d = np.zeros(term.pattern.nnz)
        term.add_hessian(y, d)
        return (term.pattern.matrix(d) @ v.ravel()).reshape(v.shape)
    return hv


@pytest.mark.parametrize("model", [0, 1, 2], ids=["neo_hookean", "hencky", "plastic"])
@pytest.mark.parametrize("rotated", [False, True], ids=["small", "rotated"])
def test_energy_gradient_hessian_fd(model, rotated):
    """A random state of strain 1e-2 (rotated: under a rotation of 0.8 rad, so the initial
    stress of the tied shear is exercised at large rotation)."""
    term = _term(model)
    x = term.rest + 2e-4 * RNG.standard_normal(term.rest.shape)
    if rotated:
        x = x @ _rotation([0.3, -1.0, 0.2], 0.8).T
    if model == 2:  # the state flows: its trial return map is on the plastic branch
        ep0 = term.ep.copy()
        saved = term.fp_inv.copy()
        term.commit(x)
        assert (term.ep > ep0).any()
        term.fp_inv[:], term.ep[:] = saved, ep0
    fd_check(term.energy, _grad(term), _hv(term), x, 1e-3, RNG)


@pytest.mark.parametrize("model", [0, 1])
def test_rest_state_and_rigid_motion_are_free(model):
    """At rest, and after any rigid motion, energy and force vanish: the strain is formed
    from the displacement, so they are round-off of the strain, not of the positions."""
    term = _term(model)
    R = _rotation([1.0, 2.0, -0.5], 1.1)
    for x in (term.rest.copy(), term.rest @ R.T + np.array([0.3, -0.1, 0.2])):
        g = _grad(term)(x)
        # rigid motion of size 1: the strain is round-off, eps ~ 1e-16, W ~ MU eps^2 V
        assert abs(term.energy(x)) < 1e-20
        assert np.abs(g).max() < 1e-9 * MU * H * 0.01  # a force of strain 1e-9 on a face


@pytest.mark.parametrize("model", [0, 1, 2], ids=["neo_hookean", "hencky", "plastic"])
def test_energy_is_objective(model):
    """The assumed strain is covariant: rotating a deformed state changes no energy."""
    term = _term(model)
    x = term.rest + 3e-4 * RNG.standard_normal(term.rest.shape)
    E0 = term.energy(x)
    E1 = term.energy(x @ _rotation([0.2, 0.7, -1.0], 2.0).T)
    assert E1 == pytest.approx(E0, rel=1e-10)  # round-off of O(1) positions over strain 1e-2


def test_inverted_element_has_infinite_energy():
    term = _term(0)
    x = term.rest.copy()
    top = term.conn[0, 6:]
    x[top, 2] = term.rest[term.conn[0, :3], 2] - 0.5 * H  # top skin pushed below the bottom
    assert term.energy(x) == np.inf


def test_element_projection_is_psd_and_exact_where_definite():
    """Any projection is the element's (the tied shear's initial stress has no per-point PSD
    split): the projected Hessian is PSD, and equals the exact one at rest (PSD there)."""
    exact, proj = _term(1), _term(1, PROJECT_ELEMENT)
    x = exact.rest + 1e-3 * RNG.standard_normal(exact.rest.shape)
    for y, check_equal in ((exact.rest.copy(), True), (x, False)):
        de, dp = np.zeros(exact.pattern.nnz), np.zeros(exact.pattern.nnz)
        exact.add_hessian(y, de)
        proj.add_hessian(y, dp)
        Kp = proj.pattern.matrix(dp).toarray()
        scale = np.abs(Kp).max()
        assert np.linalg.eigvalsh(Kp).min() > -1e-10 * scale  # eigh round-off of the scale
        if check_equal:
            np.testing.assert_allclose(dp, de, atol=1e-10 * scale)

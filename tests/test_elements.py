"""Element properties over the whole registry (scikit-fem style): nodality, partition of unity,
derivatives against finite differences, quadrature volume, patch test, and stiffness rank."""

import numpy as np
import pytest

from sim import assembly, mesh, shell
from sim.elements import ELEMENTS
from sim.quadrature import prism_rule, triangle_rule
from sim.terms.elasticity import PROJECT_NONE, Elasticity

NAMES = sorted(ELEMENTS)


@pytest.mark.parametrize("name", NAMES)
def test_nodality(name):
    e = ELEMENTS[name]
    N, _ = e.basis(e.reference_nodes())
    # Lagrange bases at their own nodes: identity to round-off of the products (degree <= 4)
    assert np.allclose(N, np.eye(e.n_nodes), atol=1e-12)


@pytest.mark.parametrize("name", NAMES)
def test_partition_of_unity_and_linear_reproduction(name):
    e = ELEMENTS[name]
    pts = np.random.default_rng(0).random((50, 3))
    pts[:, :2] *= 0.5  # inside the triangle
    pts[:, 2] = 2 * pts[:, 2] - 1
    N, dN = e.basis(pts)
    assert np.allclose(N.sum(1), 1.0, atol=1e-12)
    assert np.allclose(dN.sum(1), 0.0, atol=1e-11)
    X = e.reference_nodes()
    assert np.allclose(N @ X, pts, atol=1e-12)  # x = sum N_i x_i reproduces linear fields
    assert np.allclose(np.einsum("nad,ae->ned", dN, X), np.eye(3), atol=1e-11)


def test_paper_printed_q3t_weight_is_not_a_partition_of_unity():
    """Sec. 3.3 prints (1-w)^2 for the mid-surface weight. With it the weights do not sum to one
    (at w = -1 they sum to 5) and a linear field is not reproduced; 1 - w^2 fixes both."""
    w = np.linspace(-1, 1, 9)
    printed = 0.5 * w * (w - 1) + (1 - w) ** 2 + 0.5 * w * (w + 1)
    correct = 0.5 * w * (w - 1) + (1 - w * w) + 0.5 * w * (w + 1)
    assert np.abs(printed - 1).max() > 1.0
    assert np.allclose(correct, 1.0)
    # Eq. (6) as printed, (w-1)/2 x_b + (w+1)/2 x_t, is not nodal at the bottom (w = -1 gives
    # -x_b); the linear element uses (1-w)/2.
    assert 0.5 * (-1 - 1) == -1.0
    N, _ = ELEMENTS["linear"].basis(np.array([[1.0, 0.0, -1.0]]))
    assert N[0, 0] == 1.0


@pytest.mark.parametrize("name", NAMES)
def test_derivatives_against_finite_differences(name):
    e = ELEMENTS[name]
    p = np.array([[0.2, 0.3, 0.1]])
    _, dN = e.basis(p)
    h = 1e-6
    for d in range(3):
        dp = np.zeros(3)
        dp[d] = h
        fd = (e.basis(p + dp)[0] - e.basis(p - dp)[0]) / (2 * h)
        # central differences of polynomials of degree <= 8: truncation h^2 * 1e3, round-off
        # 1e-16 / h; 1e-7 sits above both
        assert np.allclose(fd[0], dN[0, :, d], atol=1e-7)


@pytest.mark.parametrize("n", [1, 3, 6, 7, 9, 16, 25])
def test_triangle_rules_integrate_monomials(n):
    pts, w = triangle_rule(n)
    degree = {1: 1, 3: 2, 6: 4, 7: 5, 9: 5, 16: 7, 25: 9}[n]
    from math import factorial

    for a in range(degree + 1):
        for b in range(degree + 1 - a):
            exact = factorial(a) * factorial(b) / factorial(a + b + 2)
            assert np.isclose(np.sum(w * pts[:, 0] ** a * pts[:, 1] ** b), exact, rtol=1e-12)


@pytest.mark.parametrize("name", NAMES)
def test_quadrature_weights_sum_to_prism_volume(name):
    e = ELEMENTS[name]
    m = mesh.rectangle((0.03, 0.02), 0.01)
    sh = shell.extrude(m, 0.004, e)
    el = Elasticity(sh, e.quadrature(), 0, np.array([1.0, 1.0]),
                    assembly.build_pattern(sh.conn, sh.n_nodes), PROJECT_NONE)
    assert np.isclose(el.wdetJ.sum(), 0.03 * 0.02 * 0.004, rtol=1e-12)
    assert np.isclose(prism_rule(*e.default_quadrature).weights.sum(), 1.0, rtol=1e-14)


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("model", [0, 1])
def test_patch_test_linear_field(name, model):
    """A homogeneous deformation x = A X on a distorted patch: F = A at every quadrature point
    (exactly), so the stress is constant and interior nodes carry zero net force."""
    e = ELEMENTS[name]
    m = mesh.rectangle((0.04, 0.03), 0.01)
    V = m.vertices.copy()
    rng = np.random.default_rng(3)
    interior = (V[:, 0] > 0) & (V[:, 0] < 0.04) & (V[:, 1] > 0) & (V[:, 1] < 0.03)
    V[interior, :2] += 0.002 * rng.uniform(-1, 1, (interior.sum(), 2))  # distort the patch
    sh = shell.extrude(mesh.TriMesh(V, m.faces), 0.005, e)
    pat = assembly.build_pattern(sh.conn, sh.n_nodes)
    el = Elasticity(sh, e.quadrature(), model, np.array([3e6, 5e6]), pat, PROJECT_NONE)
    A = np.array([[1.02, 0.01, 0.0], [-0.005, 0.99, 0.003], [0.002, 0.0, 1.01]])
    x = sh.rest @ A.T
    F = np.einsum("ead,eqaj->eqdj", x[el.conn], el.dNdX)
    assert np.abs(F - A).max() < 1e-12
    g = np.zeros_like(x)
    el.add_gradient(x, g)
    boundary = set(np.unique(mesh.boundary_edges(m.faces)))
    inner_plane = [a for a in range(sh.n_plane)
                   if a < sh.n_vertices and a not in boundary]
    inner = np.concatenate([k * sh.n_plane + np.array(inner_plane) for k in range(1, e.q)]) \
        if e.q > 1 else np.array([], int)
    scale = np.abs(g).max()
    if len(inner):
        # interior mid-layer nodes: forces cancel to round-off of the sum (1e-10 of the largest)
        assert np.abs(g[inner]).max() < 1e-10 * scale


def _rank_defect(name, quad, clamp, cells=(2, 1)):
    e = ELEMENTS[name]
    m = mesh.rectangle((0.02 * cells[0], 0.02 * cells[1]), 0.02) if not clamp \
        else mesh.rectangle((0.04, 0.04), 0.01)
    sh = shell.extrude(m, 0.004, e)
    pat = assembly.build_pattern(sh.conn, sh.n_nodes)
    el = Elasticity(sh, e.quadrature(quad), 0, np.array([1.0, 1.0]), pat, PROJECT_NONE)
    data = np.zeros(pat.nnz)
    el.add_hessian(sh.rest.copy(), data)
    K = pat.matrix(data).toarray()
    if clamp:  # clamp one edge (all layers): no rigid modes remain
        fixed = np.isclose(sh.plane_mid[:, 0], 0.0)
        cols = np.concatenate([k * sh.n_plane + np.flatnonzero(fixed) for k in range(e.q + 1)])
        keep = np.setdiff1d(np.arange(3 * sh.n_nodes), (3 * cols[:, None] + np.arange(3)).ravel())
        K = K[np.ix_(keep, keep)]
    ev = np.linalg.eigvalsh(K)
    # eigenvalues below 1e-9 of the largest are zero-energy modes (the spectrum's physical part
    # is above 1e-6 of the largest for these aspect ratios)
    zero = int(np.sum(ev < 1e-9 * ev.max()))
    return zero - (0 if clamp else 6)


@pytest.mark.parametrize("name", ["linear", "q3t", "quadratic"])
def test_default_quadrature_has_no_spurious_modes(name):
    """Zero-energy modes beyond the six rigid ones, on a single-cell patch and a clamped patch,
    at each element's default rule (see README: 'Quadrature and spurious modes')."""
    e = ELEMENTS[name]
    assert _rank_defect(name, e.default_quadrature, clamp=False) == 0
    assert _rank_defect(name, e.default_quadrature, clamp=True) == 0


def test_q3t_paper_rule_spurious_mode_only_on_a_single_cell():
    """The paper's 1 x 3 rule (our default) leaves one zero-energy mode on a free single-cell
    patch of two triangles; two cells or more remove it, and 3 x 3 never has it."""
    assert _rank_defect("q3t", (1, 3), clamp=False, cells=(1, 1)) == 1
    assert _rank_defect("q3t", (1, 3), clamp=False, cells=(2, 2)) == 0
    assert _rank_defect("q3t", (3, 3), clamp=False, cells=(1, 1)) == 0


@pytest.mark.parametrize("name", ["linear", "q3t", "quadratic"])
def test_scatter_colours_partition_elements_without_shared_nodes(name):
    """The parallel scatter is race-free only if no two elements of a colour share a node."""
    from sim.assembly import greedy_colors

    sh = shell.extrude(mesh.annulus(0.0, 0.03, 0.004), 0.001, ELEMENTS[name])
    groups = greedy_colors(sh.conn, sh.n_nodes)
    assert sorted(np.concatenate(groups).tolist()) == list(range(len(sh.conn)))
    for g in groups:
        nodes = sh.conn[g].ravel()
        assert len(np.unique(nodes)) == len(nodes)

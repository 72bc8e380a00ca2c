"""Penalty contact and smoothed Coulomb friction of sheet nodes against a rigid SDF tool.

Both are energy terms for a Newton solver that minimises the total energy: every function
returns the energy E, its gradient (n, 3) (d E / d x of each node) and a per-node Hessian
(n, 3, 3) (the terms are node-wise, so the global Hessian is block diagonal in them).
The contact force on node i is f_i = -grad_i.

Normal contact (``penalty_contact``)
------------------------------------
With d_i the signed distance of node i to the tool surface (``sim.tools``, > 0 in the air),
g_i its gradient (outward tool normal) and H_i its Hessian, and s = delta - d the penetration
into the contact layer of thickness delta:

* ``c2=False`` (default): e(d) = k / 2 * max(0, s)^2. C1 in d, the Hessian jumps by k when a
  node enters the layer; normal force k s, exactly the linear spring of the penalty method.
* ``c2=True``: e'' ramps linearly over the layer, e''(d) = k min(s, delta) / delta for s > 0:
      e = k s^3 / (6 delta)                                   0 <= s <= delta
      e = k delta^2 / 6 + k delta / 2 (s - delta) + k / 2 (s - delta)^2     s > delta
  C2 in d (needs delta > 0); beyond the layer the force is k (s - delta / 2), i.e. the same
  spring acting on a surface moved delta / 2 out.

delta is the contact offset: the spring starts when a node comes closer than delta to the tool
(0 means at the tool surface; a small positive value keeps the actual penetration of the
tool surface smaller for the same stiffness).

Per node, with e' = de/dd and e'' = d2e/dd2:
    grad = e'(d) g,      hess = e''(d) g g^T + e'(d) H.
The curvature term e'(d) H is what makes a node slide correctly around a rounded punch nose
or die shoulder. Next to convex parts of a tool (punch rim, die shoulder) H is PSD and
e' < 0, so the term is negative semi-definite and the node Hessian can be indefinite;
``project_psd=True`` clamps the negative eigenvalues of each 3 x 3 block to zero (Jacobi
eigen-decomposition) for solvers that need a PSD matrix. The default is the exact Hessian.
Nodes with d >= delta cost nothing: their distance is evaluated without derivatives and only
the nodes inside the layer get the full (d, g, H) evaluation.

Friction (``friction``)
-----------------------
Smoothed Coulomb friction with lagged normal force, as in IPC (Li et al. 2020, "Incremental
Potential Contact", sec. 5): lam_n (n,) normal-force magnitudes and n (n, 3) unit normals are
frozen at the start of the step (``normal_forces``); the slip of node i over the step is
    u = (x - x_start) - u_tool,   u_T = (I - n n^T) u,   y = |u_T|,
with u_tool the displacement over the step of the tool material point that was at x_start
(``tool_displacement``). The dissipative potential is
    D = sum_i mu lam_n f0(y_i),
    f1(y) = 2 y / eps - y^2 / eps^2 (y < eps), 1 (y >= eps),     f0' = f1,
    f0(y) = -y^3 / (3 eps^2) + y^2 / eps + eps / 3 (y < eps),  y (y >= eps),
eps = eps_v the slip length below which static friction is regularised (IPC's eps_v h).
    grad = mu lam_n f1(y) / y u_T                     (|grad| = mu lam_n for y >= eps)
    hess = mu lam_n [ f1(y) / y P + (f1'(y) y - f1(y)) / y^3 u_T u_T^T ],  P = I - n n^T
(for y < eps: f1 / y = 2 / eps - y / eps^2, (f1' y - f1) / y^3 = -1 / (eps^2 y); at y = 0 the
limit 2 / eps P). In the tangent plane its eigenvalues are f1(y) / y (across the slip) and
f1'(y) (along it), both >= 0 for this f1, and 0 along n: IPC's PSD projection of the 2 x 2
tangent block therefore changes nothing here; the exact Hessian returned is already PSD
(because normal and lam_n are lagged, T does not depend on x).

Reaction
--------
The force the sheet exerts on the tool is minus the sum of the contact forces on the nodes,
F_tool = -sum_i f_i = sum_i grad_i (``reaction_force``, summing any number of terms), and its
moment about a point c is sum_i (x_i - c) x grad_i (``reaction_moment``).
"""

from __future__ import annotations

import math

import numba
import numpy as np
import numpy.typing as npt

from sim.materials.isotropic import eigh3
from sim.tools.evaluate import sdf_world, sdf_world_distance
from sim.tools.pose import pose

# design contact pressure of auto_stiffness, as a fraction of Young's modulus
DESIGN_PRESSURE = 4e-3

# ----------------------------------------------------------------------------------------------
# normal contact
# ----------------------------------------------------------------------------------------------


@numba.njit(cache=True)
def _penalty_scalar(d: float, k: float, delta: float, c2: bool) -> tuple[float, float, float]:
    """(e, e', e'') of the per-node penalty as a function of the distance d."""
    s = delta - d
    if s <= 0.0:
        return 0.0, 0.0, 0.0
    if not c2:
        return 0.5 * k * s * s, -k * s, k
    if s <= delta:
        return k * s * s * s / (6.0 * delta), -k * s * s / (2.0 * delta), k * s / delta
    r = s - delta
    return (k * delta * delta / 6.0 + 0.5 * k * delta * r + 0.5 * k * r * r,
            -k * (s - 0.5 * delta), k)


@numba.njit(cache=True)
def _psd3(A: np.ndarray) -> np.ndarray:
    """Projection of a symmetric 3 x 3 matrix onto the PSD cone (negative eigenvalues -> 0)."""
    w, V = eigh3(A)
    return (V * np.maximum(w, 0.0)) @ np.ascontiguousarray(V.T)


@numba.njit(cache=True)
def _penalty_kernel(d: np.ndarray, g: np.ndarray, H: np.ndarray, k: float, delta: float, c2: bool,
                    project_psd: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = d.shape[0]
    e = np.empty(n)
    grad = np.empty((n, 3))
    hess = np.empty((n, 3, 3))
    for p in range(n):
        ep, d1, d2 = _penalty_scalar(d[p], k, delta, c2)
        e[p] = ep
        for i in range(3):
            grad[p, i] = d1 * g[p, i]
            for j in range(3):
                hess[p, i, j] = d2 * g[p, i] * g[p, j] + d1 * H[p, i, j]
        if project_psd:
            B = _psd3(hess[p])
            for i in range(3):
                for j in range(3):
                    hess[p, i, j] = B[i, j]
    return e, grad, hess


@numba.njit(cache=True)
def _normal_force_kernel(d: np.ndarray, k: float, delta: float,
                         c2: bool) -> tuple[np.ndarray, np.ndarray]:
    """(-e'(d), -e''(d)): the normal-force magnitudes and their slopes in d."""
    lam = np.empty(d.shape[0])
    slope = np.empty(d.shape[0])
    for p in range(d.shape[0]):
        _, de, dde = _penalty_scalar(d[p], k, delta, c2)
        lam[p] = -de
        slope[p] = -dde
    return lam, slope


def _check(X: npt.ArrayLike, k: float, delta: float, c2: bool) -> np.ndarray:
    X = np.ascontiguousarray(X, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] != 3:
        raise ValueError("X must have shape (n, 3)")
    if k < 0.0 or delta < 0.0 or (c2 and delta <= 0.0):
        raise ValueError("need k >= 0, delta >= 0 (delta > 0 for c2)")
    return X


def penalty_contact(X: npt.ArrayLike, prog: npt.ArrayLike, R: npt.ArrayLike | None,
                    t: npt.ArrayLike | None, k: float, delta: float, *, c2: bool = False,
                    project_psd: bool = False) -> tuple[float, np.ndarray, np.ndarray,
                                                        np.ndarray, np.ndarray]:
    """Penalty energy of nodes X (n, 3) (world) against the tool ``prog`` with pose (R, t).

    Returns E (float), grad (n, 3), hess (n, 3, 3), active (n,) bool (d < delta), gap (n,)
    (the signed distance d of each node to the tool surface). k: stiffness (N/m per node);
    delta: contact offset (m). See the module docstring for the energy and the variants.
    """
    X = _check(X, k, delta, c2)
    R, t = pose(R, t)
    prog = np.asarray(prog, dtype=np.float64)
    n = X.shape[0]
    gap = sdf_world_distance(prog, R, t, X)
    active = gap < delta
    idx = np.flatnonzero(active)
    grad = np.zeros((n, 3))
    hess = np.zeros((n, 3, 3))
    if idx.size == 0:
        return 0.0, grad, hess, active, gap
    d, g, H = sdf_world(prog, R, t, X[idx])
    e, ga, ha = _penalty_kernel(d, g, H, float(k), float(delta), bool(c2), bool(project_psd))
    grad[idx] = ga
    hess[idx] = ha
    return float(e.sum()), grad, hess, active, gap


@numba.njit(cache=True)
def _penalty_energies(d: np.ndarray, k: float, delta: float, c2: bool) -> np.ndarray:
    e = np.empty(d.shape[0])
    for p in range(d.shape[0]):
        e[p] = _penalty_scalar(d[p], k, delta, c2)[0]
    return e


def penalty_energy(X: npt.ArrayLike, prog: npt.ArrayLike, R: npt.ArrayLike | None,
                   t: npt.ArrayLike | None, k: float, delta: float, *, c2: bool = False) -> float:
    """``penalty_contact``'s energy alone (the line search's), from the distances only: the
    same terms summed in the same order, so the same value to the last bit."""
    X = _check(X, k, delta, c2)
    R, t = pose(R, t)
    gap = sdf_world_distance(np.asarray(prog, dtype=np.float64), R, t, X)
    d = gap[gap < delta]
    if d.size == 0:
        return 0.0
    return float(_penalty_energies(d, float(k), float(delta), bool(c2)).sum())


def normal_forces(X: npt.ArrayLike, prog: npt.ArrayLike, R: npt.ArrayLike | None,
                  t: npt.ArrayLike | None, k: float, delta: float, *,
                  c2: bool = False, gradients: bool = False) -> tuple[np.ndarray, ...]:
    """Lagged contact data for friction: (lam_n (n,) >= 0, normals (n, 3)).

    lam_n = -e'(d) is the magnitude of the penalty force on each node (0 outside the layer),
    normals the outward tool normal g at the node (zero where lam_n = 0). With ``gradients``
    also lam_n's gradient (n, 3) with respect to the node's position, -e''(d) g (the tool's
    translation enters d with the opposite sign): what friction's lagged normal force leaves
    out of its Hessian.
    """
    X = _check(X, k, delta, c2)
    R, t = pose(R, t)
    prog = np.asarray(prog, dtype=np.float64)
    gap = sdf_world_distance(prog, R, t, X)
    idx = np.flatnonzero(gap < delta)
    lam = np.zeros(X.shape[0])
    normals = np.zeros((X.shape[0], 3))
    grad = np.zeros((X.shape[0], 3))
    if idx.size:
        d, g, _ = sdf_world(prog, R, t, X[idx])
        lam[idx], slope = _normal_force_kernel(d, float(k), float(delta), bool(c2))
        normals[idx] = g / np.linalg.norm(g, axis=1, keepdims=True)
        grad[idx] = slope[:, None] * g
    return (lam, normals, grad) if gradients else (lam, normals)


def auto_stiffness(E_young: float, thickness: float, area: float, *, pressure: float | None = None,
                   penetration: float = 0.01) -> float:
    """Penalty stiffness k (N/m per node) from the sheet data.

    Rule: a skin node carries the contact pressure p on its tributary area; ``area`` is the
    largest one, A (sim.model takes the largest nodal share of a unit pressure on the skin,
    the consistent load: 4/3 h^2 on a criss-cross grid of spacing h, about 0.87 e^2 inside a
    mesh of equilateral triangles of edge e, a third of the triangle area per edge node and
    none per vertex for quadratic triangles). The node then takes a force F <= p A and its
    spring is compressed by s = F / k; asking s <= alpha t (alpha = ``penetration``, default
    1 % of the sheet thickness t) gives
        k = p A / (alpha t).
    p is the design contact pressure; by default p = 4e-3 E_young, the order of the tensile
    strength of sheet metals (steel 210 GPa -> 840 MPa, aluminium 70 GPa -> 280 MPa), which
    the contact pressure under a punch nose approaches; blank-holder pressures (a few MPa) are
    far below it. Pass ``pressure`` when it is known.
    Penetration: the model uses the C2 law with a contact layer delta = 2 alpha t outside the
    tool (sim.model), whose force beyond the layer is k (s - delta / 2) = k (alpha t - d): the
    linear spring starting alpha t out, smoothed over the layer. The tool surface itself is
    penetrated by -d <= alpha t (p_c / p - 1) at a contact pressure p_c: not at all up to the
    design pressure, by at most alpha t up to twice it (tests/verification/test_contact.py
    measures both).
    Conditioning: the through-thickness stiffness of the sheet under one node is about
    E A / t, so k / (E A / t) = p / (alpha E) = 0.4 with the defaults: the penalty is stiff
    enough to keep penetrations at 1 % of t and still softer than the sheet under it, which
    keeps the Newton system well conditioned. Tighter alpha raises k proportionally.
    """
    if E_young <= 0 or thickness <= 0 or area <= 0 or penetration <= 0:
        raise ValueError("E_young, thickness, area and penetration must be positive")
    p = DESIGN_PRESSURE * E_young if pressure is None else float(pressure)
    return p * area / (penetration * thickness)


# ----------------------------------------------------------------------------------------------
# friction
# ----------------------------------------------------------------------------------------------


@numba.njit(cache=True)
def _friction_kernel(X: np.ndarray, X0: np.ndarray, U_tool: np.ndarray, lam: np.ndarray,
                     N: np.ndarray, mu: float, eps: float) -> tuple[float, np.ndarray, np.ndarray]:
    n = X.shape[0]
    E = 0.0
    grad = np.zeros((n, 3))
    hess = np.zeros((n, 3, 3))
    u = np.empty(3)
    uT = np.empty(3)
    for p in range(n):
        c = mu * lam[p]
        if c == 0.0:
            continue
        for i in range(3):
            u[i] = X[p, i] - X0[p, i] - U_tool[p, i]
        un = u[0] * N[p, 0] + u[1] * N[p, 1] + u[2] * N[p, 2]
        for i in range(3):
            uT[i] = u[i] - un * N[p, i]
        y = math.sqrt(uT[0] * uT[0] + uT[1] * uT[1] + uT[2] * uT[2])
        if y < eps:
            f0 = -y * y * y / (3.0 * eps * eps) + y * y / eps + eps / 3.0
            a = 2.0 / eps - y / (eps * eps)  # f1(y) / y
            b = -1.0 / (eps * eps * y) if y > 0.0 else 0.0  # (f1' y - f1) / y^3
        else:
            f0 = y
            a = 1.0 / y
            b = -1.0 / (y * y * y)
        E += c * f0
        for i in range(3):
            grad[p, i] = c * a * uT[i]
            for j in range(3):
                P = (1.0 if i == j else 0.0) - N[p, i] * N[p, j]
                hess[p, i, j] = c * (a * P + b * uT[i] * uT[j])
    return E, grad, hess


def friction(X: npt.ArrayLike, X_start: npt.ArrayLike, tool_disp: npt.ArrayLike,
             lam_n: npt.ArrayLike, normals: npt.ArrayLike, mu: float,
             eps_v: float) -> tuple[float, np.ndarray, np.ndarray]:
    """Smoothed Coulomb friction potential (IPC) with lagged normal force.

    X, X_start: node positions now and at the start of the step (n, 3); tool_disp (n, 3): the
    displacement of the tool over the step at each node (``tool_displacement``; zeros for a
    tool at rest); lam_n (n,), normals (n, 3): lagged normal-force magnitudes and unit normals
    (``normal_forces`` at the start of the step); mu: Coulomb coefficient; eps_v: slip length
    (m). Returns E, grad (n, 3), hess (n, 3, 3) (exact, PSD; see the module docstring).
    """
    if mu < 0.0 or eps_v <= 0.0:
        raise ValueError("need mu >= 0 and eps_v > 0")
    arrs = [np.ascontiguousarray(a, dtype=np.float64) for a in (X, X_start, tool_disp, normals)]
    lam = np.ascontiguousarray(lam_n, dtype=np.float64)
    n = arrs[0].shape[0]
    if any(a.shape != (n, 3) for a in arrs) or lam.shape != (n,):
        raise ValueError("X, X_start, tool_disp, normals must be (n, 3) and lam_n (n,)")
    return _friction_kernel(arrs[0], arrs[1], arrs[2], lam, arrs[3], float(mu), float(eps_v))


def tool_displacement(X_start: npt.ArrayLike, R0: npt.ArrayLike | None, t0: npt.ArrayLike | None,
                      R1: npt.ArrayLike | None, t1: npt.ArrayLike | None) -> np.ndarray:
    """Displacement (n, 3) over a step of the tool material points at X_start (world).

    The tool moves from pose (R0, t0) to (R1, t1): the point at x maps to
    R1 R0^T (x - t0) + t1, so u_tool = R1 R0^T (x - t0) + t1 - x.
    """
    R0, t0 = pose(R0, t0)
    R1, t1 = pose(R1, t1)
    X = np.asarray(X_start, dtype=np.float64)
    return ((X - t0) @ R0) @ R1.T + t1 - X


def reaction_force(*grads: npt.ArrayLike) -> np.ndarray:
    """Force (3,) the sheet exerts on the tool: sum of the node gradients of the contact terms.

    Contact forces on the nodes are f_i = -grad_i, the tool takes -sum f_i = sum grad_i; pass
    the gradients of every term acting between this tool and the sheet (penalty, friction).
    """
    return np.sum([np.asarray(g, dtype=np.float64).sum(axis=0) for g in grads], axis=0)


def reaction_moment(X: npt.ArrayLike, point: npt.ArrayLike, *grads: npt.ArrayLike) -> np.ndarray:
    """Moment (3,) about ``point`` of the force the sheet exerts on the tool through nodes X."""
    r = np.asarray(X, dtype=np.float64) - np.asarray(point, dtype=np.float64)
    return np.sum([np.cross(r, np.asarray(g, dtype=np.float64)).sum(axis=0) for g in grads],
                  axis=0)

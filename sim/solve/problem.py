"""The problem Newton solves: the sum of energy terms with Dirichlet DoFs held by zeroing their
rows and columns and putting 1 on the diagonal, so the sparsity pattern and its symbolic
factorisation never change; its linear solves (shifted factors, refinement) and the
round-off floor of its state."""

from __future__ import annotations

import ctypes
import functools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from sim.solve.assembly import Pattern, sym_matvec
from sim.solve.linsolve import LinearSolver, SingularMatrix
from sim.terms import Term

# Problem.evaluate's result: energy, its round-off scale, gradient (n, 3), Hessian data (nnz,)
# and the applied forces (largest 2-norm, sum of the resultants' magnitudes)
Evaluation = tuple[float, float, np.ndarray, np.ndarray, tuple[float, float]]


@functools.cache
def keep_freed_memory() -> bool:
    """Have glibc's malloc keep freed memory in the process instead of handing it back to the
    system: every evaluation makes a Hessian data array (28 MB at the paper's cup size) and a
    copy of it, which glibc served from fresh pages of the system (mmap above its threshold,
    or a heap trimmed after each free), which the kernel faults in and zeroes at first touch.
    Measured on this project's 2-core VMs: a 28 MB array zeroed and copied 46 ms on fresh
    pages, 3.5 ms on reused ones. Freed blocks below 1 GiB are then reused, and a heap's free
    top is kept up to 1 GiB. False where the C library has no mallopt (not glibc): nothing
    changes."""
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    m_trim_threshold, m_mmap_threshold = -1, -3  # glibc's malloc.h
    return bool(mallopt(m_trim_threshold, 1 << 30) and mallopt(m_mmap_threshold, 1 << 30))


keep_freed_memory()  # before the model's arrays are made (as OPENBLAS_NUM_THREADS, sim/__init__)


class Problem:
    """The sum of energy terms with Dirichlet DoFs ``fixed (n_nodes, 3) bool``."""

    def __init__(self, terms: list[Term], pattern: Pattern, solver: LinearSolver,
                 fixed: np.ndarray):
        self.terms, self.pattern, self.solver = terms, pattern, solver
        self._unlagged: tuple[np.ndarray, bool, _Sum] | None = None  # see evaluate
        # whether the line search of the last minimisation's first iteration cut its step:
        # Newton then tries the next one's full step on its energy alone first
        # (sim.solve.newton)
        self.first_step_cut = False
        self.set_fixed(fixed)

    def set_fixed(self, fixed: np.ndarray) -> None:
        self.fixed = fixed
        fdof = fixed.ravel()
        rows = np.repeat(np.arange(self.pattern.n_dof), np.diff(self.pattern.indptr))
        self._zero = np.flatnonzero(fdof[rows] | fdof[self.pattern.indices])
        self._diag = self.pattern.indptr[:-1][fdof]  # upper CSR: the diagonal comes first

    def energy(self, x: np.ndarray) -> float:
        total = 0.0
        for t in self.terms:
            total += t.energy(x)
            if not np.isfinite(total):
                return np.inf
        return total

    def barrier_energy(self, x: np.ndarray) -> float:
        """The energy of the barrier terms (contact) alone."""
        return sum((t.energy(x) for t in self.terms if t.barrier), 0.0)

    def step_bound(self, x: np.ndarray, dx: np.ndarray) -> float:
        """The smallest of the terms' step bounds (Term.step_bound) along dx from x."""
        return min((t.step_bound(x, dx) for t in self.terms), default=1.0)

    def lag_change(self, x: np.ndarray, take: bool = False) -> float:
        """The largest relative change of the terms' lagged quantities at x (Term.lag_change);
        ``take``: they become x's."""
        return max((t.lag_change(x, take) for t in self.terms), default=0.0)

    def lag_guessed(self) -> bool:
        """Whether a term's lag is a guess (Term.guessed_lag)."""
        return any(t.guessed_lag for t in self.terms)

    def lag_coupling(self, x: np.ndarray) -> Callable[[np.ndarray], np.ndarray] | None:
        """v -> J v summed over the terms' lag couplings at x (Term.lag_coupling), on flat
        vectors and zero on the held DoFs, or None."""
        parts = [c for t in self.terms if (c := t.lag_coupling(x)) is not None]
        if not parts:
            return None

        def apply(v: np.ndarray) -> np.ndarray:
            out = sum(c(v.reshape(x.shape)) for c in parts)
            out[self.fixed] = 0.0
            return out.ravel()

        return apply

    def gradient(self, x: np.ndarray) -> np.ndarray:
        g = np.zeros_like(x)
        for t in self.terms:
            t.add_gradient(x, g)
        return g

    def hessian(self, x: np.ndarray) -> np.ndarray:
        return self.evaluate(x)[3]

    def gradient_hessian(self, x: np.ndarray, exact: bool = False) -> tuple[np.ndarray, np.ndarray]:
        return self.evaluate(x, exact)[2:4]

    def evaluate(self, x: np.ndarray, exact: bool = False) -> Evaluation:
        """Energy, its round-off scale (sum of the terms' absolute energies), gradient, Hessian
        data with Dirichlet rows/columns replaced by identity, and the applied forces as
        (largest 2-norm, sum of the resultants' magnitudes) of the gradients of the terms other
        than the elastic one (loads, inertia, tools), in one pass over the terms. ``exact`` skips
        the PSD projection of terms that project.

        The terms that lag a quantity (friction) come last, and the sum of the others is kept
        with x, so a refresh of the lag at x (``relagged``) assembles those terms alone."""
        lagging = [t for t in self.terms if t.lags]
        total = _Sum(np.zeros_like(x), np.zeros(self.pattern.nnz))
        for t in self.terms:
            if not t.lags:
                total.add(t, x, exact)
        self._unlagged = (x.copy(), exact, total.copy()) if lagging else None
        return self._finish(total, lagging, x, exact)

    def relagged(self, x: np.ndarray, exact: bool = False) -> Evaluation:
        """``evaluate(x, exact)`` after the lagged quantities changed (Term.lag_change with
        take): only the lagging terms are assembled again when the last evaluation was at x."""
        kept = self._unlagged
        if kept is None or kept[1] != exact or not np.array_equal(kept[0], x):
            return self.evaluate(x, exact)
        return self._finish(kept[2].copy(), [t for t in self.terms if t.lags], x, exact)

    def _finish(self, total: _Sum, lagging: list[Term], x: np.ndarray,
                exact: bool) -> Evaluation:
        for t in lagging:
            total.add(t, x, exact)
        data = total.data
        data[self._zero] = 0.0
        data[self._diag] = 1.0
        E = total.E
        return (E if np.isfinite(E) else np.inf), total.mag, total.g, data, (total.level,
                                                                            total.applied)


@dataclass
class _Sum:
    """The terms' energies, gradients and Hessians summed so far, with the energies' round-off
    scale and the applied forces (Problem.evaluate)."""

    g: np.ndarray
    data: np.ndarray
    E: float = 0.0
    mag: float = 0.0
    level: float = 0.0
    applied: float = 0.0

    def copy(self) -> _Sum:
        return _Sum(self.g.copy(), self.data.copy(), self.E, self.mag, self.level,
                    self.applied)

    def add(self, t: Term, x: np.ndarray, exact: bool) -> None:
        g = self.g
        saved = getattr(t, "project", None)
        if exact and saved is not None:
            t.project = 0
        before = None if t.name == "elasticity" else g.copy()
        try:
            e = t.add_gradient_hessian(x, g, self.data)
        finally:
            if saved is not None:
                t.project = saved
        if before is not None:
            self.level = max(self.level, float(np.linalg.norm(g - before)))
            self.applied += float(np.linalg.norm((g - before).sum(0)))
        self.E += e
        self.mag += abs(e)


def solve_refined(problem: Problem, data: np.ndarray, rhs: np.ndarray, refinements: int = 2,
                  extra: Callable[[np.ndarray], np.ndarray] | None = None
                  ) -> tuple[np.ndarray, float]:
    """Solve K x = rhs with iterative refinement against the unshifted matrix: thin, nearly
    incompressible shells have condition numbers near 1e12 and one solve alone leaves residuals
    that stall Newton well above its tolerance. A refinement that does not lower the residual
    is dropped: with factors shifted to get past a zero-energy mode (a sheet free to turn on a
    frictionless tool) it would amplify the round-off in that mode by 1 / shift. With
    ``extra`` (a flat v -> J v) the system is (K + J) x = rhs, the factors of K its
    preconditioner. Returns the solution and its relative residual |rhs - (K + J) x| / |rhs|."""
    p = problem.pattern

    def residual(x: np.ndarray) -> np.ndarray:
        r = rhs - sym_matvec(p.indptr, p.indices, data, x)
        return r - extra(x) if extra is not None else r

    scale = np.linalg.norm(rhs)
    x = problem.solver.solve(rhs)
    r = residual(x)
    rel = float(np.linalg.norm(r)) / scale if scale > 0 else 0.0
    # 1e-10: well below Newton's rtol, above what refinement can reach at cond ~ 1e12
    for _ in range(refinements):
        if rel <= 1e-10:
            break
        y = x + problem.solver.solve(r)
        ry = residual(y)
        rel_y = float(np.linalg.norm(ry)) / scale
        if not rel_y < rel:
            break
        x, r, rel = y, ry, rel_y
    return x, rel


def solve_krylov(problem: Problem, data: np.ndarray, rhs: np.ndarray, solves: int,
                 extra: Callable[[np.ndarray], np.ndarray] | None = None, tol: float = 1e-10
                 ) -> tuple[np.ndarray, float]:
    """Solve (K + J) x = rhs by GMRES, right-preconditioned by the factors at hand (of K, or of
    an earlier iterate's Hessian), ``solves`` solves at most. Refinement on the same factors
    converges only as fast as the spectral radius of K_f^-1 (K + J) - I is small, and stalled
    at 1e-6 where friction's coupling J was a tenth of K; GMRES minimises the true residual
    over the same solves' span, so it is never worse, and resolves the few directions in
    which J is large. Stops once GMRES's estimate of the relative residual is below ``tol``.
    Returns the solution and its relative residual |rhs - (K + J) x| / |rhs| (recomputed, not
    GMRES's estimate)."""
    p = problem.pattern

    def apply(x: np.ndarray) -> np.ndarray:
        y = sym_matvec(p.indptr, p.indices, data, x)
        return y + extra(x) if extra is not None else y

    beta = float(np.linalg.norm(rhs))
    if beta == 0.0:
        return np.zeros_like(rhs), 0.0
    V, Z = [rhs / beta], []
    H = np.zeros((solves + 1, solves))
    e1 = np.zeros(solves + 1)
    e1[0] = beta
    y = np.zeros(0)
    for j in range(solves):
        Z.append(problem.solver.solve(V[j]))
        w = apply(Z[j])
        for _ in range(2):  # Gram-Schmidt twice: the basis stays orthogonal at cond ~ 1e12
            for i in range(j + 1):
                h = float(V[i] @ w)
                H[i, j] += h
                w -= h * V[i]
        H[j + 1, j] = float(np.linalg.norm(w))
        y = np.linalg.lstsq(H[: j + 2, : j + 1], e1[: j + 2], rcond=None)[0]
        estimate = float(np.linalg.norm(H[: j + 2, : j + 1] @ y - e1[: j + 2])) / beta
        if estimate <= tol or H[j + 1, j] <= 1e-14 * beta:
            break
        V.append(w / H[j + 1, j])
    x = np.asarray(Z).T @ y
    return x, float(np.linalg.norm(rhs - apply(x))) / beta


def factor_shifted(problem: Problem, data: np.ndarray) -> None:
    """Factor, adding a growing multiple of the mean diagonal if a pivot is not positive."""
    shift = 0.0
    mean_diag = np.abs(data[problem.pattern.indptr[:-1]]).mean()
    diag = problem.pattern.indptr[:-1]
    for _ in range(8):
        try:
            trial = data.copy()
            trial[diag] += shift
            problem.solver.factor(trial)
            return
        except SingularMatrix:
            shift = max(1e-10 * mean_diag, 10 * shift)
    raise SingularMatrix(f"Hessian not positive definite even with shift {shift:.3g}")


class Floor:
    """What rounding the state costs, measured at x for d = one unit in the last place of every
    free coordinate, with random signs: ``force`` = |g(x + d) - g(x)| (N) and ``energy`` =
    |E(x + d) - E(x) - g . d| relative to the energy's scale. No iteration can push the residual
    much below what moving x by its own rounding error does, nor see an energy change smaller
    than the energy's jitter. Positions carry eps |X|, not eps |u|, so on thin shells this is
    far above rtol times the load (cantilever h/L = 1e-2: 2.6e-7 N against 1.8e-9 N).

    ``force`` costs a gradient evaluation at x + d and is made when first asked for: the line
    search asks only for ``energy``, near convergence of most steps (the cup's coarse target is
    far above the force floor, so the gradient went unused)."""

    def __init__(self, energy: float, force: Callable[[], float]):
        self.energy = energy
        self._force: float | Callable[[], float] = force

    @property
    def force(self) -> float:
        if callable(self._force):
            self._force = self._force()
        return self._force

    @property
    def force_measured(self) -> float | None:
        """``force`` if it was asked for, else None."""
        return None if callable(self._force) else self._force


EPS = float(np.finfo(float).eps)


# The floor is one sample of a random quantity: the residuals Newton reached after an exact
# step from near the solution measured 0.3-1.2 times it (q3t check), so a residual within twice
# the sample is at the floor.
FLOOR_MARGIN = 2.0


def measure_floor(problem: Problem, x: np.ndarray, E: float, g: np.ndarray,
                  free: np.ndarray, mag: float) -> Floor:
    rng = np.random.default_rng(0)
    d = np.where(free, rng.choice([-1.0, 1.0], x.shape) * np.spacing(np.abs(x)), 0.0)
    y = x + d  # exact: x plus or minus one ulp is the neighbouring double
    de = problem.energy(y) - E - float(np.sum(g * d))
    g = g.copy()  # the force is measured later, against the gradient at x of now

    def force() -> float:
        gy = problem.gradient(y)
        gy[~free] = 0.0
        return float(np.linalg.norm(gy - g))

    # the jitter sample can vanish by chance; 64 eps |E| is a floor under it (measured jitter
    # 1-4 eps |E| on the cantilever)
    return Floor(max(4 * abs(de), 64 * EPS * mag) / mag if mag > 0 else 0.0, force)

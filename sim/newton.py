"""Projected Newton with a backtracking line search on the total energy.

Newton only sums energy terms; Dirichlet DoFs are held by zeroing their rows and columns and
putting 1 on the diagonal, so the sparsity pattern and its symbolic factorisation never change.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from sim.assembly import sym_matvec
from sim.linsolve import SingularMatrix


@dataclass(frozen=True)
class NewtonSettings:
    rtol: float = 1e-8  # residual relative to max(initial residual of the step, load scale)
    atol: float = 0.0  # force round-off floor (N); the model estimates it
    xtol: float = 0.0  # converged when a Newton correction is below this length (m) ...
    xtol_residual: float = 1e-3  # ... and the residual is below this fraction of the reference
    max_iterations: int = 30
    max_line_search: int = 30
    armijo: float = 1e-4
    try_exact: bool = True  # exact Hessian when positive definite, projected otherwise


@dataclass
class Timing:
    assembly: float = 0.0
    factorisation: float = 0.0
    solve: float = 0.0
    line_search: float = 0.0
    iterations: int = 0

    def add(self, other: Timing) -> None:
        for k in ("assembly", "factorisation", "solve", "line_search", "iterations"):
            setattr(self, k, getattr(self, k) + getattr(other, k))


@dataclass
class NewtonResult:
    x: np.ndarray
    converged: bool
    iterations: int
    energy: float
    residuals: list[float] = field(default_factory=list)
    reason: str = ""
    timing: Timing = field(default_factory=Timing)


class Problem:
    """The sum of energy terms with Dirichlet DoFs ``fixed (n_nodes, 3) bool``."""

    def __init__(self, terms, pattern, solver, fixed: np.ndarray):
        self.terms, self.pattern, self.solver = terms, pattern, solver
        self.set_fixed(fixed)

    def set_fixed(self, fixed: np.ndarray) -> None:
        self.fixed = fixed
        fdof = fixed.ravel()
        rows = np.repeat(np.arange(self.pattern.n_dof), np.diff(self.pattern.indptr))
        self._zero = fdof[rows] | fdof[self.pattern.indices]
        self._diag = self.pattern.indptr[:-1][fdof]  # upper CSR: the diagonal comes first

    def energy(self, x: np.ndarray) -> float:
        total = 0.0
        for t in self.terms:
            total += t.energy(x)
            if not np.isfinite(total):
                return np.inf
        return total

    def gradient(self, x: np.ndarray) -> np.ndarray:
        g = np.zeros_like(x)
        for t in self.terms:
            t.add_gradient(x, g)
        return g

    def hessian(self, x: np.ndarray) -> np.ndarray:
        return self.evaluate(x)[3]

    def gradient_hessian(self, x: np.ndarray, exact: bool = False):
        return self.evaluate(x, exact)[2:]

    def evaluate(self, x: np.ndarray, exact: bool = False):
        """Energy, its round-off scale (sum of the terms' absolute energies), gradient and
        Hessian data with Dirichlet rows/columns replaced by identity, in one pass over the
        terms. ``exact`` skips the PSD projection of terms that project."""
        g = np.zeros_like(x)
        data = np.zeros(self.pattern.nnz)
        E = mag = 0.0
        for t in self.terms:
            saved = getattr(t, "project", None)
            if exact and saved is not None:
                t.project = 0
            try:
                e = t.add_gradient_hessian(x, g, data)
            finally:
                if saved is not None:
                    t.project = saved
            E += e
            mag += abs(e)
        data[self._zero] = 0.0
        data[self._diag] = 1.0
        return (E if np.isfinite(E) else np.inf), mag, g, data


def _solve(problem: Problem, data: np.ndarray, rhs: np.ndarray, refinements: int = 2):
    """Solve with iterative refinement against the unshifted matrix: thin, nearly
    incompressible shells have condition numbers near 1e12 and one solve alone leaves residuals
    that stall Newton well above its tolerance."""
    p = problem.pattern
    x = problem.solver.solve(rhs)
    scale = np.linalg.norm(rhs)
    for _ in range(refinements):
        r = rhs - sym_matvec(p.indptr, p.indices, data, x)
        # 1e-10: well below Newton's rtol, above what refinement can reach at cond ~ 1e12
        if np.linalg.norm(r) <= 1e-10 * scale:
            break
        x += problem.solver.solve(r)
    return x


def _factor(problem: Problem, data: np.ndarray) -> None:
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


def minimise(problem: Problem, x0: np.ndarray, settings: NewtonSettings,
             force_scale: float) -> NewtonResult:
    """Minimise the total energy from ``x0`` (Dirichlet DoFs already at their values)."""
    x = x0.copy()
    timing = Timing()
    free = ~problem.fixed
    E = problem.energy(x)
    if not np.isfinite(E):
        return NewtonResult(x0, False, 0, E, [], "inverted element at the start of the step",
                            timing)
    res: list[float] = []
    ref = None
    cached = None  # (E, magnitude, g, data) at x from the line search's full trial step
    for it in range(settings.max_iterations + 1):
        t0 = time.perf_counter()
        # exact Hessian first: where it is positive definite Newton converges quadratically;
        # the projected one is the fallback when the factorisation finds it indefinite
        E, mag, g, data = cached or problem.evaluate(x, exact=settings.try_exact)
        cached = None
        g[~free] = 0.0
        r = float(np.linalg.norm(g))
        if not np.isfinite(r):
            return NewtonResult(x0, False, it, E, res, "non-finite gradient", timing)
        res.append(r)
        ref = max(r, force_scale) if ref is None else ref
        # the round-off floor ends the iteration only after one Newton step: on very thin
        # shells small loads sit below it, and the first step still carries the answer
        if r <= settings.rtol * ref or (it >= 1 and r <= settings.atol):
            timing.assembly += time.perf_counter() - t0
            timing.iterations = it
            return NewtonResult(x, True, it, E, res, "", timing)
        if it == settings.max_iterations:
            break
        t1 = time.perf_counter()
        timing.assembly += t1 - t0
        try:
            if settings.try_exact:
                try:
                    problem.solver.factor(data)
                except SingularMatrix:
                    t_a = time.perf_counter()
                    _, data = problem.gradient_hessian(x)
                    timing.assembly += time.perf_counter() - t_a
                    _factor(problem, data)
            else:
                _factor(problem, data)
        except SingularMatrix as exc:
            return NewtonResult(x0, False, it, E, res, f"singular factorisation: {exc}", timing)
        t2 = time.perf_counter()
        dx = -_solve(problem, data, g.ravel()).reshape(x.shape)
        dx[~free] = 0.0
        t3 = time.perf_counter()
        # at the round-off floor of the residual the correction itself is negligible
        if (np.abs(dx).max() <= settings.xtol and r <= settings.xtol_residual * ref
                and np.isfinite(problem.energy(x + dx))):
            timing.factorisation += t2 - t1
            timing.solve += t3 - t2
            timing.iterations = it + 1
            return NewtonResult(x + dx, True, it + 1, problem.energy(x + dx), res, "", timing)
        timing.factorisation += t2 - t1
        timing.solve += t3 - t2
        slope = float(np.sum(g * dx))
        if slope >= 0:  # not a descent direction (cannot happen with a PD matrix): use -g
            dx, slope = -g, -r * r
        alpha, accepted = 1.0, False
        # measured: energies of bent thin shells carry ~1e-9 relative round-off (stretches from
        # eigenvalues of F^T F); below this the residual is the better merit
        noise = 1e-8 * mag
        for _ in range(settings.max_line_search):
            x_new = x + alpha * dx
            # the full step is usually taken: evaluate everything there at once, so the next
            # iteration reuses it instead of assembling again
            trial = problem.evaluate(x_new, exact=settings.try_exact) if alpha == 1.0 else None
            E_new = trial[0] if trial else problem.energy(x_new)
            if E_new <= E + settings.armijo * alpha * slope:
                accepted = True
                break
            # within the energy's round-off a decrease cannot be seen: the residual decides
            if E_new <= E + noise:
                g_new = trial[2].copy() if trial else problem.gradient(x_new)
                g_new[~free] = 0.0
                if np.linalg.norm(g_new) <= (1 - settings.armijo * alpha) * r:
                    accepted = True
                    break
            alpha *= 0.5
        if accepted and trial is not None:
            cached = trial
        timing.line_search += time.perf_counter() - t3
        if not accepted:
            timing.iterations = it + 1
            return NewtonResult(x, False, it + 1, E, res,
                                f"line search stalled (residual {r:.3e})", timing)
        x = x + alpha * dx
        E = E_new
    timing.iterations = settings.max_iterations
    return NewtonResult(x, False, settings.max_iterations, E, res,
                        f"no convergence in {settings.max_iterations} iterations "
                        f"(residual {res[-1]:.3e}, target {settings.rtol * ref:.3e})", timing)

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
    rtol: float = 1e-8  # residual relative to the step's force level (see minimise)
    # at the round-off floor of the residual, a Newton correction below this length (m) ends
    # the iteration: the state is then as accurate as its floating-point representation
    xtol: float = 0.0
    # the cap; an iteration without real progress (an energy decrease above its noise, or the
    # residual 10 % below all before) for ``patience`` iterations in a row ends sooner
    max_iterations: int = 200
    patience: int = 10
    max_line_search: int = 30
    armijo: float = 1e-4
    try_exact: bool = True  # exact Hessian when positive definite, projected otherwise


@dataclass
class Timing:
    """Seconds in: assembly (every energy + gradient + Hessian evaluation, wherever it runs),
    factorisation, solve, line_search (the energy and gradient evaluations of backtracking and
    of the round-off floor, nothing else)."""

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
    residuals: list[float] = field(default_factory=list)  # at every iterate, the last at x
    reason: str = ""
    timing: Timing = field(default_factory=Timing)
    ref: float = 0.0  # the force level the residual was measured against (N)
    floor: float | None = None  # measured force round-off floor (N), when it was needed


class Problem:
    """The sum of energy terms with Dirichlet DoFs ``fixed (n_nodes, 3) bool``."""

    def __init__(self, terms, pattern, solver, fixed: np.ndarray):
        self.terms, self.pattern, self.solver = terms, pattern, solver
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

    def gradient(self, x: np.ndarray) -> np.ndarray:
        g = np.zeros_like(x)
        for t in self.terms:
            t.add_gradient(x, g)
        return g

    def hessian(self, x: np.ndarray) -> np.ndarray:
        return self.evaluate(x)[3]

    def gradient_hessian(self, x: np.ndarray, exact: bool = False):
        return self.evaluate(x, exact)[2:4]

    def evaluate(self, x: np.ndarray, exact: bool = False):
        """Energy, its round-off scale (sum of the terms' absolute energies), gradient, Hessian
        data with Dirichlet rows/columns replaced by identity, and the applied forces as
        (largest 2-norm, sum of the resultants' magnitudes) of the gradients of the terms other
        than the elastic one (loads, inertia, tools), in one pass over the terms. ``exact`` skips
        the PSD projection of terms that project."""
        g = np.zeros_like(x)
        data = np.zeros(self.pattern.nnz)
        E = mag = level = applied = 0.0
        for t in self.terms:
            saved = getattr(t, "project", None)
            if exact and saved is not None:
                t.project = 0
            before = None if t.name == "elasticity" else g.copy()
            try:
                e = t.add_gradient_hessian(x, g, data)
            finally:
                if saved is not None:
                    t.project = saved
            if before is not None:
                level = max(level, float(np.linalg.norm(g - before)))
                applied += float(np.linalg.norm((g - before).sum(0)))
            E += e
            mag += abs(e)
        data[self._zero] = 0.0
        data[self._diag] = 1.0
        return (E if np.isfinite(E) else np.inf), mag, g, data, (level, applied)


def solve_refined(problem: Problem, data: np.ndarray, rhs: np.ndarray, refinements: int = 2):
    """Solve with iterative refinement against the unshifted matrix: thin, nearly
    incompressible shells have condition numbers near 1e12 and one solve alone leaves residuals
    that stall Newton well above its tolerance. A refinement that does not lower the residual
    is dropped: with factors shifted to get past a zero-energy mode (a sheet free to turn on a
    frictionless tool) it would amplify the round-off in that mode by 1 / shift. Returns the
    solution and its relative residual |rhs - K x| / |rhs|."""
    p = problem.pattern
    scale = np.linalg.norm(rhs)
    x = problem.solver.solve(rhs)
    r = rhs - sym_matvec(p.indptr, p.indices, data, x)
    rel = float(np.linalg.norm(r)) / scale if scale > 0 else 0.0
    # 1e-10: well below Newton's rtol, above what refinement can reach at cond ~ 1e12
    for _ in range(refinements):
        if rel <= 1e-10:
            break
        y = x + problem.solver.solve(r)
        ry = rhs - sym_matvec(p.indptr, p.indices, data, y)
        rel_y = float(np.linalg.norm(ry)) / scale
        if not rel_y < rel:
            break
        x, r, rel = y, ry, rel_y
    return x, rel


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


@dataclass
class Floor:
    """What rounding the state costs, measured at x for d = one unit in the last place of every
    free coordinate, with random signs: ``force`` = |g(x + d) - g(x)| (N) and ``energy`` =
    |E(x + d) - E(x) - g . d| relative to the energy's scale. No iteration can push the residual
    much below what moving x by its own rounding error does, nor see an energy change smaller
    than the energy's jitter. Positions carry eps |X|, not eps |u|, so on thin shells this is
    far above rtol times the load (cantilever h/L = 1e-2: 2.6e-7 N against 1.8e-9 N)."""

    force: float
    energy: float


# The floor is one sample of a random quantity: the residuals Newton reached after an exact
# step from near the solution measured 0.3-1.2 times it (q3t check), so a residual within twice
# the sample is at the floor.
FLOOR_MARGIN = 2.0


def measure_floor(problem: Problem, x: np.ndarray, E: float, g: np.ndarray,
                  free: np.ndarray, mag: float) -> Floor:
    rng = np.random.default_rng(0)
    d = np.where(free, rng.choice([-1.0, 1.0], x.shape) * np.spacing(np.abs(x)), 0.0)
    y = x + d  # exact: x plus or minus one ulp is the neighbouring double
    gy = problem.gradient(y)
    gy[~free] = 0.0
    de = problem.energy(y) - E - float(np.sum(g * d))
    # the jitter sample can vanish by chance; 64 eps |E| is a floor under it (measured jitter
    # 1-4 eps |E| on the cantilever)
    return Floor(float(np.linalg.norm(gy - g)),
                 max(4 * abs(de), 64 * EPS * mag) / mag if mag > 0 else 0.0)


EPS = float(np.finfo(float).eps)


def minimise(problem: Problem, x0: np.ndarray, settings: NewtonSettings,
             force_level: float = 0.0, reactions: bool = False) -> NewtonResult:
    """Minimise the total energy from ``x0`` (Dirichlet DoFs already at their values).

    Converged when the residual (gradient 2-norm on the free DoFs) is below ``rtol`` times the
    step's force level: the largest of ``force_level`` (the caller's: the run's force level so
    far), the applied forces (loads, inertia, tools) and, with ``reactions`` (a prescribed
    motion drives the step), the support reactions, all at the current iterate and never the
    residual of the predicted start. Or when the residual is at its measured round-off floor
    (:class:`Floor`), the Newton correction is Newton's (its solve exact to 1 %) and either
    below ``xtol`` or leaves the residual at the floor, and the residual's resultant still
    balances what is applied: the state is then as accurate as its representation allows."""
    x = x0.copy()
    timing = Timing()
    free = ~problem.fixed
    E = problem.energy(x)
    if not np.isfinite(E):
        return NewtonResult(x0, False, 0, E, [], "inverted element at the start of the step",
                            timing)
    res: list[float] = []
    ref = 0.0
    floor: Floor | None = None
    cap = settings.max_iterations
    idle = 0  # iterations in a row without real progress
    cached = None  # a full evaluation at x from the last iteration, reused as its assembly
    rel, inexact = 0.0, 0  # relative residual of the last linear solve; such in a row
    at_floor = 0  # iterations in a row at the round-off floor

    def result(x, ok, it, E, reason=""):
        timing.iterations = it
        return NewtonResult(x, ok, it, E, res, reason, timing, ref,
                            floor.force if floor else None)

    def get_floor(x, E, g, mag) -> Floor:
        nonlocal floor
        if floor is None:
            t = time.perf_counter()
            floor = measure_floor(problem, x, E, g, free, mag)
            timing.line_search += time.perf_counter() - t
        return floor

    def failure(x, it, E, g, mag, why):
        # a residual target below what rounding x produces: say so, not only how it ended.
        # The load is below the floor only if it is so where the attempt started as well
        # (an iterate far from equilibrium is stiffer, and so is its floor)
        fl = get_floor(x, E, g, mag)
        if ref < fl.force and it > 0:
            t = time.perf_counter()
            E0, g0 = problem.energy(x0), problem.gradient(x0)
            g0[~free] = 0.0
            fl = min(fl, measure_floor(problem, x0, E0, g0, free, abs(E0)),
                     key=lambda f: f.force)
            timing.line_search += time.perf_counter() - t
        if rel > 1e-2 and "numerically singular" not in why:
            why += (f"; Hessian numerically singular (its shifted factors leave {rel:.0%} of "
                    "the residual)")
        if ref < fl.force:
            why = (f"load below force round-off floor (load {ref:.3e} N, floor "
                   f"{fl.force:.3e} N; {why})")
        elif settings.rtol * ref < fl.force:
            why += f"; round-off floor {fl.force:.3e} N above the target"
        return result(x, False, it, E, why)

    def evaluate(y):
        t = time.perf_counter()
        out = problem.evaluate(y, exact=settings.try_exact)
        timing.assembly += time.perf_counter() - t
        return out

    for it in range(cap + 1):
        # exact Hessian first: where it is positive definite Newton converges quadratically;
        # the projected one is the fallback when the factorisation finds it indefinite
        E, mag, g, data, (level, applied) = cached or evaluate(x)
        cached = None
        if not np.isfinite(E):
            return result(x0, False, it, E, "inverted element")
        held = np.where(free, 0.0, g)
        support = float(np.linalg.norm(held)) if reactions else 0.0
        g[~free] = 0.0
        r = float(np.linalg.norm(g))
        if not np.isfinite(r):
            return result(x0, False, it, E, "non-finite gradient")
        res.append(r)
        ref = max(force_level, level, support)
        # the resultants: what the supports carry and what is applied (N); self-balanced
        # reactions (a block sheared between two faces) cancel in it, the force level not
        scale = max(applied + float(np.linalg.norm(held.sum(0))), ref)
        if r <= settings.rtol * ref:
            return result(x, True, it, E)
        # real progress, besides an energy decrease above its noise (the line search's): the
        # residual falling below all before it by a tenth, as in a linear convergence
        stalled = len(res) > 1 and r >= 0.9 * min(res[:-1])
        t1 = time.perf_counter()
        try:
            if settings.try_exact:
                try:
                    problem.solver.factor(data)
                except SingularMatrix:
                    t_a = time.perf_counter()
                    _, data = problem.gradient_hessian(x)
                    t1 += time.perf_counter() - t_a
                    timing.assembly += time.perf_counter() - t_a
                    _factor(problem, data)
            else:
                _factor(problem, data)
        except SingularMatrix as exc:
            return result(x0, False, it, E, f"singular factorisation: {exc}")
        t2 = time.perf_counter()
        timing.factorisation += t2 - t1
        dx, rel = solve_refined(problem, data, g.ravel())
        dx = -dx.reshape(x.shape)
        dx[~free] = 0.0
        timing.solve += time.perf_counter() - t2
        # only a correction that is Newton's (to 1 %) measures how far the state is off; one
        # from factors shifted far from the Hessian (numerically singular) does not. Measured:
        # below 3e-6 in every shipped scene; 0.01-300 where the Hessian's soft stiffness is
        # below its round-off (h/L = 1e-4), where descent along such directions crawls
        newton = rel <= 1e-2
        inexact = 0 if newton else inexact + 1
        if inexact == 5:
            return failure(x, it, E, g, mag, "singular factorisation: Hessian numerically "
                           "singular (5 solves in a row leave over 1 % of the residual, the "
                           f"last {rel:.1e})")
        small = newton and float(np.abs(dx).max()) <= settings.xtol
        # the floor is measured where it can matter: a negligible correction, a residual that
        # stopped falling or has nothing to be measured against; again near it, since it
        # moves with the state (the stresses change the stiffness)
        if (small or stalled or ref == 0.0) if floor is None else r <= 10 * floor.force:
            floor = None
            get_floor(x, E, g, mag)
        trial = evaluate(x + dx)  # the full step is usually taken: the next assembly
        if floor is not None and r <= FLOOR_MARGIN * floor.force:
            # the residual carries no more information than rounding x does: apply the
            # correction and stop if it is negligible or the residual stays at the floor
            g1 = trial[2].copy()
            g1[~free] = 0.0
            r1 = float(np.linalg.norm(g1))
            # the floor is stiff self-balanced pairs (top and bottom of a fibre), which cancel
            # in the resultant: a residual left at the floor must still balance what is
            # applied, or the soft (bending) modes are off. Measured at the floor: 1e-14..3e-6
            # of the applied resultants; 0.8-0.9 where the Hessian's soft stiffness is lost to
            # its round-off (h/L = 1e-4). A Newton correction below xtol needs no such proof:
            # it is the distance to equilibrium, whatever the loads (a tool that grazes the
            # sheet applies less than the floor, and its resultant is all round-off)
            off = float(np.linalg.norm(g1.sum(0))) / scale if scale > 0 else 0.0
            if (np.isfinite(trial[0]) and newton
                    and (small or (r1 <= FLOOR_MARGIN * floor.force and off <= 1e-4))):
                res.append(r1)  # the residual of the state returned
                return result(x + dx, True, it + 1, trial[0])
            # at the floor the residual cannot guide the iteration any more: a few tries
            # (converged states leave it in one or two), then say where it stands
            at_floor += 1
            if at_floor == 5:
                return failure(x, it, E, g, mag, "line search stalled at the round-off floor "
                               f"(5 iterations; residual {r:.3e}, resultant off by {off:.1e} "
                               "of the applied)")
        else:
            at_floor = 0
        if it == cap:
            return failure(x, it, E, g, mag, f"no convergence in {it} iterations (residual "
                           f"{r:.3e}, target {settings.rtol * ref:.3e})")
        if idle == settings.patience:
            return failure(x, it, E, g, mag, f"line search stalled: no progress in {idle} "
                           f"iterations (residual {r:.3e}, target {settings.rtol * ref:.3e})")
        slope = float(np.sum(g * dx))
        if slope >= 0:  # not a descent direction (cannot happen with a PD matrix): use -g
            dx, slope, trial = -g, -r * r, None
        alpha, accepted, by_energy = 1.0, False, False
        for _ in range(settings.max_line_search):
            x_new = x + alpha * dx
            t3 = time.perf_counter()
            if alpha == 1.0 and trial is not None:
                E_new = trial[0]
            else:
                trial = None
                E_new = problem.energy(x_new)
                timing.line_search += time.perf_counter() - t3
            dE = E_new - E
            if not np.isfinite(dE):
                alpha *= 0.5
                continue
            # a decrease the energy's round-off could fake proves nothing: within 1e-6 of its
            # scale (far above any jitter measured, 1e-14) compare with the measured noise
            noise = get_floor(x, E, g, mag).energy * mag if abs(dE) <= 1e-6 * mag else 0.0
            if dE <= settings.armijo * alpha * slope and -dE > noise:
                accepted = by_energy = True
                break
            if abs(dE) <= noise:  # the energy cannot tell: the residual decides
                t3 = time.perf_counter()
                g_new = trial[2].copy() if trial else problem.gradient(x_new)
                g_new[~free] = 0.0
                timing.line_search += time.perf_counter() - t3
                if np.linalg.norm(g_new) <= (1 - settings.armijo * alpha) * r:
                    accepted = True
                    break
            alpha *= 0.5
        if not accepted:
            return failure(x, it + 1, E, g, mag, f"line search stalled (residual {r:.3e})")
        idle = 0 if by_energy or not stalled else idle + 1
        cached = trial
        x = x_new
        E = E_new
    raise AssertionError("unreachable")

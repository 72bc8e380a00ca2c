"""Projected Newton with a backtracking line search on the total energy, and a watchdog.

Newton only sums energy terms (sim.solve.problem). One minimisation's state is a
:class:`Newton`; each iteration takes the Newton direction, exits at the round-off floor when
the residual carries no more information than rounding the state does, or searches along the
direction for a decrease.

The watchdog (Chamberlain, Powell, Lemarechal and Pedersen, "The watchdog technique for forcing
convergence in algorithms for constrained optimization", Math. Programming Study 16, 1982): the
first Newton step of a minimisation is taken whole even when it raises the energy, and the
energy must fall below the sufficient decrease the line search asked of it within
``watchdog`` more full steps, or the iteration returns to where the step was taken and
backtracks from there. A thin sheet bent from flat is why: the linear step moves it normal to
itself, which stretches its mid-surface, so the energy at the full step is far above the
start's while the next Newton step, from that stretched state, lands next to the solution;
backtracking shortens every other step instead and see-saws. Not where a contact term's
energy rises (past its layer Newton's model of the barrier fails), nor at later iterations
(mostly plastic flow the model missed): there the watch came back and cost iterations.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from sim.solve.assembly import sym_matvec
from sim.solve.linsolve import SingularMatrix
from sim.solve.problem import (
    FLOOR_MARGIN,
    Evaluation,
    Floor,
    Problem,
    factor_shifted,
    measure_floor,
    solve_krylov,
    solve_refined,
)

INVERTED_AT_START = "inverted element at the start of the step"
# a Newton step with at most this share of its length off one direction lies along a soft
# valley of the energy (_soft_split); the stretched sheet's wrinkled states put 1e-4 off it
SOFT_SHARE = 1e-2
# an exact Hessian shifted to factor (_factor_shift): its shift within this ratio of the least
# that factors, found by at most this many bisections
SHIFT_BRACKET = 1.2
SHIFT_BISECTIONS = 4
# a correction on a shifted Hessian is tried up to 2^this times longer (_extended)
SHIFT_EXTENSIONS = 10


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
    # full Newton steps allowed after one that raised the energy, before the energy must be
    # below the sufficient decrease asked of that step (0: backtrack at once)
    watchdog: int = 1
    try_exact: bool = True  # exact Hessian when positive definite, projected otherwise
    # with try_exact, what replaces an exact Hessian that does not factor: "project", the
    # terms' PSD projection (shifted if need be); "shift", the exact Hessian itself plus the
    # least multiple of the identity that factors (_factor_shift). Leaving a saddle (a kicked
    # unstable state) the way down is the negative curvature the projection drops: the
    # stretched sheet's descent after a kick crawled for hundreds of projected iterations
    indefinite: str = "project"
    # with try_exact: the projected Hessian while the last residual is above this fraction of
    # the force level (and at a minimisation's start), the exact one below (0: exact
    # throughout). Far from equilibrium the exact Hessian of plastic flow and of contact
    # next to a tool's edge is barely positive definite, and its corrections overshoot
    # (the cup's first step: 18 iterations exact, 11 so)
    exact_below: float = 0.0
    # a lagged quantity (friction's normal force, Term.lag_change) is taken at every iterate
    # whose residual is below ``relag_below`` of the force level (farther out the iterates'
    # normal forces move the energy under the line search, and hard steps crawled), at most
    # ``max_relags`` times per minimisation (then it stays: a lag that keeps changing)
    relag_below: float = 1e-1
    max_relags: int = 50
    # GMRES steps (one solve each) spent on the lag's coupling, or on the last factors against
    # a new Hessian, per correction (newton._solve)
    coupling_solves: int = 10
    # the last factors are tried below this residual (relative to the force level), or within
    # ``reuse_within`` of the target, GMRES making up for the Hessian's change. From 1e-2 at
    # the default rtol a coarse beam's springback stalled at 10x its target: a correction
    # GMRES leaves at 1e-8 of the residual can still be far off in the soft bending modes of
    # a Hessian with a condition number near 1e12, where fresh factors are exact. Within 1e3
    # of a coarse target (the cup's 1e-4) they are Newton's last iterations, and GMRES's
    # correction is only asked what the target needs (``_forcing``)
    reuse_below: float = 1e-5
    reuse_within: float = 1e3
    # an energy decrease counts as progress (``patience``) at an iterate whose exact Hessian
    # was indefinite and replaced by the projected one; False: only the residual's fall
    # does there. Next to an unstable equilibrium the projected corrections go down its
    # negative curvature in short steps, each lowering the energy, without nearing any
    # equilibrium: the stretched sheet's step across a secondary bifurcation spent hundreds
    # of iterations so in attempts that failed at the cap. sim.apps.stability.follow, which
    # retakes such a step in shorter ones, sets it False
    descent_is_progress: bool = True


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
    # (only the energy's was: None)


@dataclass
class Iterate:
    """An iterate and what one evaluation gives of it."""

    x: np.ndarray
    E: float
    mag: float  # the energy's round-off scale (sum of the terms' absolute energies)
    g: np.ndarray  # gradient, zero on the held DoFs
    data: np.ndarray  # Hessian data, identity on the held DoFs
    r: float = 0.0  # residual: the gradient's 2-norm
    # the resultants: what the supports carry and what is applied (N); self-balanced
    # reactions (a block sheared between two faces) cancel in it, the force level not
    scale: float = 0.0


@dataclass
class Watch:
    """A full step taken although it failed the sufficient decrease (the watchdog): where it
    was taken, along what, the energy the iteration must get below, full steps left."""

    origin: Iterate
    dx: np.ndarray
    target: float
    left: int


@dataclass
class Newton:
    """One minimisation's state, carried from iteration to iteration."""

    problem: Problem
    settings: NewtonSettings
    x0: np.ndarray  # the start, returned by an attempt that breaks down
    free: np.ndarray  # (n, 3) bool
    timing: Timing = field(default_factory=Timing)
    res: list[float] = field(default_factory=list)  # the residual at every iterate
    ref: float = 0.0  # the force level the residual is measured against (N)
    floor: Floor | None = None  # measured at (or near) the current iterate
    idle: int = 0  # iterations in a row without real progress
    rel: float = 0.0  # relative residual of the last linear solve
    inexact: int = 0  # such solves in a row leaving over 1 % of the residual
    at_floor: int = 0  # iterations in a row at the round-off floor
    trial: Evaluation | None = None  # the full step's evaluation (Problem.evaluate at x + dx)
    # the last line search cut its step: the next full step's energy is tried before its
    # evaluation (_stop)
    cut: bool = False
    watch: Watch | None = None
    relags: int = 0
    factored: bool = False  # the solver holds factors of this minimisation's Hessians
    matrix: np.ndarray | None = None  # the Hessian data the last correction solved against
    shift: float = 0.0  # the last identity shift that made the exact Hessian factor (N/m)
    shifted: bool = False  # the solver's factors are of a shifted Hessian
    # the last correction's exact Hessian was indefinite, the projected one solved instead
    projected: bool = False

    def result(self, x: np.ndarray, ok: bool, it: int, E: float, reason: str = "") -> NewtonResult:
        self.timing.iterations = it
        return NewtonResult(x, ok, it, E, self.res, reason, self.timing, self.ref,
                            self.floor.force_measured if self.floor else None)

    def evaluate(self, y: np.ndarray) -> Evaluation:
        t = time.perf_counter()
        s = self.settings
        far = s.exact_below > 0 and (not self.res or self.res[-1] > s.exact_below * self.ref)
        out = self.problem.evaluate(y, exact=s.try_exact and not far)
        self.timing.assembly += time.perf_counter() - t
        return out

    def measured_floor(self, cur: Iterate) -> Floor:
        if self.floor is None:
            t = time.perf_counter()
            self.floor = measure_floor(self.problem, cur.x, cur.E, cur.g, self.free, cur.mag)
            self.timing.line_search += time.perf_counter() - t
        return self.floor

    def failure(self, cur: Iterate, it: int, why: str) -> NewtonResult:
        """The failed result, saying whether the residual target is below what rounding x
        produces, not only how it ended. The load is below the floor only if it is so where
        the attempt started as well (an iterate far from equilibrium is stiffer, and so is its
        floor)."""
        fl = self.measured_floor(cur)
        if self.ref < fl.force and it > 0:
            t = time.perf_counter()
            E0, g0 = self.problem.energy(self.x0), self.problem.gradient(self.x0)
            g0[~self.free] = 0.0
            fl = min(fl, measure_floor(self.problem, self.x0, E0, g0, self.free, abs(E0)),
                     key=lambda f: f.force)
            self.timing.line_search += time.perf_counter() - t
        if self.rel > 1e-2 and "numerically singular" not in why:
            why += (f"; Hessian numerically singular (its shifted factors leave {self.rel:.0%} "
                    "of the residual)")
        if self.ref < fl.force:
            why = (f"load below force round-off floor (load {self.ref:.3e} N, floor "
                   f"{fl.force:.3e} N; {why})")
        elif self.settings.rtol * self.ref < fl.force:
            why += f"; round-off floor {fl.force:.3e} N above the target"
        return self.result(cur.x, False, it, cur.E, why)


# told of each iterate as it is reached: (iteration, residual N, the residual it converges
# below N); a minimisation of seconds to minutes shows its progress
Iterated = Callable[[int, float, float], None]


def minimise(problem: Problem, x0: np.ndarray, settings: NewtonSettings,
             force_level: float = 0.0, reactions: bool = False,
             iterated: Iterated | None = None) -> NewtonResult:
    """Minimise the total energy from ``x0`` (Dirichlet DoFs already at their values);
    ``iterated`` is told of each iterate (:data:`Iterated`).

    Converged when the residual (gradient 2-norm on the free DoFs) is below ``rtol`` times the
    step's force level: the largest of ``force_level`` (the caller's: the run's force level so
    far), the applied forces (loads, inertia, tools) and, with ``reactions`` (a prescribed
    motion drives the step), the support reactions, all at the current iterate and never the
    residual of the predicted start. Or when the residual is at its measured round-off floor
    (:class:`Floor`) and its resultant still balances what is applied, reached by a Newton
    correction (its solve exact to 1 %), or with the next correction below ``xtol`` or
    leaving the residual at the floor: the state is then as accurate as its representation
    allows."""
    nt = Newton(problem, settings, x0, ~problem.fixed, cut=problem.first_step_cut)
    x = x0.copy()
    # a full evaluation at x from the last iteration, reused as its assembly; the start's is
    # the first iteration's (an energy alone first cost an evaluation of the sheet per step)
    cached = nt.evaluate(x)
    if not np.isfinite(cached[0]):
        return NewtonResult(x0, False, 0, cached[0], [], INVERTED_AT_START, nt.timing)
    for it in range(settings.max_iterations + 1):
        # exact Hessian first: where it is positive definite Newton converges quadratically;
        # the projected one is the fallback when the factorisation finds it indefinite
        cur, bad = _iterate(nt, x, cached or nt.evaluate(x), force_level, reactions)
        if iterated is not None and not bad:
            iterated(it, cur.r, settings.rtol * nt.ref)
        if nt.watch is not None and _watch_fails(nt, cur, bad, settings.rtol * nt.ref):
            step = _give_up_watch(nt, it)
            if isinstance(step, NewtonResult):
                return step
            x, cached, _ = step
            continue
        if not bad and nt.watch is None:
            cur, bad = _relag(nt, cur, force_level, reactions)
        if bad:
            return nt.result(x0, False, it, cur.E, bad)
        if cur.r <= settings.rtol * nt.ref:
            return nt.result(x, True, it, cur.E)
        # real progress, besides an energy decrease above its noise (the line search's): the
        # residual falling below all before it by a tenth, as in a linear convergence
        stalled = len(nt.res) > 1 and cur.r >= 0.9 * min(nt.res[:-1])
        if _settled_at_floor(nt, cur, stalled):
            return nt.result(x, True, it, cur.E)
        dx = _direction(nt, cur, it)
        if isinstance(dx, NewtonResult):
            return dx
        dx = _off_valley(nt, cur, dx, stalled)
        stop = _stop(nt, cur, it, dx)
        if stop is not None:
            return stop
        if nt.watch is not None:  # watched: the full step, unless its energy is not finite
            if np.isfinite(nt.trial[0]):
                x, cached = cur.x + dx, nt.trial
                continue
            step = _give_up_watch(nt, it)
        else:
            step = _line_search(nt, cur, it, dx, nt.trial)
        if isinstance(step, NewtonResult):
            return step
        x, cached, by_energy = step
        descent = by_energy and (settings.descent_is_progress or not nt.projected)
        nt.idle = 0 if descent or not stalled else nt.idle + 1
    raise AssertionError("unreachable")


def _watch_fails(nt: Newton, cur: Iterate, bad: str, target: float) -> bool:
    """Whether the watched iteration must return to its origin at ``cur``: its energy is not
    below the target yet and no full step is left, or it cannot go on (bad), or it converged
    to a stationary point above the origin's energy. Clears the watch once the energy is
    below its target; counts a full step otherwise."""
    w = nt.watch
    if not bad and cur.E <= w.target:
        nt.watch = None
        return False
    if bad or w.left == 0 or cur.r <= target:
        return True
    w.left -= 1
    return False


def _give_up_watch(nt: Newton,
                   it: int) -> tuple[np.ndarray, Evaluation | None, bool] | NewtonResult:
    """Back to the watch's origin and backtrack from there, the full step known to fail."""
    w, nt.watch = nt.watch, None
    return _line_search(nt, w.origin, it, w.dx, None, alpha=0.5)


def _barrier_rose(problem: Problem, x: np.ndarray, x_new: np.ndarray, dE: float) -> bool:
    """Whether a barrier term (contact) takes more than a thousandth of the energy's rise
    ``dE`` from x to x_new: the watchdog is for the sheet's own energy."""
    return problem.barrier_energy(x_new) - problem.barrier_energy(x) > 1e-3 * abs(dE)


def _iterate(nt: Newton, x: np.ndarray, out: Evaluation, force_level: float,
             reactions: bool) -> tuple[Iterate, str]:
    """The iterate x of an evaluation ``out`` (Problem.evaluate), its residual recorded and
    the force level updated; a reason when it cannot be iterated from."""
    E, mag, g, data, (level, applied) = out
    cur = Iterate(x, E, mag, g, data)
    if not np.isfinite(E):
        return cur, "inverted element"
    held = np.where(nt.free, 0.0, g)
    support = float(np.linalg.norm(held)) if reactions else 0.0
    g[~nt.free] = 0.0
    cur.r = float(np.linalg.norm(g))
    if not np.isfinite(cur.r):
        return cur, "non-finite gradient"
    nt.res.append(cur.r)
    nt.ref = max(force_level, level, support)
    cur.scale = max(applied + float(np.linalg.norm(held.sum(0))), nt.ref)
    return cur, ""


def _relag(nt: Newton, cur: Iterate, force_level: float,
           reactions: bool) -> tuple[Iterate, str]:
    """Refresh what the energy lags (friction's normal force) at every iterate near
    convergence, so the lag follows Newton and its residual is the lag-consistent one: a
    minimisation converges with the lag taken at the state it returns, never in re-solves
    after it. A refresh
    changes the energy, so the iterate is evaluated again (not an iteration; only the
    lagging terms are assembled again, Problem.relagged), and Newton's correction takes the
    lag's coupling (``_solve``). A guessed lag (Term.guessed_lag) is refreshed at every
    iterate after the first correction, near convergence or not. Past ``max_relags`` the lag
    stays, and the minimisation ends on the residual alone."""
    s = nt.settings
    near = cur.r <= s.relag_below * nt.ref or (len(nt.res) > 1 and nt.problem.lag_guessed())
    if (not near or nt.relags == s.max_relags
            or nt.problem.lag_change(cur.x, take=True) == 0.0):
        return cur, ""
    nt.relags += 1
    nt.res.pop()  # the iterate's residual under the old lag
    nt.floor = None  # measured under the old energy
    t = time.perf_counter()
    out = nt.problem.relagged(cur.x, exact=nt.settings.try_exact)
    nt.timing.assembly += time.perf_counter() - t
    return _iterate(nt, cur.x, out, force_level, reactions)


def _direction(nt: Newton, cur: Iterate, it: int) -> np.ndarray | NewtonResult:
    """The Newton correction at ``cur``: the exact Hessian's when it factors, its replacement's
    otherwise (``_factor``); the failed result when nothing factors. Once the
    lag follows the iterates, with its coupling (``_solve``). Close to convergence the
    Hessian barely changes from one iterate to the next: the last factors are tried first
    (``reuse_below``), refined against the new Hessian."""
    timing, data, s = nt.timing, cur.data, nt.settings
    t1 = time.perf_counter()
    near = cur.r <= max(s.reuse_below, s.reuse_within * s.rtol) * nt.ref
    # a shifted Hessian's factors are no preconditioner for an indefinite one's correction
    if nt.factored and near and not nt.shifted:
        dx = _solve(nt, cur, data, stale=True)
        nt.matrix = data
        t = time.perf_counter()
        # a stale attempt that fails is solving too, not factorising: counted so, the
        # factorisation column reads the factorisations' cost alone
        timing.solve += t - t1
        t1 = t
        if dx is not None:
            return dx
    assembled = timing.assembly
    try:
        data = _factor(nt, cur, data)
    except SingularMatrix as exc:
        return nt.result(nt.x0, False, it, cur.E, f"singular factorisation: {exc}")
    nt.factored = True
    nt.matrix = data
    t2 = time.perf_counter()
    # the projected Hessian's assembly (_factor) is counted as assembly
    timing.factorisation += t2 - t1 - (timing.assembly - assembled)
    dx = _solve(nt, cur, data, stale=False)
    timing.solve += time.perf_counter() - t2
    return dx


def _factor(nt: Newton, cur: Iterate, data: np.ndarray) -> np.ndarray:
    """Factor the Hessian ``data``, the exact one if it is positive definite, else its
    replacement (NewtonSettings.indefinite); the data factored."""
    problem, s = nt.problem, nt.settings
    nt.shifted = nt.projected = False
    if not s.try_exact:
        factor_shifted(problem, data)
        return data
    try:
        problem.solver.factor(data)
        return data
    except SingularMatrix:
        shifted = _factor_shift(nt, data) if s.indefinite == "shift" else None
    if shifted is not None:
        return shifted
    nt.projected = True
    t = time.perf_counter()
    _, data = problem.gradient_hessian(cur.x)
    nt.timing.assembly += time.perf_counter() - t
    factor_shifted(problem, data)
    return data


def _factor_shift(nt: Newton, data: np.ndarray) -> np.ndarray | None:
    """The exact Hessian plus mu times the identity on the free DoFs, factored (the data
    returned), mu within ``SHIFT_BRACKET`` above the least that factors, which is the most
    negative eigenvalue's magnitude: up from a quarter of the last mu in this minimisation
    (the Hessian changes little from one iterate to the next), else from 1e-10 of the mean
    diagonal, by fours to the first that factors (None if none does: past the diagonal
    itself) or down by fours to the first that does not, then bisected (geometrically)
    between the two.

    Along the most negative curvature -lambda the correction is a / (mu / lambda - 1) for a
    state a from the saddle along it: mu close to lambda takes the descent a long way down
    the valley in one step (the line search takes back what overshoots), mu four times lambda
    a third of a; a descent then crawled out of the saddle, as the projected Hessian does
    where the compression barely exceeds the critical one (the stretched sheet just past its
    crossing, 234 projected iterations after the kick)."""
    diag = nt.problem.pattern.indptr[:-1][nt.free.ravel()]
    lo, mu = 0.0, nt.shift / 4 if nt.shift else 1e-10 * float(np.abs(data[diag]).mean())
    best, last = None, False
    for _ in range(16 + SHIFT_BISECTIONS):
        trial = data.copy()
        trial[diag] += mu
        try:
            nt.problem.solver.factor(trial)
            best, last = (mu, trial), True
        except SingularMatrix:
            lo, last = mu, False
        if best is None:
            mu *= 4
        elif lo == 0.0:  # the Hessian is indefinite: some smaller shift fails
            mu /= 4
        elif best[0] <= SHIFT_BRACKET * lo:
            break
        else:
            mu = float(np.sqrt(lo * best[0]))
    if best is None:
        return None
    if not last:  # the factors of the last one tried, which did not factor
        nt.problem.solver.factor(best[1])
    nt.shift, nt.shifted = best[0], True
    return best[1]


def _solve(nt: Newton, cur: Iterate, data: np.ndarray, stale: bool) -> np.ndarray | None:
    """The correction from the factors at hand (``stale``: an earlier iterate's), refined
    against the Hessian ``data``, with the lag's coupling (Problem.lag_coupling) once the lag
    follows the iterates: the lagged Hessian H leaves out how friction's normal forces move
    with x, J, and Newton with H alone converges only as fast as J is small against H; (H +
    J) dx = -g is solved by GMRES on H's factors, a solve per step (``coupling_solves``), to
    the accuracy the target needs (``_forcing``). Where that does not converge (the factors
    too old) None for stale factors, the lagged correction for fresh ones."""
    couple = nt.problem.lag_coupling(cur.x) if nt.relags else None
    g = cur.g.ravel()
    if couple is not None or stale:
        # old factors below reuse_below keep 1e-8: there (the default rtol, its target under
        # the round-off floor) looser stale corrections cost a dragged sheet iterations
        s = nt.settings
        eta = 1e-8 if stale and cur.r <= s.reuse_below * nt.ref else _forcing(nt, cur)
        dx, rel = solve_krylov(nt.problem, data, g, nt.settings.coupling_solves, couple, eta)
        if rel <= eta:
            return _held(nt, dx, rel)
        if stale:
            return None
    return _held(nt, *solve_refined(nt.problem, data, g))


def _forcing(nt: Newton, cur: Iterate) -> float:
    """How exactly a GMRES correction solves its system (an inexact Newton forcing term,
    Eisenstat and Walker 1996): what it leaves, eta |g|, is to first order the next residual,
    so eta |g| at a tenth of the target costs no iteration. Never looser than 1e-2 (a
    correction exact to 1 % is Newton's for the round-off floor, ``_stop``) nor tighter than
    1e-8, what every correction was solved to before: far from the target still so. Solving
    to 1e-8 throughout spent about seven solves per correction of the 2 mm cup's friction
    phase and gave the same iterates."""
    s = nt.settings
    return min(1e-2, max(1e-8, 0.1 * s.rtol * nt.ref / cur.r)) if cur.r > 0 else 1e-8


def _held(nt: Newton, dx: np.ndarray, rel: float) -> np.ndarray:
    nt.rel = rel
    dx = -dx.reshape(nt.x0.shape)
    dx[~nt.free] = 0.0
    return dx


def _stop(nt: Newton, cur: Iterate, it: int, dx: np.ndarray) -> NewtonResult | None:
    """The result when the iteration ends at ``cur`` (at the round-off floor, or out of
    iterations or progress), else None with the full step's evaluation in ``nt.trial``."""
    settings = nt.settings
    # only a correction that is Newton's (to 1 %) measures how far the state is off; one
    # from factors shifted far from the Hessian (numerically singular) does not. Measured:
    # below 3e-6 in every shipped scene; 0.01-300 where the Hessian's soft stiffness is
    # below its round-off (h/L = 1e-4), where descent along such directions crawls
    newton = nt.rel <= 1e-2
    nt.inexact = 0 if newton else nt.inexact + 1
    if nt.inexact == 5:
        return nt.failure(cur, it, "singular factorisation: Hessian numerically singular (5 "
                          "solves in a row leave over 1 % of the residual, the last "
                          f"{nt.rel:.1e})")
    small = newton and float(np.abs(dx).max()) <= settings.xtol
    if small:
        nt.measured_floor(cur)
    nt.trial = None if _energy_first(nt, cur) else nt.evaluate(cur.x + dx)
    done = _floor_exit(nt, cur, it, dx, newton, small)
    if done is not None:
        return done
    if it == settings.max_iterations:
        return nt.failure(cur, it, f"no convergence in {it} iterations (residual "
                          f"{cur.r:.3e}, target {settings.rtol * nt.ref:.3e})")
    if nt.idle == settings.patience:
        return nt.failure(cur, it, f"line search stalled: no progress in {nt.idle} "
                          f"iterations (residual {cur.r:.3e}, target "
                          f"{settings.rtol * nt.ref:.3e})")
    return None


def _settled_at_floor(nt: Newton, cur: Iterate, stalled: bool) -> bool:
    """Whether ``cur``, reached by a Newton correction (its solve exact to 1 %), is at the
    round-off floor with its residual balancing what is applied: then no correction can
    improve it, and computing one to confirm cost an iteration per step. The floor is
    measured where it can matter (a residual that stopped falling or has nothing to be
    measured against), and again near it, since it moves with the state (the stresses change
    the stiffness)."""
    if (stalled or nt.ref == 0.0) if nt.floor is None else cur.r <= 10 * nt.floor.force:
        nt.floor = None
        nt.measured_floor(cur)
    return (nt.floor is not None and len(nt.res) > 1 and nt.rel <= 1e-2
            and cur.r <= FLOOR_MARGIN * nt.floor.force and _off_balance(cur, cur.g) <= 1e-4)


def _off_balance(cur: Iterate, g: np.ndarray) -> float:
    """The residual's resultant relative to the applied forces. The floor is stiff
    self-balanced pairs (top and bottom of a fibre), which cancel in the resultant: a
    residual left at the floor must still balance what is applied, or the soft (bending)
    modes are off. Measured at the floor: 1e-14..3e-6 of the applied resultants; 0.8-0.9
    where the Hessian's soft stiffness is lost to its round-off (h/L = 1e-4)."""
    return float(np.linalg.norm(g.sum(0))) / cur.scale if cur.scale > 0 else 0.0


def _energy_first(nt: Newton, cur: Iterate) -> bool:
    """Whether the full step's energy is tried before it is evaluated. The full step is
    usually taken, and its evaluation is the next iterate's assembly; but after a step the
    line search cut (a forming step's first: the predictor carries the sheet on into the
    tools, and Newton's step from there carries nodes next to a tool into it) the next full
    step is likely cut too, its gradient and Hessian wasted. The floor's exit and a watched
    step need the gradient."""
    return nt.cut and nt.watch is None and not _at_floor(nt, cur)


def _at_floor(nt: Newton, cur: Iterate) -> bool:
    return nt.floor is not None and cur.r <= FLOOR_MARGIN * nt.floor.force


def _floor_exit(nt: Newton, cur: Iterate, it: int, dx: np.ndarray, newton: bool,
                small: bool) -> NewtonResult | None:
    """At the round-off floor the residual carries no more information than rounding x does:
    apply the correction and stop if it is negligible or the residual stays at the floor; a
    few tries (converged states leave it in one or two), then say where it stands."""
    if not _at_floor(nt, cur):
        nt.at_floor = 0
        return None
    trial = nt.trial
    g1 = trial[2].copy()
    g1[~nt.free] = 0.0
    r1 = float(np.linalg.norm(g1))
    # a Newton correction below xtol needs no proof of balance: it is the distance to
    # equilibrium, whatever the loads (a tool that grazes the sheet applies less than the
    # floor, and its resultant is all round-off)
    off = _off_balance(cur, g1)
    if (np.isfinite(trial[0]) and newton
            and (small or (r1 <= FLOOR_MARGIN * nt.floor.force and off <= 1e-4))):
        nt.res.append(r1)  # the residual of the state returned
        return nt.result(cur.x + dx, True, it + 1, trial[0])
    nt.at_floor += 1
    if nt.at_floor == 5:
        return nt.failure(cur, it, "line search stalled at the round-off floor (5 "
                          f"iterations; residual {cur.r:.3e}, resultant off by {off:.1e} of "
                          "the applied)")
    return None


def _line_search(nt: Newton, cur: Iterate, it: int, dx: np.ndarray,
                 trial: Evaluation | None,
                 alpha: float = 1.0) -> tuple[np.ndarray, Evaluation | None, bool] | NewtonResult:
    """Backtracking along ``dx`` from the step ``alpha`` (the full step evaluated: ``trial``).
    At a minimisation's first iteration, a full step that fails the sufficient decrease is
    taken and watched (see the module's doc) when its energy is finite and no barrier rose.
    A full step that fails along a soft valley (``_soft_split``) is cut in its soft part
    only, its stiff part kept whole; if no such step is accepted, the whole step is cut.
    Returns the new iterate, its full evaluation when it is the full step and was evaluated
    (else None) and whether the energy decided; or the failed result. Records whether it cut
    Newton's step (``Newton.cut``; at the first iteration for the next minimisation too)."""
    problem, settings, timing = nt.problem, nt.settings, nt.timing
    x, E, g, r, mag = cur.x, cur.E, cur.g, cur.r, cur.mag
    slope = float(np.sum(g * dx))
    newton = slope < 0
    if not newton:  # not a descent direction (cannot happen with a PD matrix): use -g
        dx, slope, trial = -g, -r * r, None

    def taken(x_new: np.ndarray, trial: Evaluation | None, by_energy: bool,
              alpha: float) -> tuple[np.ndarray, Evaluation | None, bool]:
        nt.cut = alpha < 1.0 or not newton
        if it == 0:
            problem.first_step_cut = nt.cut
        return x_new, trial, by_energy

    alpha = min(alpha, problem.step_bound(x, dx))  # a kink ahead (Term.step_bound)
    split = None  # (stiff, soft) parts of dx once its full step failed along a soft valley
    for _ in range(settings.max_line_search):
        step = alpha * dx if split is None else split[0] + alpha * split[1]
        x_new = x + step
        t3 = time.perf_counter()
        if alpha == 1.0 and trial is not None:
            E_new = trial[0]
        else:
            trial = None
            E_new = problem.energy(x_new)
            timing.line_search += time.perf_counter() - t3
        dE = E_new - E
        # the first-order change of the energy
        decrease = alpha * slope if split is None else float(np.sum(g * step))
        # a decrease the energy's round-off could fake proves nothing: within 1e-6 of its
        # scale (far above any jitter measured, 1e-14) compare with the measured noise
        noise = (nt.measured_floor(cur).energy * mag
                 if np.isfinite(dE) and abs(dE) <= 1e-6 * mag else 0.0)
        if np.isfinite(dE) and dE <= settings.armijo * decrease and -dE > noise:
            if nt.shifted and alpha == 1.0 and split is None:
                longer = _extended(nt, x, dx, E_new)
                if longer is not None:
                    return taken(longer, None, True, alpha)
            return taken(x_new, trial, True, alpha)
        if (np.isfinite(dE) and alpha == 1.0 and it == 0 and settings.watchdog > 0 and newton
                and abs(dE) > noise and not _barrier_rose(problem, x, x_new, dE)):
            nt.watch = Watch(cur, dx, E + settings.armijo * slope, settings.watchdog)
            return taken(x_new, trial, True, alpha)
        # the energy cannot tell, the residual decides: a change within its noise, or a step
        # whose predicted decrease (first order) is below that noise, whatever sign the
        # change shows (the beam's release: a full Newton step took the residual from 2e-5 to
        # 1e-8 N, its energy 1.8e-16 J up, its predicted decrease 2.5e-17 J)
        if np.isfinite(dE) and (abs(dE) <= noise or -decrease <= noise):
            t3 = time.perf_counter()
            g_new = trial[2].copy() if trial else problem.gradient(x_new)
            g_new[~nt.free] = 0.0
            timing.line_search += time.perf_counter() - t3
            if np.linalg.norm(g_new) <= (1 - settings.armijo * alpha) * r:
                return taken(x_new, trial, False, alpha)
        if split is None and alpha == 1.0 and newton:
            split = _soft_split(nt, dx)
        alpha *= 0.5
    if split is not None:  # no step along the valley: the whole step cut, as everywhere
        return _line_search(nt, cur, it, dx, None, alpha=0.5)
    return nt.failure(cur, it + 1, f"line search stalled (residual {r:.3e})")


def _extended(nt: Newton, x: np.ndarray, dx: np.ndarray, E: float) -> np.ndarray | None:
    """x + alpha dx for the alpha of 2, 4, ... up to ``SHIFT_EXTENSIONS`` doublings with the
    least energy, as long as the energy falls from one to the next (``E``: at x + dx), for a
    correction on a shifted Hessian (_factor_shift); None if 2 dx does not lower it. The shift
    is the most negative eigenvalue's, and the way down a saddle need not be that mode: a strip
    compressed to eight times its Euler load, kicked along its first mode, has its most
    negative eigenvalue in a higher one, and the correction along the first is a small part
    of its way down. It does not look for kinks ahead (Term.step_bound holds to the full step
    only): the bifurcation tool, which asks for the shift, follows sheets without tools."""
    best = None
    for k in range(1, SHIFT_EXTENSIONS + 1):
        t = time.perf_counter()
        y = x + 2.0**k * dx
        E_new = nt.problem.energy(y)
        nt.timing.line_search += time.perf_counter() - t
        if not E_new < E:
            break
        best, E = y, E_new
    return best


def _off_valley(nt: Newton, cur: Iterate, dx: np.ndarray, stalled: bool) -> np.ndarray:
    """Newton's step ``dx`` without its soft part (``_soft_split``) where the residual along
    the soft direction is a tenth of the target or less: the target does not need the state
    moved along it, and each step along it (a curved valley) lifts the stiff modes' residual
    that the target does need (a wrinkled sheet: an energy-accepted step 10 um along its
    wrinkles' soft mode took the residual from 7e-8 to 6e-6 N, target 1.4e-8, where the
    soft mode's own residual was 4e-12). Asked only once Newton ``stalled`` or was cut: a
    solve more per iteration."""
    split = _soft_split(nt, dx) if stalled or nt.cut else None
    if split is None:
        return dx
    s, t = split
    soft = abs(float(np.sum(cur.g * t))) / float(np.linalg.norm(t))
    return s if soft <= 0.1 * nt.settings.rtol * nt.ref else dx


def _soft_split(nt: Newton, dx: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The Newton step ``dx`` as (s, t), s + t = dx: t along the softest direction of the
    Hessian that ``dx`` holds, s the rest, H-orthogonal to it (the Newton step on the
    stiff modes); None unless t is all of ``dx`` but a ``SOFT_SHARE``.

    A mode far softer than the rest (a wrinkled sheet whose wrinkles can shift or mix at
    almost no cost: 3e-7 N/m against the next 4e-4) takes a residual component far below the
    target to a Newton step of its size over that stiffness, micrometres along a valley that
    curves within them; the full step climbs the valley's wall, the whole step is cut to a
    sixteenth, and the stiff modes, which hold the residual, converge a sixteenth at a time:
    Newton crawled for hundreds of iterations at 1e-6 N with a target of 1e-8. Cutting only
    the soft part keeps the stiff modes' Newton step, and the residual falls as it should.
    The direction is one step of inverse iteration from ``dx`` (the factors at hand), which
    the soft mode already dominates."""
    p, free = nt.problem.pattern, nt.free.ravel()
    d = dx.ravel()
    w = nt.problem.solver.solve(d)
    w[~free] = 0.0
    size = float(np.linalg.norm(w))
    if not (np.isfinite(size) and size > 0.0):
        return None
    v = w / size
    Hv = sym_matvec(p.indptr, p.indices, nt.matrix, v)
    vHv = float(v @ Hv)
    if not vHv > 0.0:
        return None
    t = v * (float(Hv @ d) / vHv)
    s = d - t
    if np.linalg.norm(s) > SOFT_SHARE * np.linalg.norm(d):
        return None
    return s.reshape(dx.shape), t.reshape(dx.shape)

"""Friction's lagged normal force settled within a step: the contact terms (sim.terms.tool_contact)
give energy, gradient and Hessian with the normal forces frozen at the start of a solve; after
a converged solve the stepping refreshes them and solves again until they no longer change."""

from __future__ import annotations

import numpy as np

from sim.solve.newton import NewtonResult, NewtonSettings, Timing, minimise
from sim.solve.problem import Problem
from sim.terms.tool_contact import ToolContact


def settle_friction(problem: Problem, x: np.ndarray, settings: NewtonSettings, force_level: float,
                    timing: Timing, reactions: bool = False, tol: float = 1e-3,
                    max_solves: int = 4) -> tuple[np.ndarray, NewtonResult | None, int, float]:
    """Fixed point of the lagged normal force within a step: friction uses the normal forces
    frozen at the start of the solve (a potential, so Newton applies); after convergence they
    are refreshed from the converged state and the step is solved again from there until they
    change by at most ``tol`` of the largest one (usually once or twice), so a sliding node's
    drag is mu times its own converged normal force. A re-solve that fails keeps the last
    converged state and its lag. Returns the state, the last converged re-solve's
    NewtonResult (None when none ran), the Newton iterations of all re-solves, and how far
    from settled the state is: the largest change of its normal forces from the lagged ones,
    relative to the largest (at most ``tol`` when settled; more after ``max_solves`` re-solves
    or a failed one, which the step record then shows)."""
    tools = [t for t in problem.terms if isinstance(t, ToolContact) and t.mu > 0]
    last, iterations = None, 0
    for _ in range(max_solves):
        saved = [t.lagged for t in tools]
        change = max((t.relag(x) for t in tools), default=0.0)
        if change <= tol:
            return x, last, iterations, change
        res = minimise(problem, x, settings, force_level, reactions)
        timing.add(res.timing)
        iterations += res.iterations
        if not res.converged:
            for t, lag in zip(tools, saved, strict=True):
                t.lagged = lag
            break
        x, last = res.x, res
    return x, last, iterations, max((t.lag_change(x) for t in tools), default=0.0)

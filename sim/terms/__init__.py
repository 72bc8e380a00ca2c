"""Energy terms. Each is (value, gradient, Hessian) of one part of the incremental potential:

    term.energy(x) -> float
    term.add_gradient(x, g)           # g += dE/dx, x and g of shape (n_nodes, 3)
    term.add_hessian(x, data)         # data += d2E/dx2 on the fixed CSR pattern

Newton only sums them. ``begin_step(t, dt, x)`` is called before each step, ``commit(x)`` after
it converged. Terms that need neither inherit the no-ops.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

# how an elastic term's Hessian is made positive semi-definite (sim.model.terms.PROJECTIONS):
# not at all, per quadrature point, or whole per element
PROJECT_NONE, PROJECT_QP, PROJECT_ELEMENT = 0, 1, 2


class Term:
    name = "term"
    # a penalty barrier (contact): Newton's quadratic model of it fails past its thin layer,
    # so a full step that raises its energy is backtracked, never watched (sim.solve.newton)
    barrier = False
    # whether the energy lags a quantity of the state now (see lag_change)
    lags = False
    # the lag was taken from a state no step converged to (a scene's rest placement): a
    # guess, which Newton replaces at every iterate after its first correction
    guessed_lag = False

    def begin_step(self, t: float, dt: float, x: np.ndarray) -> None:
        """Take the step's time, step size and the state at its start."""

    def commit(self, x: np.ndarray) -> None:
        """Accept the converged state of the step (plastic state, velocities)."""

    def lag_change(self, x: np.ndarray, take: bool = False) -> float:
        """A term whose energy lags a quantity of the state (friction its normal force): how
        far that quantity at x is from the lagged one, relative; ``take``: x's becomes the
        lagged one (Newton refreshes it as it converges, sim.solve.newton). 0: no lag."""
        return 0.0

    def lag_coupling(self, x: np.ndarray) -> Callable[[np.ndarray], np.ndarray] | None:
        """v -> J v: the part of the Jacobian of the term's forces at x that the lagged
        quantity's dependence on x adds to its energy's Hessian (None: no lag)."""
        return None

    def step_bound(self, x: np.ndarray, dx: np.ndarray) -> float:
        """The largest fraction of a Newton correction dx from x that the term's quadratic
        model at x holds (a kink ahead, such as a stop, ends it); 1 where it holds the whole
        step. Newton's line search starts from it (sim.solve.newton)."""
        return 1.0

    def energy(self, x: np.ndarray) -> float:
        raise NotImplementedError

    def add_gradient(self, x: np.ndarray, g: np.ndarray) -> None:
        raise NotImplementedError

    def add_hessian(self, x: np.ndarray, data: np.ndarray) -> None:
        """Linear terms have none."""

    def add_gradient_hessian(self, x: np.ndarray, g: np.ndarray, data: np.ndarray) -> float:
        """Both at once, returning the energy; terms whose kernels share the work override
        this."""
        self.add_gradient(x, g)
        self.add_hessian(x, data)
        return self.energy(x)

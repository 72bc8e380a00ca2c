"""Implicit Euler as minimisation (Martin et al. 2011): E = 1/(2 dt^2) (x - x~)^T M (x - x~),
x~ = x_n + dt v_n, with a lumped (HRZ) mass matrix so the Hessian is diagonal and positive."""

from __future__ import annotations

import numpy as np

from sim.geometry.quadrature import Rule
from sim.geometry.shell import Shell
from sim.solve.assembly import Pattern, scatter_node_blocks
from sim.terms import Term


def lumped_mass(shell: Shell, rule: Rule, wdetJ: np.ndarray, density: float) -> np.ndarray:
    """HRZ lumping: diagonal of the consistent mass, rescaled to the element mass. Row sums would
    give negative corner masses for quadratic triangles. Shape (n_nodes,)."""
    N, _ = shell.element.basis(rule.points)  # (n_qp, n_en)
    diag = density * np.einsum("eq,qa->ea", wdetJ, N * N)
    mass_e = density * wdetJ.sum(1)
    diag *= (mass_e / diag.sum(1))[:, None]
    m = np.zeros(shell.n_nodes)
    np.add.at(m, shell.conn, diag)
    return m


class Inertia(Term):
    name = "inertia"

    def __init__(self, mass: np.ndarray, pattern: Pattern, x0: np.ndarray):
        self.m = mass
        self.pattern = pattern
        self.x_n = x0.copy()
        self.v = np.zeros_like(x0)
        self.dt = 1.0
        self.x_pred = x0.copy()
        self._nodes = np.arange(len(mass))

    def begin_step(self, t: float, dt: float, x: np.ndarray) -> None:
        self.dt = dt
        self.x_pred = self.x_n + dt * self.v

    def commit(self, x: np.ndarray) -> None:
        self.v = (x - self.x_n) / self.dt
        self.x_n = x.copy()

    def energy(self, x: np.ndarray) -> float:
        d = x - self.x_pred
        return 0.5 / self.dt**2 * float(np.sum(self.m[:, None] * d * d))

    def add_gradient(self, x: np.ndarray, g: np.ndarray) -> None:
        g += (self.m / self.dt**2)[:, None] * (x - self.x_pred)

    def add_hessian(self, x: np.ndarray, data: np.ndarray) -> None:
        blocks = np.zeros((len(self.m), 3, 3))
        blocks[:, [0, 1, 2], [0, 1, 2]] = (self.m / self.dt**2)[:, None]
        scatter_node_blocks(data, self.pattern.node_slots, self._nodes, blocks)

"""Geometrically linear (small-strain) elasticity, for the classical linear benchmarks.

E(x) = 1/2 u^T K u with u = x - X and K the elastic term's exact Hessian at the rest state:
at F = I the tangent of every law of sim.materials.isotropic is Hooke's C = lam I (x) I +
2 mu I_sym, and the Hessian is sum_q w detJ B^T C B, so E = sum_q w detJ 1/2 eps:C:eps with
eps = sym(grad u). Taking it from the element's own kernel keeps its strain, interpolation and
quadrature (an assumed strain included) exactly as in the finite-strain run, linearised.
"""

from __future__ import annotations

import numpy as np

from sim.terms import PROJECT_NONE, Term
from sim.terms.elasticity import Elasticity


class SmallStrain(Term):
    """1/2 u^T K u; ``rest (n_dof / 3, 3)`` the positions where u = 0 (tool rows included,
    where K is zero)."""

    name = "small_strain_elasticity"

    def __init__(self, elastic: Elasticity, rest: np.ndarray):
        if elastic.plastic or elastic.project != PROJECT_NONE:
            raise ValueError("small strain: needs the elastic term with its exact Hessian")
        self.rest = rest
        self.data = np.zeros(elastic.pattern.nnz)
        elastic.add_hessian(rest[: len(elastic.rest)], self.data)
        self.K = elastic.pattern.matrix(self.data).tocsr()

    def _forces(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        u = (x - self.rest).ravel()
        return u, self.K @ u

    def energy(self, x: np.ndarray) -> float:
        u, Ku = self._forces(x)
        return 0.5 * float(u @ Ku)

    def add_gradient(self, x: np.ndarray, g: np.ndarray) -> None:
        g += self._forces(x)[1].reshape(g.shape)

    def add_hessian(self, x: np.ndarray, data: np.ndarray) -> None:
        data += self.data

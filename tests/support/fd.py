"""Finite-difference checks of an energy's gradient and Hessian."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def fd_check(energy: Callable, gradient: Callable, hessian_matvec: Callable, x: np.ndarray,
             scale: float, rng: np.random.Generator) -> None:
    """Central differences along three random directions drawn from ``rng``. With step h the
    truncation error is O(h^2 |E'''|) and round-off O(eps |E| / h); h = 1e-6 * scale balances
    both to ~1e-7 of the derivative's size, so 1e-5 relative is a safe bound that still
    catches any wrong term."""
    for _ in range(3):
        v = rng.standard_normal(x.shape)
        h = 1e-6 * scale
        fd = (energy(x + h * v) - energy(x - h * v)) / (2 * h)
        an = float(np.sum(gradient(x) * v))
        assert abs(fd - an) <= 1e-5 * max(abs(an), 1e-12), (fd, an)
        fdH = (gradient(x + h * v) - gradient(x - h * v)) / (2 * h)
        Hv = hessian_matvec(x, v)
        assert np.abs(fdH - Hv).max() <= 1e-5 * np.abs(Hv).max(), np.abs(fdH - Hv).max()


def fd_check_term(term, pattern, x: np.ndarray, scale: float,
                  rng: np.random.Generator) -> None:
    """fd_check of an energy term (its energy, add_gradient and add_hessian), the Hessian's
    data laid out on ``pattern``."""

    def gradient(y: np.ndarray) -> np.ndarray:
        g = np.zeros_like(y)
        term.add_gradient(y, g)
        return g

    def hessian_matvec(y: np.ndarray, v: np.ndarray) -> np.ndarray:
        d = np.zeros(pattern.nnz)
        term.add_hessian(y, d)
        return (pattern.matrix(d) @ v.ravel()).reshape(v.shape)

    fd_check(term.energy, gradient, hessian_matvec, x, scale, rng)

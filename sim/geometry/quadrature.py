"""Quadrature rules on the reference triangle, the line [-1, 1] and their tensor-product prisms.

The reference triangle is {(u, v): u >= 0, v >= 0, u + v <= 1} (area 1/2); the prism is that
triangle times w in [-1, 1] (volume 1). Rules are named by their in-plane point count and their
thickness point count, e.g. ``(7, 3)`` for the 21-point rule of the paper's quadratic prism.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Rule:
    """Points ``(n_qp, 3)`` in (u, v, w) and weights ``(n_qp,)`` summing to the prism volume 1."""

    points: np.ndarray
    weights: np.ndarray


def _dunavant6() -> tuple[np.ndarray, np.ndarray]:
    a, b = 0.445948490915965, 0.091576213509771
    wa, wb = 0.223381589678011, 0.109951743655322
    pts = [(a, a), (1 - 2 * a, a), (a, 1 - 2 * a), (b, b), (1 - 2 * b, b), (b, 1 - 2 * b)]
    return np.array(pts), np.array([wa] * 3 + [wb] * 3) / 2


def _radon7() -> tuple[np.ndarray, np.ndarray]:
    # Radon's degree-5 rule, the 7-point rule the paper uses in-plane for quadratic prisms.
    s15 = np.sqrt(15.0)
    a1, a2 = (6 - s15) / 21, (6 + s15) / 21
    w1, w2 = (155 - s15) / 2400, (155 + s15) / 2400
    pts = [(1 / 3, 1 / 3)]
    pts += [(a1, a1), (1 - 2 * a1, a1), (a1, 1 - 2 * a1)]
    pts += [(a2, a2), (1 - 2 * a2, a2), (a2, 1 - 2 * a2)]
    return np.array(pts), np.array([9 / 80] + [w1] * 3 + [w2] * 3)


def _collapsed(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Stroud's conical product (Duffy collapse of Gauss x Gauss-Jacobi); exact to degree 2n-1."""
    x, wx = np.polynomial.legendre.leggauss(n)
    from scipy.special import roots_jacobi

    y, wy = roots_jacobi(n, 1.0, 0.0)  # weight (1 - y) absorbs the collapse Jacobian
    s, ws = (x + 1) / 2, wx / 2
    t, wt = (y + 1) / 2, wy / 4
    u = np.outer(t, np.ones(n)).ravel()
    v = np.outer(1 - t, s).ravel()
    pts = np.column_stack([u, v])
    return pts, np.outer(wt, ws).ravel()


def triangle_rule(n_points: int) -> tuple[np.ndarray, np.ndarray]:
    """In-plane rule with ``n_points`` points: 1, 3, 6, 7 or a square number (collapsed Gauss).

    Returns points ``(n, 2)`` and weights ``(n,)`` summing to 1/2.
    """
    if n_points == 1:
        return np.array([[1 / 3, 1 / 3]]), np.array([0.5])
    if n_points == 3:
        return np.array([[1 / 6, 1 / 6], [2 / 3, 1 / 6], [1 / 6, 2 / 3]]), np.full(3, 1 / 6)
    if n_points == 6:
        return _dunavant6()
    if n_points == 7:
        return _radon7()
    root = int(round(np.sqrt(n_points)))
    if root * root == n_points and root > 1:
        return _collapsed(root)
    raise ValueError(f"no triangle rule with {n_points} points (use 1, 3, 6, 7 or a square)")


def line_rule(n_points: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre on [-1, 1]: points ``(n,)``, weights ``(n,)`` summing to 2."""
    if n_points < 1:
        raise ValueError("a thickness rule needs at least one point")
    return np.polynomial.legendre.leggauss(n_points)


def prism_rule(n_inplane: int, n_thickness: int) -> Rule:
    """Tensor product of a triangle rule and a Gauss line rule."""
    tp, tw = triangle_rule(n_inplane)
    lp, lw = line_rule(n_thickness)
    pts = np.array([(u, v, w) for w in lp for (u, v) in tp])
    wts = np.array([a * b for b in lw for a in tw])
    return Rule(pts, wts)

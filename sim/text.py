"""Numbers in messages as engineers read them: significant digits without an exponent
("100000 mm", not "1e+05 mm"; "0.00012 mm", not "1.2e-04 mm")."""

from __future__ import annotations

import numpy as np


def figure(x: float, digits: int = 3) -> str:
    """``x`` to ``digits`` significant digits, written out in full."""
    return np.format_float_positional(float(f"{x:.{digits}g}"), trim="-")


def mm(metres: float, digits: int = 3) -> str:
    """A length in metres as millimetres, with its unit."""
    return f"{figure(1e3 * metres, digits)} mm"


def plan_extent(points: np.ndarray) -> str:
    """Where points ``(n, 2+)`` (m) lie in x and y: 'x 5 mm to 65 mm, y -65 mm to -5 mm'."""
    lo, hi = points.min(0), points.max(0)
    return f"x {mm(lo[0])} to {mm(hi[0])}, y {mm(lo[1])} to {mm(hi[1])}"

"""The rim of a drawn cup: its height around the punch axis, and the ears in it.

A rolled sheet's anisotropy gives a round cup ears (Hill48: four of them, at 45 degrees to the
rolling direction when r45 > (r0 + r90) / 2, at 0 and 90 degrees when below); a mesh gives a
pattern of its own symmetry (the structured disk blank's is six-fold). The Fourier harmonics of
the height around the axis tell them apart: the four-fold one is the ears, the six-fold the
mesh.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

HARMONICS = 8  # fitted orders 1..8: the ears' 4, a hexagonal mesh's 6, and their neighbours


@dataclass(frozen=True)
class Rim:
    """The rim's heights ``height (m,)`` (m) above the part's lowest point along the punch
    axis, at the angles ``angle (m,)`` (rad, ascending) of the rest edge vertices ``vertices
    (m,)`` about the axis, from the scene's x axis (projected normal to the axis)."""

    vertices: np.ndarray
    angle: np.ndarray
    height: np.ndarray

    def terms(self, k: int, start: float = 0.0) -> tuple[float, float]:
        """The k-fold harmonic a cos(k phi) + b sin(k phi) of the least-squares Fourier fit of
        orders 0..HARMONICS, phi the angle from ``start`` (rad): (a, b), m."""
        cols = [np.ones_like(self.angle)]
        for j in range(1, HARMONICS + 1):
            cols += [np.cos(j * (self.angle - start)), np.sin(j * (self.angle - start))]
        coef = np.linalg.lstsq(np.column_stack(cols), self.height, rcond=None)[0]
        return float(coef[2 * k - 1]), float(coef[2 * k])

    def harmonic(self, k: int) -> tuple[float, float]:
        """Amplitude (m) and the angle (rad, in [0, 2 pi / k)) of the first crest of the k-fold
        harmonic."""
        a, b = self.terms(k)
        return float(np.hypot(a, b)), float(np.arctan2(b, a) % (2 * np.pi) / k)

    @property
    def earing(self) -> float:
        """(h_max - h_min) / h_mean: the ears' height relative to the cup's."""
        return float((self.height.max() - self.height.min()) / self.height.mean())


def angle_about(direction: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Angle (rad, in [0, 2 pi)) of each vector ``p (..., 3)`` about the punch axis along unit
    ``direction``: from the x axis (the y axis for a punch along x), counter-clockwise seen
    against the punch's motion."""
    d = direction
    e1 = np.array([1.0, 0.0, 0.0]) - d[0] * d
    if np.linalg.norm(e1) < 1e-6:  # a punch along x: angles from y
        e1 = np.array([0.0, 1.0, 0.0]) - d[1] * d
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(-d, e1)
    return np.arctan2(p @ e2, p @ e1) % (2 * np.pi)


def rim(rest: np.ndarray, cur: np.ndarray, edge_vertices: np.ndarray, direction: np.ndarray,
        axis_point: np.ndarray) -> Rim:
    """The rim of edge vertices ``edge_vertices`` of the mid-surface, rest ``(n, 3)`` and
    current ``cur (n, 3)``; the punch moves along unit ``direction`` on the axis through
    ``axis_point``. Heights along -direction, from the lowest mid-surface point."""
    d = direction / np.linalg.norm(direction)
    angle = angle_about(d, rest[edge_vertices] - axis_point)
    along = cur @ d
    height = along.max() - along[edge_vertices]
    order = np.argsort(angle)
    return Rim(edge_vertices[order], angle[order], height[order])

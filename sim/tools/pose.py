"""Tool poses: x_world = R x_local + t, so x_local = R^T (x_world - t)."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt


def rotation(axis: npt.ArrayLike, angle: float) -> np.ndarray:
    """Rotation matrix (3, 3) by ``angle`` (rad) about ``axis`` (Rodrigues)."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    K = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


def pose(R: npt.ArrayLike | None, t: npt.ArrayLike | None) -> tuple[np.ndarray, np.ndarray]:
    """The pose as contiguous float64 R (3, 3) and t (3,); None is the identity / zero."""
    R = np.eye(3) if R is None else np.ascontiguousarray(R, dtype=np.float64)
    t = np.zeros(3) if t is None else np.ascontiguousarray(t, dtype=np.float64)
    if R.shape != (3, 3) or t.shape != (3,):
        raise ValueError("pose: R must be (3, 3) and t (3,)")
    return R, t


def transform(X: npt.ArrayLike, R: npt.ArrayLike | None, t: npt.ArrayLike | None) -> np.ndarray:
    """Local -> world: x_world = R x_local + t for points X (n, 3) (applies the tool pose)."""
    R, t = pose(R, t)
    return np.asarray(X, dtype=np.float64) @ R.T + t


def to_local(X: npt.ArrayLike, R: npt.ArrayLike | None, t: npt.ArrayLike | None) -> np.ndarray:
    """World -> local: x_local = R^T (x_world - t) for points X (n, 3) (inverse of transform)."""
    R, t = pose(R, t)
    return (np.asarray(X, dtype=np.float64) - t) @ R


def to_world_derivatives(g: np.ndarray, H: np.ndarray,
                         R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotate local gradients (n, 3) and Hessians (n, 3, 3) to the world: R g, R H R^T."""
    return g @ R.T, np.einsum("ij,njk,lk->nil", R, H, R)


"""Rigid-body modes of a free part and the statically determinate support that holds them.

A released part (springback) keeps only the supports its scene gives it; where those leave
rigid motion free, the equilibrium is defined only up to that motion and the Hessian is
singular in it: Newton then wanders along the mode as far as round-off pushes it, and whether it
converges depends on the last bits of the factorisation. :func:`determinate_support` adds
exactly one held DoF per free mode (a 3-2-1 support for a part held by nothing), so the
problem is regular, and, being determinate, the added supports carry no force once the part is
in equilibrium: the springback shape is the same as with any other such support, up to a
rigid motion.
"""

from __future__ import annotations

import numpy as np

# a mode counts as held when the held DoFs' components of its unit-scaled field sum (squared) to
# at least this: a lever arm of 1e-4 of the part's size on one DoF, far above round-off (1e-16)
# and far below what any real support gives (a fibre's thickness on a symmetry plane: 1e-2)
HELD = 1e-8
# near-equal candidates (a symmetric part has many) are taken in node order, so the choice
# does not follow the last bits of the positions
TIE = 1e-6


def rigid_modes(points: np.ndarray) -> np.ndarray:
    """The six rigid-body velocity fields at ``points (n, 3)``: translations along x, y, z and
    rotations about the axes through the centroid, the rotations divided by the largest
    distance from it so that all six are of order one. Shape: (n, 3, 6)."""
    c = points.mean(0)
    r = points - c
    L = float(np.linalg.norm(r, axis=1).max()) or 1.0
    modes = np.zeros((len(points), 3, 6))
    modes[:, :, :3] = np.eye(3)
    for a in range(3):
        axis = np.eye(3)[a]
        modes[:, :, 3 + a] = np.cross(axis, r) / L
    return modes


def free_modes(modes: np.ndarray, held: np.ndarray) -> np.ndarray:
    """Orthonormal basis (6, k) of the rigid motions that the held DoFs ``held (n, 3) bool``
    leave free (k = 0 when the part is held)."""
    M = modes[held]  # (n_held, 6)
    w, V = np.linalg.eigh(M.T @ M)
    return V[:, w < HELD]


def determinate_support(points: np.ndarray, held: np.ndarray,
                        candidates: np.ndarray) -> list[tuple[int, int]]:
    """(node, component) pairs, one per rigid mode that ``held (n, 3) bool`` leaves free, chosen
    among ``candidates`` (node ids) by pivoted Gram-Schmidt on the modes' values: each pick is
    the DoF that moves most in the free modes not yet held, so the support is as far from
    singular as the part allows (far-apart nodes for rotations)."""
    modes = rigid_modes(points)
    F = free_modes(modes, held)
    if F.shape[1] == 0:
        return []
    rows = (modes[candidates] @ F).reshape(-1, F.shape[1])  # (3 m, k): DoF c of node i
    ids = [(int(i), c) for i in candidates for c in range(3)]
    picked: list[tuple[int, int]] = []
    for _ in range(F.shape[1]):
        norms = np.linalg.norm(rows, axis=1)
        best = int(np.flatnonzero(norms >= (1 - TIE) * norms.max())[0])
        q = rows[best] / norms[best]
        rows = rows - np.outer(rows @ q, q)
        picked.append(ids[best])
    return picked

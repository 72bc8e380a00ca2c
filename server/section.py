"""The viewer's section plane: the part and the tools cut by a plane the user moves, so the sheet
inside the die can be seen. viser draws no clipping planes, so the cut is made here, by the
triangles kept: those whose centroid lies on the far side of the plane (the side away from the
viewer's camera, which looks from -y). The cut edge is as ragged as the mesh is coarse."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

AXES = {"x": 0, "y": 1}  # the plane's normal: a cut across the part, the punch axis in it


def rotation(wxyz: np.ndarray) -> np.ndarray:
    """The rotation matrix (3, 3) of a unit quaternion (w, x, y, z)."""
    w, x, y, z = np.asarray(wxyz, np.float64)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


@dataclass(frozen=True)
class Section:
    """Keep what lies at ``coordinate[axis] >= at`` (m); ``axis`` None: no cut."""

    axis: int | None = None
    at: float = 0.0

    def faces(self, positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """The triangles ``faces (m, 3)`` over ``positions (n, 3)`` left by the cut."""
        if self.axis is None:
            return faces
        centroid = positions[faces, self.axis].mean(1)
        return faces[centroid >= self.at]

    def tool_faces(self, vertices: np.ndarray, faces: np.ndarray, translation: np.ndarray,
                   wxyz: np.ndarray) -> np.ndarray:
        """The triangles of a tool mesh given in its own frame ``vertices (n, 3)``, placed by
        ``translation (3,)`` and rotation ``wxyz (4,)``, left by the cut."""
        if self.axis is None:
            return faces
        world = vertices @ rotation(wxyz).T + np.asarray(translation, np.float64)
        return self.faces(world, faces)

"""What the viewer and the recorder see of a shell: a closed triangle surface (top skin, bottom
skin, rim) over the corner-vertex columns, and per-vertex fields. No solver objects leak out."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from sim.geometry.trimesh import oriented_boundary_edges

if TYPE_CHECKING:
    from sim.geometry.shell import Shell


@dataclass(frozen=True)
class DisplayMesh:
    """faces ``(m, 3)`` over display vertices; ``nodes (2 n_v,)`` maps them to shell nodes
    (top skin first, then bottom skin)."""

    faces: np.ndarray
    nodes: np.ndarray

    @classmethod
    def from_shell(cls, shell: Shell) -> DisplayMesh:
        return cls.from_skins(shell.mesh.faces, shell.skin_nodes(True), shell.skin_nodes(False))

    @classmethod
    def from_skins(cls, F: np.ndarray, top: np.ndarray, bot: np.ndarray) -> DisplayMesh:
        """Of the mid-surface faces ``F (n_f, 3)`` and the top and bottom skin node of each
        mid-surface vertex ``(n_v,)`` (an export reads them from a run's files)."""
        n_v = len(top)
        faces = [F, F[:, ::-1] + n_v]
        # rim: each boundary edge (a, b) in its face's orientation gives a quad top-a, top-b,
        # bottom-b, bottom-a
        be = oriented_boundary_edges(F)
        a, b = be[:, 0], be[:, 1]
        faces += [np.column_stack([a, a + n_v, b]), np.column_stack([b, a + n_v, b + n_v])]
        return cls(np.concatenate(faces).astype(np.int32), np.concatenate([top, bot]))

    def positions(self, x: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(x[self.nodes], dtype=np.float32)

    def per_vertex(self, values: np.ndarray) -> np.ndarray:
        """Repeat a per-mid-surface-vertex field on both skins."""
        return np.concatenate([values, values])


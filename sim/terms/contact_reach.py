"""Which of a contact term's nodes can be in its tool's contact layer: a candidate list kept
between evaluations, and the proof that the nodes left out of it are still out of reach.

A tool's contact term is asked for its energy about fifteen times per Newton iteration (the
assembly, the full step's trial, backtracking, the friction lag's refresh, the round-off
floor), and every skin node's signed distance was computed each time, although most of the
sheet is far from any one tool. ``Reach.near`` returns the nodes that were within
``delta + margin`` of the tool when the list was made, and makes it again from all nodes
whenever a node left out may have come within ``delta``:

The distance is tested in the tool's frame, x_local = R^T (x - t), where the tool stands
still, so its motion (translation, rotation, a force-controlled height) and the node's are one
displacement. A signed distance d is L-Lipschitz in x_local (L = 1: PLANE, BOX, REVOLVE,
SWEEP and RSWEEP are exact distances, and hard or smooth min / max of such keep |g| <= 1,
sim.tools.program), so a node that stood at d_0 > delta when the list was made and has since
moved by |dx_local| < (d_0 - delta) / L is still outside the layer, where its energy,
gradient and Hessian are zero. One node beyond its own bound makes the list again: no node is
ever missed, whatever a Newton correction does. A GRID tool (a triangle mesh's distance
interpolated by splines, trilinear far from the surface) is not an exact distance: L = 2
bounds its interpolation's overshoot (trilinear: |g| <= sqrt 3) with room.
"""

from __future__ import annotations

import numba
import numpy as np

from sim.tools.evaluate import sdf_world_distance
from sim.tools.program import OP_GRID, records


@numba.njit(cache=True)
def moved_out(x: np.ndarray, nodes: np.ndarray, R: np.ndarray, t: np.ndarray,
              ref: np.ndarray, slack: np.ndarray) -> bool:
    """Whether a node p has moved, in the tool frame, by ``slack[p]`` or more from ``ref[p]``.

    x (n_rows, 3) the state; nodes (m,) rows of x; R (3, 3), t (3,) the tool's pose
    (x_local = R^T (x - t)); ref (m, 3) the nodes' local positions when ``slack`` (m,) was
    set (inf: not watched)."""
    for p in range(nodes.shape[0]):
        s = slack[p]
        if s == np.inf:
            continue
        n = nodes[p]
        d2 = 0.0
        for i in range(3):
            loc = (R[0, i] * (x[n, 0] - t[0]) + R[1, i] * (x[n, 1] - t[1])
                   + R[2, i] * (x[n, 2] - t[2]))
            d2 += (loc - ref[p, i]) ** 2
        if d2 >= s * s:
            return True
    return False


def lipschitz(prog: np.ndarray) -> float:
    """A bound on |grad d| of the tool program (module docstring)."""
    return 2.0 if any(op == OP_GRID for op, _ in records(prog)) else 1.0


class Reach:
    """The candidate nodes of one tool: ``near`` gives the indices (into ``nodes``) of those
    that can be within ``delta`` of the tool at a state; ``margin`` (m) is how far beyond the
    layer a node is still listed, so the list is made again only after the sheet or the
    tool has moved by about that much. ``builds`` counts the lists made."""

    def __init__(self, prog: np.ndarray, nodes: np.ndarray, delta: float, margin: float):
        self.prog, self.nodes = prog, nodes
        self.delta, self.margin = float(delta), float(margin)
        self.L = lipschitz(prog)
        self.idx = np.zeros(0, np.int64)
        self.ref = np.zeros((len(nodes), 3))
        self.slack: np.ndarray | None = None
        self.builds = 0

    def near(self, x: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Sorted indices into ``nodes`` of the candidates at state x, tool pose (R, t)."""
        if self.slack is None or moved_out(x, self.nodes, R, t, self.ref, self.slack):
            self._build(x, R, t)
        return self.idx

    def _build(self, x: np.ndarray, R: np.ndarray, t: np.ndarray) -> None:
        X = x[self.nodes]
        d = sdf_world_distance(self.prog, R, t, X)
        far = d > self.delta + self.margin
        self.ref = np.ascontiguousarray((X - t) @ R)  # rows of R^T (x - t)
        self.slack = np.where(far, (d - self.delta) / self.L, np.inf)
        self.idx = np.flatnonzero(~far)
        self.builds += 1

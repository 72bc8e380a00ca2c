"""The SDF program of a scene's tool shape (sim.scene's ShapeSpec): its primitive or CSG of
operands, placed by its offset and rotation. The scene's shape validator runs it, so a shape
the builders refuse (radii that do not fit, a polygon that is not simple) is a scene error."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np

from sim.tools import builders as b
from sim.tools.meshtool import MeshOptions, mesh_program
from sim.tools.pose import rotation

# primitive kind -> its builder, called with the shape's fields
PRIMITIVES = {
    "plane": lambda s: b.plane(s.point, s.normal),
    "box": lambda s: b.rounded_box(s.half_extents, s.radius, s.center),
    "punch": lambda s: b.punch(s.radius, s.height, s.edge_radius),
    "die_ring": lambda s: b.die_ring(s.inner_radius, s.outer_radius, s.height, s.edge_radius),
    "blank_holder": lambda s: b.blank_holder(s.inner_radius, s.outer_radius, s.height,
                                             s.edge_radius),
    "star_die": lambda s: b.star_die(s.n_points, s.r_outer, s.r_inner, s.height, s.edge_radius,
                                     s.corner_radius, phase=s.phase,
                                     valley_radius=s.reflex_radius),
    "star": lambda s: b.star(s.n_points, s.r_outer, s.r_inner, s.height, s.corner_radius,
                             s.edge_radius, s.phase, s.reflex_radius or 0.0),
    "polygon": lambda s: b.extruded_polygon(s.points, 0.0, s.height, s.corner_radius,
                                            s.edge_radius, s.reflex_radius or 0.0),
    "mesh": lambda s: mesh_program(s.path, mesh_options(s)),
}
# kinds whose builder reads a file and may take seconds: the scene checks them apart
# (sim.scene.shapes) and only the model builds them
FILE_KINDS = ("mesh",)


def mesh_options(s: Shape) -> MeshOptions:
    return MeshOptions(s.scale, s.spacing, s.open, s.flip)
CSG = {"union": b.union, "subtract": b.subtract, "intersect": b.intersect}


class Shape(Protocol):
    """A scene's shape as tool_program reads it: sim.scene.shapes' specs, which run
    tool_program in their validator and so cannot be imported here. A CSG kind also has its
    operands in ``shapes``, a primitive the fields its builder reads (PRIMITIVES)."""

    kind: str
    blend: float
    offset: Sequence[float]
    rotation: Sequence[float]


def tool_program(s: Shape) -> np.ndarray:
    """SDF program of a ShapeSpec, CSG operands (folded left) and placements included."""
    if s.kind in CSG:
        progs = [tool_program(c) for c in s.shapes]
        prog = progs[0]
        for other in progs[1:]:
            prog = CSG[s.kind](prog, other, s.blend)
    else:
        prog = PRIMITIVES[s.kind](s)
    if any(s.rotation) or any(s.offset):
        rv = np.asarray(s.rotation, float)
        angle = float(np.linalg.norm(rv))
        R = rotation(rv / angle, angle) if angle > 0 else np.eye(3)
        prog = b.moved(prog, R, s.offset)
    return prog

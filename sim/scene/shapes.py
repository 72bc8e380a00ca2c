"""The tools: ``[[tools]]`` with their shapes (primitives, CSG of operands, placement)."""

from __future__ import annotations

import re
from typing import Annotated, Literal, Self

from pydantic import Field, model_validator

from sim.scene.fields import (
    MAX_FORCE,
    MAX_STIFFNESS,
    Angle,
    Coord,
    Direction,
    Extent,
    Length,
    Point,
    Rotation,
    Speed,
    Strict,
    bounded,
    check_keyframes,
)
from sim.tools import shapes as tool_shapes

PRIMITIVES = tuple(tool_shapes.PRIMITIVES)  # the kinds sim.tools.shapes builds
CSG = tuple(tool_shapes.CSG)
ROLES = ("punch", "die", "blank_holder", "other")
# the roles a tool's name or shape kind implies when it does not declare one (tool_role)
ROLE_WORDS = ((re.compile("punch"), "punch"), (re.compile("holder"), "blank_holder"),
              (re.compile("(?<![a-z])die"), "die"))
ROLE_SHAPES = {"punch": "punch", "die_ring": "die", "star_die": "die",
               "blank_holder": "blank_holder"}


class _Shape(Strict):
    """A tool shape (sim.tools.builders). Lengths in m, in the tool's local frame.

    CSG: kind union / intersect (two or more ``shapes``, folded left) or subtract (exactly
    two: the first minus the second), ``blend`` > 0 a smooth fillet of that width (C2); the
    operands may be CSG of primitives in turn (two levels, which keeps the scene schema
    finite for the web form). Any shape can be placed in its parent's frame by ``offset``
    (m) and ``rotation`` (an axis-angle vector, rad: axis * angle), e.g. a punch lying along
    y: rotation [1.5708, 0, 0]."""

    point: Point = (0.0, 0.0, 0.0)  # plane
    normal: Direction = (0.0, 0.0, 1.0)  # plane
    half_extents: tuple[Length, Length, Length] | None = None  # box
    center: Point = (0.0, 0.0, 0.0)  # box
    radius: Extent = 0.0  # punch radius / box corner radius
    height: Length = 0.05
    edge_radius: Extent = 0.0
    inner_radius: Extent = 0.0  # die opening, holder inner
    outer_radius: Length = 0.1
    n_points: Annotated[int, Field(ge=3, le=32)] = 5  # star
    r_outer: Length = 0.05
    r_inner: Length = 0.03
    corner_radius: Extent = 0.0  # star tips, convex polygon corners
    # star and star_die valleys (star_die default max(corner_radius, edge_radius), star 0),
    # reflex polygon corners
    reflex_radius: Extent | None = None
    phase: Angle = 0.0
    # polygon: a prism 0 <= z <= height over these (x, y) vertices (either orientation)
    points: list[tuple[Coord, Coord]] = []
    blend: Extent = 0.0
    offset: Point = (0.0, 0.0, 0.0)
    rotation: Rotation = (0.0, 0.0, 0.0)

    @model_validator(mode="after")
    def _needs(self) -> Self:
        if self.kind == "box" and self.half_extents is None:
            raise ValueError("a box needs half_extents")
        if self.kind in ("die_ring", "blank_holder") and self.inner_radius >= self.outer_radius:
            raise ValueError("inner_radius must be smaller than outer_radius")
        if self.kind in ("star", "star_die") and self.r_inner >= self.r_outer:
            raise ValueError("r_inner must be smaller than r_outer")
        if self.kind == "polygon" and len(self.points) < 3:
            raise ValueError("a polygon needs at least 3 points")
        shapes = getattr(self, "shapes", [])
        if self.kind in CSG:
            if self.kind == "subtract" and len(shapes) != 2:
                raise ValueError("subtract needs exactly two shapes (the first minus the "
                                 "second)")
            if len(shapes) < 2:
                raise ValueError(f"{self.kind} needs at least two shapes")
        elif shapes:
            raise ValueError(f"shapes: only union, subtract and intersect have operands, "
                             f"not {self.kind!r}")
        if self.kind in PRIMITIVES:  # the builders' own checks (radii fit, polygon simple)
            tool_shapes.tool_program(self)
        return self


class PrimitiveSpec(_Shape):
    """A primitive tool shape (an operand of an operand)."""

    kind: Literal[PRIMITIVES]


class OperandSpec(_Shape):
    """A CSG operand: a primitive or a CSG of primitives."""

    kind: Literal[PRIMITIVES + CSG]
    shapes: list[PrimitiveSpec] = []


class ShapeSpec(_Shape):
    """A tool's shape: a primitive or a CSG of operands (see _Shape)."""

    kind: Literal[PRIMITIVES + CSG]
    shapes: list[OperandSpec] = []


class ToolSpec(Strict):
    """A rigid tool: position at t = 0, velocity in m per unit time (static stepping: over the
    whole run t goes 0 -> 1, so velocity is the stroke), and keyframes of offset and
    rotation."""

    name: str
    shape: ShapeSpec
    position: Point = (0.0, 0.0, 0.0)
    velocity: tuple[Speed, Speed, Speed] = (0.0, 0.0, 0.0)
    friction: Annotated[float, Field(ge=0, le=2)] = 0.0
    # N/m per node; default: sim.terms.contact_kernels.auto_stiffness
    stiffness: bounded(0.0, MAX_STIFFNESS) | None = None
    release: bool = False  # retracted in the release (springback) stage
    # force control: the tool presses along -z with this force (N) and its z is solved with
    # the sheet (a blank holder); velocity must then have no z component
    force: bounded(0.0, MAX_FORCE) | None = None
    # a path: [t, dx, dy, dz] rows, offsets from `position` (m) at scene times t (static: 0-1),
    # or [t, dx, dy, dz, rx, ry, rz] with a rotation vector (axis * angle, rad) about the
    # tool's origin; piecewise linear in between (rotations: exact for a fixed axis), held
    # before the first and after the last; adds to the velocity's motion
    keyframes: list[list[float]] = []
    # force control: the lowest z offset (m, from the start position) the tool can reach, the
    # press's distance blocks; without it a holder falls once the flange has been drawn in
    stop: Coord | None = None
    # what the tool does, for the run summary (punch force, flange); default: from the name
    # (punch*, *holder*, die*), else the shape (punch, die_ring / star_die, blank_holder),
    # else a force-controlled tool is a blank holder; see tool_role
    role: Literal[ROLES] | None = None

    @model_validator(mode="after")
    def _force_axis(self) -> Self:
        if self.force is not None and self.velocity[2] != 0.0:
            raise ValueError("a force-controlled tool moves in z by itself: velocity z must be 0")
        times = [k[0] for k in self.keyframes]
        if any(b <= a for a, b in zip(times, times[1:], strict=False)):
            raise ValueError("keyframes: times must increase")
        lengths = {len(k) for k in self.keyframes}
        if len(lengths) > 1 or not lengths <= {4, 7}:
            raise ValueError("keyframes: rows must all be [t, dx, dy, dz] or all "
                             "[t, dx, dy, dz, rx, ry, rz]")
        check_keyframes(self.keyframes, 4)
        if self.force is not None and any(k[3] != 0.0 for k in self.keyframes):
            raise ValueError("keyframes: a force-controlled tool has no z path")
        if self.force is not None and any(any(k[4:]) for k in self.keyframes):
            raise ValueError("keyframes: a force-controlled tool does not rotate")
        return self




def tool_role(spec: ToolSpec) -> str:
    """The tool's role: its ``role``, else the first of: a word of its name (lower case:
    ``punch`` anywhere, ``holder`` anywhere, ``die`` at the start of a word, so ``die``,
    ``lower_die`` and ``die2`` are dies, ``studied`` is not), its shape's kind, force control
    (a blank holder); else ``other``."""
    if spec.role is not None:
        return spec.role
    name = spec.name.lower()
    for word, role in ROLE_WORDS:
        if word.search(name):
            return role
    if spec.shape.kind in ROLE_SHAPES:
        return ROLE_SHAPES[spec.shape.kind]
    return "blank_holder" if spec.force is not None else "other"

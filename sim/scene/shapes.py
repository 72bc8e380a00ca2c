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
    FileName,
    Length,
    Point,
    Rotation,
    Speed,
    Strict,
    bounded,
    check_keyframes,
    doc,
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
    """A tool shape (sim.tools.builders), in the tool's local frame: a primitive of one
    ``kind`` with its own fields, or a CSG of shapes. Any shape can be placed in its parent's
    frame by ``offset`` and ``rotation`` (an axis-angle vector: axis * angle), e.g. a punch
    lying along y: rotation [1.5708, 0, 0]."""

    kind: str = doc("what shape: a primitive (plane, box, punch, die_ring, blank_holder, "
                    "star, star_die, polygon, mesh) or a CSG (union, subtract, intersect)")
    offset: Point = doc("placement: a shift in the parent's frame", "m", (0.0, 0.0, 0.0))
    rotation: Rotation = doc("placement: a rotation vector (axis * angle) about the "
                             "shape's origin", "rad", (0.0, 0.0, 0.0))

    @model_validator(mode="after")
    def _valid(self) -> Self:
        self.check()
        # the builders' own checks (radii fit, polygon simple); a file is read by the model
        # (sim.model.terms), as the sheet's mesh file is
        if self.kind in PRIMITIVES and self.kind not in tool_shapes.FILE_KINDS:
            tool_shapes.tool_program(self)
        return self

    def check(self) -> None:
        """The kind's own checks, which name its fields (before the builder's)."""


class PlaneShape(_Shape):
    """A half-space: the solid lies below the plane (against ``normal``)."""

    kind: Literal["plane"] = doc("a half-space bounded by a plane")
    point: Point = doc("a point of the plane", "m", (0.0, 0.0, 0.0))
    normal: Direction = doc("the plane's outward normal (any length)", "1", (0.0, 0.0, 1.0))


class BoxShape(_Shape):
    """A box with rounded edges and corners."""

    kind: Literal["box"] = doc("a box")
    half_extents: tuple[Length, Length, Length] = doc("half its sides along x, y, z", "m")
    center: Point = doc("its centre", "m", (0.0, 0.0, 0.0))
    radius: Extent = doc("the radius of its edges and corners", "m", 0.0)


class PunchShape(_Shape):
    """A cylindrical punch along z: its nose (the flat end) at z = 0, its body above."""

    kind: Literal["punch"] = doc("a cylindrical punch, nose at z = 0")
    radius: Extent = doc("the punch radius", "m", 0.0)
    height: Length = doc("its length along z", "m", 0.05)
    edge_radius: Extent = doc("the nose's edge (profile) radius", "m", 0.0)


class _Ring(_Shape):
    inner_radius: Extent = doc("the opening's radius", "m", 0.0)
    outer_radius: Length = doc("the outer radius", "m", 0.1)
    height: Length = doc("its thickness along z", "m", 0.05)
    edge_radius: Extent = doc("the radius of its edge at the opening", "m", 0.0)

    def check(self) -> None:
        if self.inner_radius >= self.outer_radius:
            raise ValueError("inner_radius must be smaller than outer_radius")


class DieRingShape(_Ring):
    """A die: a ring around the z axis, its top face at z = 0, the opening rounded by
    ``edge_radius`` (the die shoulder)."""

    kind: Literal["die_ring"] = doc("a die ring, top face at z = 0")


class BlankHolderShape(_Ring):
    """A blank holder: a ring around the z axis, its bottom face at z = 0."""

    kind: Literal["blank_holder"] = doc("a blank holder ring, bottom face at z = 0")


class _Star(_Shape):
    n_points: Annotated[int, Field(ge=3, le=32)] = doc("the number of tips", "1", 5)
    r_outer: Length = doc("the tips' radius", "m", 0.05)
    r_inner: Length = doc("the valleys' radius", "m", 0.03)
    height: Length = doc("its extent along z", "m", 0.05)
    edge_radius: Extent = doc("the radius of its edge at z = 0", "m", 0.0)
    corner_radius: Extent = doc("the tips' corner radius", "m", 0.0)
    reflex_radius: Extent | None = doc(
        "the valleys' corner radius; unset: star 0, star_die max(corner_radius, edge_radius)",
        "m", None)
    phase: Angle = doc("the rotation of the first tip from the x axis", "rad", 0.0)

    def check(self) -> None:
        if self.r_inner >= self.r_outer:
            raise ValueError("r_inner must be smaller than r_outer")


class StarShape(_Star):
    """A star-shaped punch along z, its nose at z = 0."""

    kind: Literal["star"] = doc("a star-shaped punch")


class StarDieShape(_Star):
    """A die with a star-shaped opening, its top face at z = 0."""

    kind: Literal["star_die"] = doc("a die with a star-shaped opening")


class PolygonShape(_Shape):
    """A prism 0 <= z <= height over a simple polygon."""

    kind: Literal["polygon"] = doc("a prism over a polygon")
    points: list[tuple[Coord, Coord]] = doc(
        "the polygon's (x, y) vertices, either orientation, at least 3", "m")
    height: Length = doc("its extent along z", "m", 0.05)
    corner_radius: Extent = doc("the radius of its convex corners", "m", 0.0)
    reflex_radius: Extent | None = doc("the radius of its reflex corners; unset: 0", "m", None)
    edge_radius: Extent = doc("the radius of its edges at z = 0 and z = height", "m", 0.0)

    def check(self) -> None:
        if len(self.points) < 3:
            raise ValueError("a polygon needs at least 3 points")


class MeshShape(_Shape):
    """A tool surface from a triangle mesh file (STL, OBJ, PLY; CAD's tessellation), in the
    file's coordinates times ``scale``: closed (the tool is inside), or open with a consistent
    orientation (the tool lies behind the faces' normals, or in front with ``flip``). Its
    signed distance is sampled on a grid of ``spacing`` near the surface and smoothed by
    tricubic B-splines (sim.tools.meshtool); a relative path is taken from the scene file's
    folder."""

    kind: Literal["mesh"] = doc("a tool surface from a triangle mesh file")
    path: FileName = doc("the mesh file (STL, OBJ, PLY)")
    scale: Annotated[float, Field(ge=1e-9, le=1e3)] = doc(
        "file units to metres (1e-3 for a file in mm)", "m per file unit", 1.0)
    spacing: Annotated[float, Field(ge=5e-5, le=0.01)] = doc(
        "the grid spacing of the smoothed distance: a fraction of the smallest rounding "
        "radius the tool has (the smoothing follows features larger than a few spacings)",
        "m", 5e-4)
    open: bool = doc("an open surface (not closed): the tool lies behind its faces' normals",
                     default=False)
    flip: bool = doc("an open surface's tool lies in front of its faces' normals",
                     default=False)

    def check(self) -> None:
        if self.flip and not self.open:
            raise ValueError("flip: only for an open surface (a closed one's inside is the tool)")


Primitive = (PlaneShape | BoxShape | PunchShape | DieRingShape | BlankHolderShape | StarShape
             | StarDieShape | PolygonShape | MeshShape)
PrimitiveSpec = Annotated[Primitive, Field(discriminator="kind")]


class _CSG(_Shape):
    """A CSG of shapes: union or intersect (two or more ``shapes``, folded left) or
    subtract (exactly two: the first minus the second); ``blend`` > 0 a smooth fillet of
    that width (C2)."""

    kind: Literal[CSG] = doc("union, subtract (the first minus the second) or intersect")
    blend: Extent = doc("the width of a smooth (C2) fillet where the shapes meet; 0: sharp",
                        "m", 0.0)

    def check(self) -> None:
        if self.kind == "subtract" and len(self.shapes) != 2:
            raise ValueError("subtract needs exactly two shapes (the first minus the second)")
        if len(self.shapes) < 2:
            raise ValueError(f"{self.kind} needs at least two shapes")


class CSGOperand(_CSG):
    """A CSG operand that is itself a CSG, of primitives (two levels keep the scene schema
    finite for the web form)."""

    shapes: list[PrimitiveSpec] = doc("its operands: primitives")


OperandSpec = Annotated[Primitive | CSGOperand, Field(discriminator="kind")]


class CSGShape(_CSG):
    """A tool's shape that is a CSG of operands (primitives or CSGs of primitives)."""

    shapes: list[OperandSpec] = doc("its operands: primitives or CSGs of primitives")


# a tool's shape: a primitive or a CSG, each kind with its own fields only
ShapeSpec = Annotated[Primitive | CSGShape, Field(discriminator="kind")]


class ToolSpec(Strict):
    """A rigid tool: its shape, where it starts and how it moves (velocity, keyframes, or a
    force along -z), its friction."""

    name: str = doc("the tool's name (probes and the run summary refer to it)")
    shape: ShapeSpec = doc("its shape, in its own frame")
    position: Point = doc("where its frame's origin is at t = 0", "m", (0.0, 0.0, 0.0))
    velocity: tuple[Speed, Speed, Speed] = doc(
        "its velocity per unit of scene time: static stepping runs t from 0 to 1, so there it "
        "is the stroke over the run (m); dynamic stepping: m/s", "m/s", (0.0, 0.0, 0.0))
    friction: Annotated[float, Field(ge=0, le=2)] = doc(
        "the Coulomb friction coefficient against the sheet", "1", 0.0)
    stiffness: bounded(0.0, MAX_STIFFNESS) | None = doc(
        "the penalty contact stiffness per node; unset: from the sheet "
        "(sim.terms.contact_kernels.auto_stiffness)", "N/m", None)
    release: bool = doc("retracted in the release (springback) stage", default=False)
    force: bounded(0.0, MAX_FORCE) | None = doc(
        "force control: the tool presses along -z with this force and its z is solved with "
        "the sheet (a blank holder); velocity must then have no z component", "N", None)
    keyframes: list[list[float]] = doc(
        "a path: [t, dx, dy, dz] rows, offsets from position (m) at scene times t (static: "
        "0-1), or [t, dx, dy, dz, rx, ry, rz] with a rotation vector (axis * angle, rad) about "
        "the tool's origin; piecewise linear in between (rotations: exact for a fixed axis), "
        "held before the first and after the last; adds to the velocity's motion",
        "t, m, rad", [])
    stop: Coord | None = doc(
        "force control: the lowest z offset from the start position the tool can reach, the "
        "press's distance blocks; without it a holder falls once the flange has been drawn "
        "in", "m", None)
    role: Literal[ROLES] | None = doc(
        "what the tool does, for the run summary (punch force, flange); unset: from the name "
        "(punch*, *holder*, die*), else the shape (punch, die_ring / star_die, blank_holder), "
        "else a force-controlled tool is a blank holder", default=None)

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

"""Where the sheet is held and loaded: ``[[regions]]``, ``[[bcs]]`` (bends, keyframes) and
``[[loads]]``."""

from __future__ import annotations

from typing import Annotated, Literal, Self

from pydantic import Field, field_validator, model_validator

from sim.scene.fields import (
    MAX_ACCELERATION,
    MAX_FORCE,
    MAX_STRESS,
    Angle,
    Direction,
    Extent,
    Length,
    Point,
    Strict,
    Vec3,
    bounded,
    check_keyframes,
    check_magnitude,
    doc,
)


class BoxSpec(Strict):
    """Nodes whose rest position lies in an axis-aligned box."""

    min: Point = doc("the box's corner of least x, y, z", "m")
    max: Point = doc("its corner of greatest x, y, z", "m")


class PlaneSpec(Strict):
    """Nodes whose rest position lies on a plane."""

    point: Point = doc("a point of the plane", "m")
    normal: Direction = doc("the plane's normal (any length)", "1")
    tolerance: Length = doc("how far from the plane a node may be", "m", 1e-9)


# a box's or ring's bounds reach this fraction of the mesh's extent (its largest side) past
# their values, so that a node placed on a bound by round-off (a rim vertex at r_outer, made
# as r cos t, r sin t) is still selected: by the build (sim.model.dirichlet.region_mask) and
# by the check of a ring when the scene is read (sim.scene.footprint)
REGION_TOLERANCE = 1e-9


class RingSpec(Strict):
    """Nodes whose rest distance from the z axis lies in [r_min, r_max]."""

    r_min: Extent = doc("the ring's inner radius", "m", 0.0)
    # unset: the ring reaches the blank's edge, whatever its size (a cup's rim and flange
    # follow a blank made larger in the form, where a fixed r_max selected nothing)
    r_max: Length | None = doc("its outer radius; unset: every node from r_min out", "m",
                               None)

    @property
    def outer(self) -> float:
        return float("inf") if self.r_max is None else self.r_max


class RegionSpec(Strict):
    """A named set of the sheet's node columns, chosen by exactly one of box, plane or ring
    at their rest positions."""

    name: str = doc("the region's name (BCs, loads and probes refer to it)")
    box: BoxSpec | None = doc("the nodes in a box", default=None)
    plane: PlaneSpec | None = doc("the nodes on a plane", default=None)
    ring: RingSpec | None = doc("the nodes in a ring around the z axis", default=None)
    boundary: bool = doc("only nodes on the mesh boundary", default=False)

    @model_validator(mode="after")
    def _one_shape(self) -> Self:
        if sum(s is not None for s in (self.box, self.plane, self.ring)) != 1:
            raise ValueError("a region needs exactly one of box, plane or ring")
        return self


# the largest rotation (rad) of a bend held without z (BendSpec): a strip bent by a pure end
# moment is then a circle to 0.04 % in radius and 0.15 % in curvature (the quadratic prism, 20
# steps); at 1.2 rad 0.2 % and 0.5 %, at 1.5 rad 2 % and 4 %, and at 2 rad it bends the other
# way, to 180 degrees less the angle, which its layers' x cannot tell apart
WALL_BEND = 1.0


class BendSpec(Strict):
    """Cylindrical bending about y of a strip whose symmetry plane is x = 0: the region (an end
    section at x = length) moves rigidly along the arc of curvature angle / length, rotating by
    ``angle`` (rad) at t = 1; positive angles bend the ends up (+z). Only the BC's components are
    held: ``components = "x"`` holds the x of each node of the section where the rigid motion
    puts it, z free, so the section may slide across the strip (no shear force: a pure end
    moment) and is turned by its layers' x, t sin(angle) apart. That turns it less and less
    firmly towards 90 degrees (it cannot at 90, and 180 degrees less the angle gives the same
    x), so such a bend is refused past ``WALL_BEND`` rad; "xyz" moves it rigidly, at any
    angle."""

    angle: Angle = doc("the end section's rotation at t = 1", "rad")
    length: Length = doc("the distance of the end section from the symmetry plane x = 0", "m")


class BCSpec(Strict):
    """Dirichlet condition on the named components of a region's node columns.

    Its motion over time is one of: ``displacement`` (m) along the default ramp, linear in t
    from 0 to the full value and held after it: over the whole run in static stepping
    (t = 0 -> 1), over ``stepping.load_ramp`` in dynamic stepping, or over 1 s when that is 0
    (a jump would be an infinite velocity); ``keyframes``, rows [t, u_c...] with one
    displacement (m) per named component, in order, at increasing scene times t >= 0,
    piecewise linear in between, held after the last and starting from rest (a first row at
    t = 0 must be zero; one at t > 0 is reached from zero at t = 0); or ``bend``."""

    region: str = doc("the region whose nodes it holds")
    components: Annotated[str, Field(pattern=r"^[xyz]{1,3}$")] = doc(
        "the components held: x, y, z or several (xyz)", default="xyz")
    layers: Literal["all", "bottom", "mid", "top"] = doc(
        "which nodes of each column through the thickness", default="all")
    displacement: Point = doc("the displacement at the end of its ramp", "m", (0.0, 0.0, 0.0))
    keyframes: list[list[float]] = doc(
        "rows [t, u...]: one displacement per named component at scene time t", "t, m", [])
    bend: BendSpec | None = doc("a cylindrical bend of the region (an end section)",
                                default=None)
    release: bool = doc("removed in the release (springback) stage", default=False)
    release_only: bool = doc(
        "only in the release stage, holding the nodes where they are (a support for the free "
        "part)", default=False)

    @model_validator(mode="after")
    def _motion(self) -> Self:
        if len(set(self.components)) != len(self.components):
            raise ValueError(f"components: {self.components!r} names a component twice")
        if self.bend is not None and "z" not in self.components \
                and abs(self.bend.angle) > WALL_BEND:
            raise ValueError(
                f"bend.angle: {self.bend.angle:g} rad held in {self.components!r} alone turns "
                f"the section by its layers' x only, which fixes it less and less towards 90 "
                f"degrees (and not at all at 90, or against 180 degrees less the angle): at "
                f"most {WALL_BEND:g} rad so; hold 'xyz' (a rigid end) for larger bends")
        if not self.keyframes:
            return self
        if self.bend is not None or any(self.displacement):
            raise ValueError("keyframes: give either keyframes or displacement / bend")
        n = 1 + len(self.components)
        for i, row in enumerate(self.keyframes):
            if len(row) != n:
                raise ValueError(f"keyframes.{i}: needs [t, {', '.join(self.components)}] "
                                 f"({n} numbers) for components {self.components!r}, "
                                 f"got {len(row)}")
        check_keyframes(self.keyframes, n)
        times = [r[0] for r in self.keyframes]
        if times[0] < 0:
            raise ValueError("keyframes: times must be >= 0")
        if any(b <= a for a, b in zip(times, times[1:], strict=False)):
            raise ValueError("keyframes: times must increase")
        if times[0] == 0 and any(self.keyframes[0][1:]):
            raise ValueError("keyframes: the motion starts from rest (zero at t = 0)")
        return self


class _Load(Strict):
    """An external load of one ``kind``, ramped by the stepping (static: over the run;
    dynamic: over ``stepping.load_ramp``) and scaled by the live load_scale."""

    kind: str = doc("what load: gravity, traction, pressure, surface or point")


class GravityLoad(_Load):
    """A body force: the density times this acceleration on all of the sheet."""

    kind: Literal["gravity"] = doc("a body force, density times an acceleration")
    vector: Vec3 = doc("the acceleration", "m/s^2")

    @field_validator("vector")
    @classmethod
    def _magnitude(cls, v: Vec3) -> Vec3:
        check_magnitude(v, MAX_ACCELERATION, "m/s^2")
        return v


class TractionLoad(_Load):
    """A force per rest area on the rim faces of a region's boundary edges (a dead load)."""

    kind: Literal["traction"] = doc("a force per area on a region's rim faces")
    vector: Vec3 = doc("the traction (force per reference area)", "Pa")
    region: str = doc("the region it acts on")

    @field_validator("vector")
    @classmethod
    def _magnitude(cls, v: Vec3) -> Vec3:
        check_magnitude(v, MAX_STRESS, "Pa")
        return v


class PressureLoad(_Load):
    """A pressure on a skin along its rest inward normal (a dead load)."""

    kind: Literal["pressure"] = doc("a pressure normal to a skin")
    value: bounded(-MAX_STRESS, MAX_STRESS, lo_open=False) = doc(
        "the pressure; positive pushes on the skin, into the sheet", "Pa")
    region: str | None = doc("the region it acts on; unset: the whole skin", default=None)
    skin: Literal["top", "bottom"] = doc("the skin it acts on", default="top")


class SurfaceLoad(_Load):
    """A force per rest area of the mid-surface, of fixed direction (a dead load: a roof's
    weight given per area, snow), on a region's elements or the whole sheet."""

    kind: Literal["surface"] = doc("a force per area of the mid-surface, fixed direction")
    vector: Vec3 = doc("the force per rest mid-surface area", "Pa")
    region: str | None = doc("the region it acts on (elements whose corners all lie in it); "
                             "unset: the whole sheet", default=None)

    @field_validator("vector")
    @classmethod
    def _magnitude(cls, v: Vec3) -> Vec3:
        check_magnitude(v, MAX_STRESS, "Pa")
        return v


class PointLoad(_Load):
    """A force on the mid-surface vertex nearest to a point."""

    kind: Literal["point"] = doc("a force at one vertex")
    vector: Vec3 = doc("the force", "N")
    point: Point = doc("where: the nearest mid-surface vertex takes it", "m")

    @field_validator("vector")
    @classmethod
    def _magnitude(cls, v: Vec3) -> Vec3:
        check_magnitude(v, MAX_FORCE, "N")
        return v


# a load of one kind, with that kind's fields only
LoadSpec = Annotated[GravityLoad | TractionLoad | PressureLoad | SurfaceLoad | PointLoad,
                     Field(discriminator="kind")]

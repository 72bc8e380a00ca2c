"""Where the sheet is held and loaded: ``[[regions]]``, ``[[bcs]]`` (bends, keyframes) and
``[[loads]]``."""

from __future__ import annotations

from typing import Annotated, ClassVar, Literal

from pydantic import Field, ValidationInfo, field_validator, model_validator

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
)


class BoxSpec(Strict):
    min: Point
    max: Point


class PlaneSpec(Strict):
    point: Point
    normal: Direction
    tolerance: Length = 1e-9


class RingSpec(Strict):
    """Nodes whose rest distance from the z axis lies in [r_min, r_max]."""

    r_min: Extent = 0.0
    r_max: Length


class RegionSpec(Strict):
    name: str
    box: BoxSpec | None = None
    plane: PlaneSpec | None = None
    ring: RingSpec | None = None
    boundary: bool = False  # only nodes on the mesh boundary

    @model_validator(mode="after")
    def _one_shape(self):
        if sum(s is not None for s in (self.box, self.plane, self.ring)) != 1:
            raise ValueError("a region needs exactly one of box, plane or ring")
        return self


class BendSpec(Strict):
    """Cylindrical bending about y of a strip whose symmetry plane is x = 0: the region (an end
    section at x = length) moves rigidly along the arc of curvature angle / length, rotating by
    ``angle`` (rad) at t = 1; positive angles bend the ends up (+z). Only the BC's components are
    held: ``components = "x"`` turns the section like a rotated wall that it may slide along
    (no shear force: a pure end moment), "xyz" moves it rigidly."""

    angle: Angle
    length: Length


class BCSpec(Strict):
    """Dirichlet condition on the named components of a region's node columns.

    Its motion over time is one of: ``displacement`` (m) along the default ramp, linear in t
    from 0 to the full value and held after it: over the whole run in static stepping
    (t = 0 -> 1), over ``stepping.load_ramp`` in dynamic stepping, or over 1 s when that is 0
    (a jump would be an infinite velocity); ``keyframes``, rows [t, u_c...] with one
    displacement (m) per named component, in order, at increasing scene times t >= 0,
    piecewise linear in between, held after the last and starting from rest (a first row at
    t = 0 must be zero; one at t > 0 is reached from zero at t = 0); or ``bend``."""

    region: str
    components: Annotated[str, Field(pattern=r"^[xyz]{1,3}$")] = "xyz"
    layers: Literal["all", "bottom", "mid", "top"] = "all"
    displacement: Point = (0.0, 0.0, 0.0)
    keyframes: list[list[float]] = []
    bend: BendSpec | None = None
    release: bool = False  # removed in the release (springback) stage
    # only in the release stage, holding the nodes where they are (a support for the free part)
    release_only: bool = False

    @model_validator(mode="after")
    def _motion(self):
        if len(set(self.components)) != len(self.components):
            raise ValueError(f"components: {self.components!r} names a component twice")
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


class LoadSpec(Strict):
    kind: Literal["gravity", "traction", "pressure", "point"]
    vector: Vec3 | None = None  # gravity (m/s^2), traction (Pa), point (N)
    value: bounded(-MAX_STRESS, MAX_STRESS, lo_open=False) | None = None  # pressure (Pa)
    region: str | None = None
    point: Point | None = None
    skin: Literal["top", "bottom"] = "top"

    # the bound of each kind's vector, and its unit (a pressure has none)
    BOUNDS: ClassVar[dict[str, tuple[float, str]]] = {
        "gravity": (MAX_ACCELERATION, "m/s^2"), "traction": (MAX_STRESS, "Pa"),
        "point": (MAX_FORCE, "N")}

    @field_validator("vector")
    @classmethod
    def _magnitude(cls, v: Vec3 | None, info: ValidationInfo) -> Vec3 | None:
        kind = info.data.get("kind")
        if v is not None and kind in cls.BOUNDS:
            check_magnitude(v, *cls.BOUNDS[kind])
        return v

    @model_validator(mode="after")
    def _fields(self):
        need = {"gravity": ["vector"], "traction": ["vector", "region"],
                "pressure": ["value"], "point": ["vector", "point"]}[self.kind]
        missing = [k for k in need if getattr(self, k) is None]
        if missing:
            raise ValueError(f"load kind {self.kind!r} needs {', '.join(missing)}")
        return self



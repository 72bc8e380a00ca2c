"""Scene files: TOML validated into frozen pydantic models. Units SI (m, Pa, kg, s, N).

``load_scene(path, overrides)`` applies ``key.path=value`` overrides to the raw TOML before
validation, so an override is checked exactly like the file. Errors name the field.
"""

from __future__ import annotations

import json
import math
import re
import tomllib
from pathlib import Path
from typing import Annotated, ClassVar, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from sim.tree import MAX_DEPTH, tree_problem

Vec3 = tuple[float, float, float]
Pos = Annotated[float, Field(gt=0)]


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class MeshSpec(Strict):
    kind: Literal["rectangle", "annulus", "disk", "cylinder_band", "file"]
    edge_length: Pos | None = None
    size: tuple[Pos, Pos] | None = None  # rectangle: (Lx, Ly)
    origin: tuple[float, float] = (0.0, 0.0)
    r_inner: Annotated[float, Field(ge=0)] = 0.0
    r_outer: Pos | None = None
    radius: Pos | None = None  # cylinder_band
    height: Pos | None = None  # cylinder_band
    path: str | None = None
    scale: Pos = 1.0  # file units to metres
    # out-of-plane imperfection of a flat mid-surface (m): z += a sin(pi s) sin(pi t), with
    # (s, t) in [0, 1]^2 over its bounding box; a perfect plate in tension has no reason to
    # leave its plane, so buckling (Fig. 4 at nu = 0.499) needs a seed
    imperfection: float = 0.0

    @model_validator(mode="after")
    def _needs(self):
        need = {"rectangle": ["size", "edge_length"], "annulus": ["r_outer", "edge_length"],
                "disk": ["r_outer", "edge_length"],
                "cylinder_band": ["radius", "height", "edge_length"], "file": ["path"]}[self.kind]
        missing = [k for k in need if getattr(self, k) is None]
        if missing:
            raise ValueError(f"mesh kind {self.kind!r} needs {', '.join(missing)}")
        if self.kind == "annulus" and self.r_inner >= self.r_outer:
            raise ValueError("r_inner must be smaller than r_outer")
        return self


class ShellSpec(Strict):
    """Thickness (m), one of: ``thickness`` (constant, or at the origin of a taper
    ``thickness + thickness_gradient . X``); ``thickness_file``, a .npy or text file of one value
    per mesh vertex (generated meshes: the generator's vertex order; mesh files: the file's);
    ``thickness_attribute``, a vertex property of a PLY mesh file. Relative paths are taken
    from the scene file's folder."""

    thickness: Pos | None = None
    # a tapered sheet: thickness + gradient . X at every vertex (m per m); must stay positive
    thickness_gradient: Vec3 = (0.0, 0.0, 0.0)
    thickness_file: str | None = None
    thickness_attribute: str | None = None
    element: str = "q3t"
    quadrature: tuple[Annotated[int, Field(ge=1)], Annotated[int, Field(ge=1)]] | None = None
    # section points through the thickness, keeping the element's in-plane rule: plastic
    # bending needs more than the 2-3 of the defaults to integrate the elastic-plastic profile
    thickness_points: Annotated[int, Field(ge=1, le=20)] | None = None

    @model_validator(mode="after")
    def _one_thickness(self):
        given = [k for k in ("thickness", "thickness_file", "thickness_attribute")
                 if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError("give exactly one of thickness, thickness_file, thickness_attribute"
                             f" (got {', '.join(given) or 'none'})")
        if self.thickness is None and any(self.thickness_gradient):
            raise ValueError("thickness_gradient tapers a constant thickness: it needs thickness")
        return self


FinitePos = Annotated[float, Field(gt=0, allow_inf_nan=False)]
FiniteNonNeg = Annotated[float, Field(ge=0, allow_inf_nan=False)]


class Hardening(Strict):
    """Isotropic hardening Y(ep) of sim.materials.plasticity. The initial flow stress is always
    ``material.yield_stress``; each law takes its own fields only (a field of another law is an
    error, never silently ignored):

    - perfect: Y = yield_stress
    - linear: Y = yield_stress + modulus ep, modulus >= 0
    - swift: Y = K (e0 + ep)^n, K > 0, n >= 0; e0 defaults to (yield_stress / K)^(1/n) so that
      Y(0) = yield_stress; an e0 given explicitly must satisfy K e0^n = yield_stress
    - voce: Y = yield_stress + (saturation - yield_stress)(1 - exp(-rate ep)), saturation >=
      yield_stress, rate > 0 (rate 0 is perfect plasticity: use law 'perfect')

    Softening (modulus < 0, saturation < yield_stress) is rejected: the incremental potential is
    convex, and its Hessian positive semi-definite, only for a nondecreasing Y (module docstring
    of sim.materials.plasticity), and a softening law localises into a mesh-dependent band.
    """

    law: Literal["perfect", "linear", "swift", "voce"] = "perfect"
    modulus: FiniteNonNeg | None = None  # linear: H (Pa)
    K: FinitePos | None = None  # swift strength coefficient (Pa)
    n: FiniteNonNeg | None = None  # swift exponent
    e0: FinitePos | None = None  # swift strain offset
    saturation: FinitePos | None = None  # voce Ysat (Pa)
    rate: FinitePos | None = None  # voce C

    FIELDS: ClassVar[dict[str, tuple[str, ...]]] = {
        "perfect": (), "linear": ("modulus",), "swift": ("K", "n", "e0"),
        "voce": ("saturation", "rate")}
    REQUIRED: ClassVar[dict[str, tuple[str, ...]]] = {
        "perfect": (), "linear": ("modulus",), "swift": ("K", "n"), "voce": ("saturation", "rate")}

    @model_validator(mode="after")
    def _own_fields(self):
        for other, names in self.FIELDS.items():
            for name in names:
                if other != self.law and getattr(self, name) is not None \
                        and name not in self.FIELDS[self.law]:
                    raise ValueError(f"{name}: a parameter of law {other!r}, not of "
                                     f"{self.law!r} (which takes "
                                     f"{', '.join(self.FIELDS[self.law]) or 'none'})")
        missing = [k for k in self.REQUIRED[self.law] if getattr(self, k) is None]
        if missing:
            raise ValueError(f"law {self.law!r} needs {', '.join(missing)}")
        return self


class MaterialSpec(Strict):
    model: Literal["neo_hookean", "hencky", "plastic"] = "neo_hookean"
    E: FinitePos
    nu: Annotated[float, Field(ge=0.0, lt=0.5)]
    density: FinitePos = 1000.0
    yield_stress: FinitePos | None = None  # initial flow stress (Pa), plastic model only
    hardening: Hardening = Hardening()

    @model_validator(mode="after")
    def _plastic_fields(self):
        if self.model != "plastic":
            if self.yield_stress is not None:
                raise ValueError(f"yield_stress: only used by model 'plastic' (not "
                                 f"{self.model!r})")
            if self.hardening.law != "perfect":
                raise ValueError(f"hardening: only used by model 'plastic' (not "
                                 f"{self.model!r})")
            return self
        if self.yield_stress is None:
            raise ValueError("a plastic material needs yield_stress")
        h, y0 = self.hardening, self.yield_stress
        if h.law == "voce" and h.saturation < y0:
            raise ValueError(f"hardening.saturation: {h.saturation:.6g} Pa is below yield_stress "
                             f"{y0:.6g} Pa (a softening law; see Hardening)")
        if h.law == "swift":
            self._swift_e0()
        return self

    def _swift_e0(self) -> float:
        h, y0 = self.hardening, self.yield_stress
        if h.e0 is not None:
            y_swift = h.K * h.e0**h.n
            # the two spellings of the initial yield must agree to round-off of the inputs
            if abs(y_swift / y0 - 1) > 1e-6:
                raise ValueError(f"hardening.e0: K e0^n = {y_swift:.6g} Pa differs from "
                                 f"yield_stress = {y0:.6g} Pa (omit e0 to derive it from them)")
            return h.e0
        if h.n == 0.0:  # Y = K whatever e0: it must be the yield stress
            if abs(h.K / y0 - 1) > 1e-6:
                raise ValueError(f"hardening.K: with n = 0 Swift is Y = K = {h.K:.6g} Pa, which "
                                 f"differs from yield_stress = {y0:.6g} Pa")
            return 1.0
        try:
            e0 = (y0 / h.K) ** (1.0 / h.n)
        except OverflowError:
            e0 = float("inf")
        if not (0.0 < e0 < float("inf")):
            raise ValueError(f"hardening: e0 = (yield_stress / K)^(1/n) = {e0:.3g} is not a "
                             "positive finite strain; check K and n")
        return e0

    def hardening_params(self) -> list[float]:
        """Kernel parameters ``hp`` of sim.materials.plasticity for this law (plastic only)."""
        h, y0 = self.hardening, self.yield_stress
        return {"perfect": lambda: [y0], "linear": lambda: [y0, h.modulus],
                "swift": lambda: [h.K, self._swift_e0(), h.n],
                "voce": lambda: [y0, h.saturation, h.rate]}[h.law]()


class BoxSpec(Strict):
    min: Vec3
    max: Vec3


class PlaneSpec(Strict):
    point: Vec3
    normal: Vec3
    tolerance: Pos = 1e-9


class RingSpec(Strict):
    """Nodes whose rest distance from the z axis lies in [r_min, r_max]."""

    r_min: Annotated[float, Field(ge=0)] = 0.0
    r_max: Pos


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

    angle: float
    length: Pos


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
    displacement: Vec3 = (0.0, 0.0, 0.0)
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
            if not all(math.isfinite(v) for v in row):
                raise ValueError(f"keyframes.{i}: not a finite number")
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
    value: float | None = None  # pressure (Pa)
    region: str | None = None
    point: Vec3 | None = None
    skin: Literal["top", "bottom"] = "top"

    @model_validator(mode="after")
    def _fields(self):
        need = {"gravity": ["vector"], "traction": ["vector", "region"],
                "pressure": ["value"], "point": ["vector", "point"]}[self.kind]
        missing = [k for k in need if getattr(self, k) is None]
        if missing:
            raise ValueError(f"load kind {self.kind!r} needs {', '.join(missing)}")
        return self


class SteppingSpec(Strict):
    kind: Literal["static", "dynamic"] = "static"
    steps: Annotated[int, Field(ge=1, le=100000)] = 1
    dt: Pos | None = None  # dynamic: time step (s); duration = steps * dt
    # dynamic: loads ramp over this time (s), 0 = applied at once; also the default ramp of
    # prescribed displacements (BCSpec), which take 1 s when it is 0
    load_ramp: Annotated[float, Field(ge=0)] = 0.0
    max_cutbacks: Annotated[int, Field(ge=0, le=30)] = 10  # down to 1/1024 of a step
    # after the last step: remove loads and the BCs marked release, solve static equilibrium
    release: bool = False

    @model_validator(mode="after")
    def _dt(self):
        if self.kind == "dynamic" and self.dt is None:
            raise ValueError("dynamic stepping needs dt")
        return self


class SolverSpec(Strict):
    rtol: Annotated[float, Field(gt=0, lt=1)] = 1e-8
    # a Newton correction below xtol * thickness ends the iteration (at the residual's floor)
    xtol: Annotated[float, Field(gt=0, lt=1)] = 1e-6
    # Newton's cap per attempt; one that stops progressing ends sooner (sim.newton)
    max_iterations: Annotated[int, Field(ge=1, le=1000)] = 200
    linear_solver: Literal["auto", "pardiso", "scipy"] = "auto"
    # auto: the exact Hessian where it is positive definite, else projected per quadrature point
    hessian_projection: Literal["auto", "qp", "element", "none"] = "auto"


class ProbeSpec(Strict):
    name: str
    kind: Literal["displacement", "thickness", "reaction", "volume", "curvature",
                  "plastic_strain", "von_mises", "tool_force", "penetration", "contact_nodes",
                  "fibre_tilt", "height_range", "tool_position", "springback", "cup_height"]
    tool: str | None = None
    point: Vec3 | None = None
    component: Literal["x", "y", "z", "norm"] = "norm"
    stat: Literal["min", "max", "mean"] = "mean"
    region: str | None = None

    @model_validator(mode="after")
    def _fields(self):
        if self.kind == "displacement" and self.point is None:
            raise ValueError("a displacement probe needs point")
        if (self.kind in ("reaction", "curvature", "height_range", "cup_height")
                and self.region is None):
            raise ValueError(f"a {self.kind} probe needs region")
        if (self.kind in ("tool_force", "penetration", "contact_nodes", "tool_position")
                and self.tool is None):
            raise ValueError(f"a {self.kind} probe needs tool")
        return self


class StudySpec(Strict):
    """A refinement study (``q3t study``): mesh edge lengths, elements, what is measured and the
    reference it is measured against.

    measure: ``final`` - the probe after the last step; ``curve`` - the probe over the run
    against ``over`` (``time`` or another probe, e.g. the punch's position), compared on the
    common range of the two curves; ``profile`` - a section's ``field`` along its rest radius
    at recorded ``step`` (default: the last recorded). ``norm``: relative L2 or max difference
    (curves and profiles). ``analytic``: a closed-form value for the probe (``final`` only)
    instead of a numerical reference run; the scene must satisfy the formula's assumptions.
    """

    probe: str | None = None  # default: the scene's first probe
    measure: Literal["final", "curve", "profile"] = "final"
    over: str = "time"
    section: str | None = None
    field: Literal["thickness", "radius", "z"] = "thickness"
    step: Annotated[int, Field(ge=0)] | None = None
    norm: Literal["l2", "max"] = "l2"
    edge_lengths: list[Pos] | None = None  # default: 4x, 2x, 1x the mesh's own
    elements: list[str] = ["linear", "q3t", "quadratic"]
    reference_element: str = "quadratic"
    reference_edge_length: Pos | None = None
    analytic: Literal["euler_bernoulli", "springback"] | None = None

    @model_validator(mode="after")
    def _what(self):
        if self.measure == "profile" and self.section is None:
            raise ValueError("a profile study needs section")
        if self.analytic and self.measure != "final":
            raise ValueError("analytic: a closed-form reference is one value: measure must be "
                             "'final'")
        return self


PRIMITIVES = ("plane", "box", "punch", "die_ring", "blank_holder", "star_die", "star", "polygon")
CSG = ("union", "subtract", "intersect")


class _Shape(Strict):
    """A tool shape (sim.tools.sdf builders). Lengths in m, in the tool's local frame.

    CSG: kind union / intersect (two or more ``shapes``, folded left) or subtract (exactly
    two: the first minus the second), ``blend`` > 0 a smooth fillet of that width (C2); the
    operands may be CSG of primitives in turn (two levels, which keeps the scene schema
    finite for the web form). Any shape can be placed in its parent's frame by ``offset``
    (m) and ``rotation`` (an axis-angle vector, rad: axis * angle), e.g. a punch lying along
    y: rotation [1.5708, 0, 0]."""

    point: Vec3 = (0.0, 0.0, 0.0)  # plane
    normal: Vec3 = (0.0, 0.0, 1.0)  # plane
    half_extents: tuple[Pos, Pos, Pos] | None = None  # box
    center: Vec3 = (0.0, 0.0, 0.0)  # box
    radius: Annotated[float, Field(ge=0)] = 0.0  # punch radius / box corner radius
    height: Pos = 0.05
    edge_radius: Annotated[float, Field(ge=0)] = 0.0
    inner_radius: Annotated[float, Field(ge=0)] = 0.0  # die opening, holder inner
    outer_radius: Pos = 0.1
    n_points: Annotated[int, Field(ge=3, le=32)] = 5  # star
    r_outer: Pos = 0.05
    r_inner: Pos = 0.03
    corner_radius: Annotated[float, Field(ge=0)] = 0.0  # star tips, convex polygon corners
    # star and star_die valleys (star_die default max(corner_radius, edge_radius), star 0),
    # reflex polygon corners
    reflex_radius: Annotated[float, Field(ge=0)] | None = None
    phase: float = 0.0
    # polygon: a prism 0 <= z <= height over these (x, y) vertices (either orientation)
    points: list[tuple[float, float]] = []
    blend: Annotated[float, Field(ge=0)] = 0.0
    offset: Vec3 = (0.0, 0.0, 0.0)
    rotation: Vec3 = (0.0, 0.0, 0.0)

    @model_validator(mode="after")
    def _needs(self):
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
        if not all(map(math.isfinite, self.rotation + self.offset)):
            raise ValueError("offset and rotation must be finite")
        if self.kind in PRIMITIVES:  # the builders' own checks (radii fit, polygon simple)
            from sim.model import tool_program

            tool_program(self)
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
    position: Vec3 = (0.0, 0.0, 0.0)
    velocity: Vec3 = (0.0, 0.0, 0.0)
    friction: Annotated[float, Field(ge=0, le=2)] = 0.0
    stiffness: Pos | None = None  # N/m per node; default: sim.contact.auto_stiffness
    release: bool = False  # retracted in the release (springback) stage
    # force control: the tool presses along -z with this force (N) and its z is solved with
    # the sheet (a blank holder); velocity must then have no z component
    force: Pos | None = None
    # a path: [t, dx, dy, dz] rows, offsets from `position` (m) at scene times t (static: 0-1),
    # or [t, dx, dy, dz, rx, ry, rz] with a rotation vector (axis * angle, rad) about the
    # tool's origin; piecewise linear in between (rotations: exact for a fixed axis), held
    # before the first and after the last; adds to the velocity's motion
    keyframes: list[list[float]] = []
    # force control: the lowest z offset (m, from the start position) the tool can reach, the
    # press's distance blocks; without it a holder falls once the flange has been drawn in
    stop: float | None = None

    @model_validator(mode="after")
    def _force_axis(self):
        if self.force is not None and self.velocity[2] != 0.0:
            raise ValueError("a force-controlled tool moves in z by itself: velocity z must be 0")
        times = [k[0] for k in self.keyframes]
        if any(b <= a for a, b in zip(times, times[1:], strict=False)):
            raise ValueError("keyframes: times must increase")
        lengths = {len(k) for k in self.keyframes}
        if len(lengths) > 1 or not lengths <= {4, 7}:
            raise ValueError("keyframes: rows must all be [t, dx, dy, dz] or all "
                             "[t, dx, dy, dz, rx, ry, rz]")
        if not all(math.isfinite(v) for k in self.keyframes for v in k):
            raise ValueError("keyframes: values must be finite")
        if self.force is not None and any(k[3] != 0.0 for k in self.keyframes):
            raise ValueError("keyframes: a force-controlled tool has no z path")
        if self.force is not None and any(any(k[4:]) for k in self.keyframes):
            raise ValueError("keyframes: a force-controlled tool does not rotate")
        return self


class SectionSpec(Strict):
    """A radial section: the mid-surface vertices within ``width`` of the ray from the origin
    along ``direction`` (rest state), sorted by rest radius; their current radius and
    thickness are recorded at every step listed (all steps when empty)."""

    name: str
    direction: tuple[float, float] = (1.0, 0.0)
    width: Pos = 1e-4
    steps: list[Annotated[int, Field(ge=0)]] = []


class Scene(Strict):
    name: str
    description: str = ""
    mesh: MeshSpec
    shell: ShellSpec
    material: MaterialSpec
    regions: list[RegionSpec] = []
    bcs: list[BCSpec] = []
    loads: list[LoadSpec] = []
    stepping: SteppingSpec = SteppingSpec()
    solver: SolverSpec = SolverSpec()
    tools: list[ToolSpec] = []
    probes: list[ProbeSpec] = []
    sections: list[SectionSpec] = []
    study: StudySpec | None = None

    @model_validator(mode="after")
    def _references(self):
        from sim.elements import ELEMENTS

        if self.shell.element not in ELEMENTS:
            raise ValueError(f"shell.element: unknown {self.shell.element!r}, "
                             f"known: {sorted(ELEMENTS)}")
        names = [r.name for r in self.regions]
        if len(set(names)) != len(names):
            raise ValueError("regions: names must be unique")
        for where, items in (("bcs", self.bcs), ("loads", self.loads), ("probes", self.probes)):
            for i, it in enumerate(items):
                if getattr(it, "region", None) and it.region not in names:
                    raise ValueError(f"{where}.{i}.region: unknown region {it.region!r}")
        tools = [t.name for t in self.tools]
        if len(set(tools)) != len(tools):
            raise ValueError("tools: names must be unique")
        for i, p in enumerate(self.probes):
            if p.tool is not None and p.tool not in tools:
                raise ValueError(f"probes.{i}.tool: unknown tool {p.tool!r}")
        if self.shell.thickness_attribute and not (
                self.mesh.kind == "file" and str(self.mesh.path).lower().endswith(".ply")):
            raise ValueError("shell.thickness_attribute: needs a PLY mesh file (mesh.kind = "
                             "'file', mesh.path ending in .ply)")
        plastic = self.material.model == "plastic"
        for i, p in enumerate(self.probes):  # nothing is recorded of a quantity the scene lacks
            if p.kind == "plastic_strain" and not plastic:
                raise ValueError(f"probes.{i}: a plastic_strain probe needs material.model = "
                                 "'plastic' (an elastic scene has no plastic strain)")
        if self.study:
            self._check_study(self.study)
        return self

    def _check_study(self, st: StudySpec) -> None:
        probes = [p.name for p in self.probes]
        if st.probe is not None and st.probe not in probes:
            raise ValueError(f"study.probe: no probe named {st.probe!r}")
        if st.measure != "profile" and st.probe is None and not probes:
            raise ValueError("study.probe: the scene has no probe to study")
        if st.measure == "curve" and st.over != "time" and st.over not in probes:
            raise ValueError(f"study.over: 'time' or a probe name, not {st.over!r}")
        if st.measure == "profile":
            sec = next((s for s in self.sections if s.name == st.section), None)
            if sec is None:
                raise ValueError(f"study.section: no section named {st.section!r}")
            if st.step is not None and sec.steps and st.step not in sec.steps:
                raise ValueError(f"study.step: section {sec.name!r} records steps {sec.steps}, "
                                 f"not {st.step}")
        if st.analytic:
            from sim.analytic import reference

            reference(self, st.analytic, st.probe or probes[0])


class SceneError(ValueError):
    """A scene that cannot be loaded; the message names the field and the reason."""


PATH_PREFIX = re.compile(r"^([A-Za-z_]\w*(?:\.\w+)*): (.+)$", re.S)


BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")


def _key(part) -> str:
    """A part of a field's path as TOML writes it: bare when it can be, else quoted (so an
    empty key shows as "")."""
    return str(part) if BARE_KEY.fullmatch(str(part)) else json.dumps(part)


def scene_errors(err: ValidationError) -> list[dict]:
    """pydantic's errors as ``{loc, msg}``, ``loc`` the field's dotted path. A check on the
    whole scene names its field in the message (``bcs.0.region: unknown region 'x'``): that
    becomes the loc; pydantic's "Value error, " is dropped."""
    out = []
    for e in err.errors():
        loc = ".".join(_key(p) for p in e["loc"])
        msg = e["msg"].removeprefix("Value error, ")
        if not loc:
            m = PATH_PREFIX.match(msg)
            if m and m.group(1).split(".")[0] in Scene.model_fields:
                loc, msg = m.group(1), m.group(2)
            else:
                loc = "scene"
        out.append({"loc": loc, "msg": msg})
    return out


def joined(errors: list[dict]) -> str:
    return "; ".join(f"{e['loc']}: {e['msg']}" for e in errors)


def parse_value(text: str):
    """A TOML value (number, bool, array, quoted string); bare words are strings."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def apply_override(raw: dict, key: str, value) -> None:
    """Set ``raw[a][b]...`` for ``key = "a.b..."``; list items by index (``loads.0.vector``)."""
    parts = key.split(".")
    if not all(parts):
        raise SceneError(f"{json.dumps(key)}: an override key is a field's dotted path, e.g. "
                         "material.nu or loads.0.vector")
    node = raw
    for p in parts[:-1]:
        if isinstance(node, list):
            if not p.isdigit() or int(p) >= len(node):
                raise SceneError(f"{key}: no item {p!r}")
            node = node[int(p)]
        else:
            node = node.setdefault(p, {})
        if not isinstance(node, (dict, list)):
            raise SceneError(f"{key}: {p!r} is not a table")
    last = parts[-1]
    if isinstance(node, list):
        if not last.isdigit() or int(last) >= len(node):
            raise SceneError(f"{key}: no item {last!r}")
        node[int(last)] = value
    else:
        node[last] = value


def scene_from_dict(raw: dict) -> Scene:
    try:
        return Scene.model_validate(raw)
    except ValidationError as err:
        raise SceneError(joined(scene_errors(err))) from None


def read_toml(text: str) -> dict:
    """The tables of a TOML text. Raises SceneError for bad TOML and for arrays or tables
    nested deeper than a scene can be (tomllib recurses once per level)."""
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise SceneError(f"TOML: {err}") from None
    except RecursionError:
        raise SceneError(f"TOML: nested deeper than {MAX_DEPTH} levels") from None
    problem = tree_problem(raw)
    if problem:
        raise SceneError(problem)
    return raw


def scene_from_toml(text: str, overrides: dict | None = None,
                    folder: Path | None = None) -> Scene:
    """The scene of a TOML text with ``overrides`` applied; relative file paths are taken from
    ``folder`` when given (a scene file's own folder)."""
    raw = read_toml(text)
    for k, v in (overrides or {}).items():
        apply_override(raw, k, v)
    if folder is not None:
        _from_folder(raw, folder)
    return scene_from_dict(raw)


def _from_folder(raw: dict, folder: Path) -> None:
    """Relative file paths of a scene file are taken from its folder."""
    for table, key in (("mesh", "path"), ("shell", "thickness_file")):
        node = raw.get(table)
        if isinstance(node, dict) and isinstance(node.get(key), str):
            p = Path(node[key]).expanduser()
            node[key] = str(p if p.is_absolute() else folder / p)


def load_scene(path: str | Path, overrides: dict | None = None) -> Scene:
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"scene file {str(path)!r} does not exist")
    return scene_from_toml(path.read_text(), overrides, path.resolve().parent)

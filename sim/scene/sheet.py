"""The sheet's tables: ``[mesh]``, ``[shell]`` and ``[material]`` (with its hardening law)."""

from __future__ import annotations

import functools
import math
from pathlib import Path
from typing import Annotated, Literal, Self

import numpy as np
from pydantic import Field, model_validator

from sim.geometry import outline
from sim.geometry import trimesh as meshes
from sim.scene import footprint
from sim.scene.boundary import RingSpec
from sim.scene.fields import (
    MAX_DENSITY,
    MAX_STRAIN,
    MAX_STRESS,
    Coord,
    Direction,
    Extent,
    FileName,
    Length,
    Slope,
    Stress,
    Strict,
    bounded,
    doc,
)


class _Mesh(Strict):
    """The sheet's mid-surface: a generated mesh of one ``kind`` or a mesh file; each kind
    takes its own fields only."""

    kind: str = doc("what mesh: rectangle, annulus, disk, cylinder_band, cylinder_patch, "
                    "sphere_patch, strip, file or outline")
    imperfection: Coord = doc(
        "out-of-plane imperfection of a flat mid-surface: z += a sin(pi s) sin(pi t), with "
        "(s, t) in [0, 1]^2 over its bounding box. A perfect flat sheet follows its flat path "
        "past a bifurcation (Newton has no reason to leave the plane): a seed picks a "
        "wrinkled branch; q3t bifurcation finds where the flat path loses stability and "
        "kicks along the mode instead", "m", 0.0)

    def radial_ranges(self) -> footprint.RadialRanges | None:
        """Intervals of the distance from the z axis (m) that hold every node of the built
        mesh, and every boundary node, known before it is built (sim.scene.footprint); None:
        known only once built (a twisted strip, a drawing or mesh file that cannot be
        read)."""
        return None


class _Generated(_Mesh):
    edge_length: Length = doc("the triangles' edge length: the mesh's resolution", "m")

    def _at_most(self, longest: float, what: str, makes: str) -> Self:
        # an edge longer than the sheet is across makes a mesh of a few triangles, no sheet: a
        # typo (an edge length of 5 m on a 60 mm blank ran and "finished"; a study's level of
        # 1000 m gave the same 90 DoFs as its 100 m). A coarse mesh short of that is the
        # user's look to take.
        if self.edge_length > longest * (1 + 1e-9):
            raise ValueError(f"edge_length: {1e3 * self.edge_length:.4g} mm is longer than "
                             f"{what} ({1e3 * longest:.4g} mm): at most that, {makes}")
        return self


class RectangleMesh(_Generated):
    """A rectangle in the plane z = 0, from ``origin`` to ``origin + size``."""

    kind: Literal["rectangle"] = doc("a rectangle in z = 0")
    size: tuple[Length, Length] = doc("its sides (Lx, Ly)", "m")
    origin: tuple[Coord, Coord] = doc("its corner of least x and y", "m", (0.0, 0.0))

    @model_validator(mode="after")
    def _resolved(self) -> Self:
        return self._at_most(max(self.size), "the rectangle's longer side",
                             "two triangles across it")

    def radial_ranges(self) -> footprint.RadialRanges:
        return footprint.rectangle_ranges(self.origin, self.size)


class AnnulusMesh(_Generated):
    """A ring in the plane z = 0 around the z axis."""

    kind: Literal["annulus"] = doc("a ring in z = 0 around the z axis")
    r_inner: Extent = doc("the hole's radius", "m", 0.0)
    r_outer: Length = doc("the outer radius", "m")

    @model_validator(mode="after")
    def _radii(self) -> Self:
        if self.r_inner >= self.r_outer:
            raise ValueError("r_inner must be smaller than r_outer")
        return self._at_most(self.r_outer, "the ring's outer radius", "a ring of a few "
                             "triangles")

    def radial_ranges(self) -> footprint.RadialRanges:
        return footprint.annulus_ranges(self.r_inner, self.r_outer, self.edge_length)


class DiskMesh(_Generated):
    """A disk in the plane z = 0 centred on the z axis (a round blank)."""

    kind: Literal["disk"] = doc("a disk in z = 0 centred on the z axis")
    r_outer: Length = doc("the disk's radius", "m")

    @model_validator(mode="after")
    def _resolved(self) -> Self:
        return self._at_most(self.r_outer, "the disk's radius", "a hexagon of six triangles")

    def radial_ranges(self) -> footprint.RadialRanges:
        return footprint.annulus_ranges(0.0, self.r_outer, self.edge_length)


class CylinderBandMesh(_Generated):
    """The side of a cylinder around the z axis, from z = 0 up to ``height`` (a tube)."""

    kind: Literal["cylinder_band"] = doc("a cylinder's side around the z axis (a tube)")
    radius: Length = doc("the cylinder's radius", "m")
    height: Length = doc("its height along z", "m")

    @model_validator(mode="after")
    def _resolved(self) -> Self:
        return self._at_most(max(self.height, 2 * math.pi * self.radius),
                             "the tube's height and circumference", "a band of a few "
                             "triangles")

    def radial_ranges(self) -> footprint.RadialRanges:
        return footprint.tube_ranges(self.radius, self.height, self.edge_length)


class _Patch(_Mesh):
    """A patch of a curved surface on a grid of parameters, refined by ``cells``; the quadratic
    and higher elements put their mid-edge nodes on the exact surface."""

    cells: Annotated[int, Field(ge=1, le=4096)] = doc(
        "cells per side: cells x cells quadrilaterals of two triangles each, the mesh's "
        "resolution", "1")
    curved: bool = doc(
        "nodes between the vertices (quadratic and higher elements) on the exact surface, and "
        "every node column along the exact normal; false: on the flat triangles (a faceted "
        "shell, normals averaged over the triangles)", default=True)


class CylinderPatchMesh(_Patch):
    """Part of a cylinder around the x axis (a roof, an octant of a tube): x from 0 to
    ``length``, and from the top (+z) by ``angle`` towards +y."""

    kind: Literal["cylinder_patch"] = doc("part of a cylinder around the x axis")
    radius: Length = doc("the cylinder's radius", "m")
    length: Length = doc("its length along x, from x = 0", "m")
    angle: bounded(0.0, math.pi) = doc(
        "the angle it spans, from the top (+z) towards +y (0.698 rad is 40 degrees)", "rad")

    def radial_ranges(self) -> footprint.RadialRanges:
        return footprint.cylinder_patch_ranges(self.radius, self.length, self.angle, self.cells)


class SpherePatchMesh(_Patch):
    """Part of a sphere around the origin (a hemisphere with a polar hole, or a sector of
    one): from the polar angle ``hole`` down to the equator z = 0, and from the x axis by
    ``azimuth`` towards +y."""

    kind: Literal["sphere_patch"] = doc("part of a sphere around the origin")
    radius: Length = doc("the sphere's radius", "m")
    hole: Annotated[float, Field(gt=0.0, lt=math.pi / 2)] = doc(
        "the polar hole: its rim's angle from the +z axis (0.314 rad is 18 degrees); above "
        "0, since the grid cannot close at the pole", "rad")
    azimuth: bounded(0.0, math.pi) = doc(
        "the angle it spans around z from the x axis towards +y; unset: a quarter", "rad",
        math.pi / 2)

    def radial_ranges(self) -> footprint.RadialRanges:
        return footprint.sphere_patch_ranges(self.radius, self.hole, self.azimuth, self.cells)


MAX_TWIST_PER_CELL = math.pi / 4  # rad


class StripMesh(_Mesh):
    """A strip along the x axis, refined by ``cells`` along it: x from 0 to ``length``, its
    width centred on the axis, turned about it by ``twist`` from root to tip (a helicoid; 0: a
    flat strip in z = 0, its width along y). A beam of shell elements; its triangles are flat,
    so every element's nodes lie on them."""

    kind: Literal["strip"] = doc("a strip along x, flat or twisted about its axis")
    length: Length = doc("its length along x, from x = 0", "m")
    width: Length = doc("its width, centred on the x axis (along y at x = 0)", "m")
    twist: bounded(-math.pi, math.pi, lo_open=False) = doc(
        "how far the width turns about the x axis from x = 0 to the tip, towards +z "
        "(1.571 rad is 90 degrees)", "rad", 0.0)
    cells: Annotated[int, Field(ge=1, le=4096)] = doc(
        "cells along the length (quadrilaterals of two triangles each), the mesh's "
        "resolution", "1")
    aspect: bounded(0.01, 100.0) = doc(
        "a cell's length over its width: the cells across are cells x width x aspect / length, "
        "rounded, at least 1, so refining cells refines both ways", "1", 1.0)

    def radial_ranges(self) -> footprint.RadialRanges | None:
        if self.twist != 0.0:  # turned out of z = 0: known once built
            return None
        return footprint.rectangle_ranges((0.0, -self.width / 2), (self.length, self.width))

    @property
    def across(self) -> int:
        """Cells across the width."""
        return max(1, round(self.cells * self.width * self.aspect / self.length))

    @model_validator(mode="after")
    def _cells(self) -> Self:
        if self.across > 4096:
            raise ValueError(f"aspect: {self.across} cells across the width (cells x width x "
                             "aspect / length, from cells, width, aspect and length) is more "
                             "than 4096")
        # a cell turned by 90 degrees or more stands one of its triangles on edge or folds
        # the two over each other; 45 keeps both facing the same side
        if abs(self.twist) > MAX_TWIST_PER_CELL * self.cells:
            raise ValueError(f"cells: {self.cells} cells turn by {math.degrees(self.twist):.4g} "
                             f"degrees in all, more than "
                             f"{math.degrees(MAX_TWIST_PER_CELL):.0f} each (the triangles "
                             "would fold over); give more cells or less twist")
        return self


class FileMesh(_Mesh):
    """A triangle mesh file (STL, OBJ, PLY, ...), read with trimesh; a relative path is taken
    from the scene file's folder."""

    kind: Literal["file"] = doc("a triangle mesh file")
    path: FileName = doc("the mesh file")
    merge_vertices: bool | None = doc(
        "a file's coincident vertices merged into one (a slit whose sides are two rows of "
        "coincident vertices closes); unset: only for STL, which stores every triangle's "
        "corners apart. result.json's built.mesh says what was merged", default=None)
    scale: Annotated[float, Field(ge=1e-9, le=1e3)] = doc(
        "file units to metres (1e-3 for a file in mm): between nanometres and kilometres",
        "m per file unit", 1.0)

    def radial_ranges(self) -> footprint.RadialRanges | None:
        """The file's ranges, read once per version of it (a form edit checks them again); one
        it cannot read is left to the build, which names the file's problem."""
        path = Path(self.path)
        try:
            st = path.stat()
        except OSError:
            return None
        return _file_ranges(str(path.resolve()), st.st_mtime_ns, st.st_size, self.scale,
                            self.merge_vertices)


@functools.lru_cache(maxsize=8)
def _file_ranges(path: str, mtime_ns: int, size: int, scale: float,
                 merge: bool | None) -> footprint.RadialRanges | None:
    try:
        mesh = meshes.load(path, scale, merge)
    except meshes.MeshFileError:
        return None
    return footprint.mesh_ranges(mesh.vertices, mesh.faces)


XY = tuple[Coord, Coord]


class CircleSpec(Strict):
    """A round outline: the regular polygon of ``segments`` sides inscribed in the circle, its
    first corner on the +x side of the centre, its points rounded to a nanometre
    (sim.geometry.outline.circle). The mesh resamples it at the edge length, as a curve."""

    radius: Length = doc("the circle's radius", "m")
    center: XY = doc("its centre [x, y]", "m", (0.0, 0.0))
    segments: Annotated[int, Field(ge=outline.MIN_SEGMENTS, le=outline.MAX_SEGMENTS)] = doc(
        "the inscribed polygon's sides; at least 15, since with fewer each corner turns by "
        "25 degrees or more and the mesh keeps the polygon's corners instead of the curve",
        "1", 360)

    def loop(self) -> np.ndarray:
        """The circle's points ``(segments, 2)``, counter-clockwise."""
        return outline.circle(self.radius, self.center, self.segments)


class RefineSpec(Strict):
    """A ring of finer triangles around the z axis, graded back to the mesh's edge length
    outside it: where a drawn blank's material passes a die's radius (the cup's wall), without
    refining the bottom and the flange's edge alike."""

    ring: RingSpec = doc("where: the ring of rest positions around the z axis")
    edge_length: Length = doc("the edge length inside the ring: finer than the mesh's", "m")
    growth: Annotated[float, Field(ge=0.05, le=1.0)] = doc(
        "how fast the edge length grows back outside the ring, per unit of distance from it "
        "(0.25: neighbouring triangles about a quarter apart in size)", "m/m", 0.25)

    @model_validator(mode="after")
    def _radii(self) -> Self:
        if self.ring.r_max is None:
            raise ValueError("ring: r_max: a refinement needs the ring's outer radius")
        if self.ring.r_min >= self.ring.r_max:
            raise ValueError("ring: r_min must be smaller than r_max")
        return self


class OutlineMesh(_Generated):
    """A blank cut from a closed 2-D outline in z = 0, with optional holes, meshed into
    isotropic triangles (sim.geometry.outline): the outline as ``points``, as a ``circle``, or
    the closed paths of an SVG or DXF drawing (``path``: the path enclosing the most area is
    the outline, the others its holes). A relative path is taken from the scene file's
    folder."""

    kind: Literal["outline"] = doc("a closed outline (points, a circle or an SVG/DXF drawing)")
    points: list[XY] | None = doc("the outline's [x, y] corners in order (at least 3; curves "
                                  "as many points, which the mesh resamples)", "m", None)
    circle: CircleSpec | None = doc("a round outline instead of points: radius, center and "
                                    "segments", default=None)
    holes: list[list[XY]] = doc("holes inside the outline (points or circle), each a list of "
                                "[x, y] points", "m", [])
    path: FileName | None = doc("an SVG or DXF drawing of closed paths instead of points or "
                                "a circle", default=None)
    scale: Annotated[float, Field(ge=1e-9, le=1e3)] | None = doc(
        "the drawing's units to metres (1e-3 for a drawing in mm); unset: the units the "
        "drawing says, an SVG's width in mm, cm, in, pt or pc over its viewBox or a DXF's "
        "$INSUNITS (refused if it says none)", "m per drawing unit", None)
    centre: bool = doc("move the drawing so that its outline's bounding box is centred on "
                       "the origin, the punch axis of the cup scenes (a drawing whose origin "
                       "is a corner); false: the drawing's own coordinates, y up",
                       default=False)
    refine: list[RefineSpec] = doc(
        "rings around the z axis meshed finer (each graded back to edge_length)", default=[])
    mesher: Literal[tuple(outline.MESHERS)] = doc(
        "gmsh's algorithm: frontal_delaunay (the most regular triangles, lined up in a "
        "60-degree lattice: a drawn disk's rim takes six waves from it) or meshadapt (edges "
        "in every direction: no waves from the mesh, less regular triangles)",
        default="frontal_delaunay")

    @property
    def bands(self) -> tuple:
        """``refine`` as the mesher's bands (sim.geometry.outline.Band)."""
        return tuple(outline.Band(r.ring.r_min, r.ring.r_max, r.edge_length, r.growth)
                     for r in self.refine)

    def shape(self) -> outline.Outline | None:
        """The outline as the scene gives it, ``points`` or ``circle``, with its holes,
        checked and counter-clockwise; None for a drawing (``path``), read when the mesh is
        built. OutlineError naming the field."""
        if self.path is not None:
            return None
        field = "points" if self.points is not None else "circle"
        outer = outline.loop(self.points if self.points is not None else self.circle.loop(),
                             field)
        return outline.checked(outer, [outline.loop(h, f"holes.{i}")
                                       for i, h in enumerate(self.holes)], field)

    def radial_ranges(self) -> footprint.RadialRanges | None:
        shape = self.shape()
        if shape is None:  # a drawing: read here too, or named by the build if it cannot be
            try:
                shape = outline.read_drawing(self.path, self.scale, self.edge_length,
                                             centre=self.centre)
            except outline.OutlineError:
                return None
        return footprint.loop_ranges(outline.meshed_loops(shape, self.edge_length))

    @model_validator(mode="after")
    def _outline(self) -> Self:
        given = [k for k in ("points", "path", "circle") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError("give exactly one of points, path, circle (got "
                             f"{', '.join(given) or 'none'})")
        if self.centre and self.path is None:
            raise ValueError("centre: for a drawing (path); points and a circle are placed "
                             "by their coordinates")
        if self.path is not None:
            if self.holes:
                raise ValueError("holes: a drawing's holes are its inner paths (holes go with "
                                 "points or circle)")
            return self
        try:
            outline.check_size(self.shape(), self.edge_length, self.bands)
        except outline.OutlineError as exc:
            raise ValueError(f"{exc.field}: {exc}") from None
        return self


# the mesh of the chosen kind: only its own fields are accepted (pydantic tells the kinds
# apart by ``kind`` and names a field of another kind as not permitted)
MeshSpec = Annotated[RectangleMesh | AnnulusMesh | DiskMesh | CylinderBandMesh
                     | CylinderPatchMesh | SpherePatchMesh | StripMesh | FileMesh | OutlineMesh,
                     Field(discriminator="kind")]


class ShellSpec(Strict):
    """Thickness (m), one of: ``thickness`` (constant, or at the origin of a taper
    ``thickness + thickness_gradient . X``); ``thickness_file``, a .npy or text file of one value
    per mesh vertex (generated meshes: the generator's vertex order; mesh files: the file's);
    ``thickness_attribute``, a vertex property of a PLY mesh file. Relative paths are taken
    from the scene file's folder."""

    thickness: Length | None = doc("a constant thickness (or a taper's at the origin)", "m",
                                   None)
    thickness_gradient: tuple[Slope, Slope, Slope] = doc(
        "a tapered sheet: thickness + gradient . X at every vertex; must stay positive",
        "m/m", (0.0, 0.0, 0.0))
    thickness_file: FileName | None = doc("a .npy or text file of one thickness (m) per vertex",
                                     default=None)
    thickness_attribute: str | None = doc(
        "the PLY mesh file's vertex property holding the thickness (m)", default=None)
    element: str = doc("the prism element: linear, q3t, q3t_ans or quadratic (sim.elements)",
                       default="q3t")
    quadrature: tuple[Annotated[int, Field(ge=1)], Annotated[int, Field(ge=1)]] | None = doc(
        "the quadrature (in-plane points, points through the thickness); unset: the "
        "element's own", "1", None)
    thickness_points: Annotated[int, Field(ge=1, le=20)] | None = doc(
        "section points through the thickness, keeping the element's in-plane rule: plastic "
        "bending needs more than the 2-3 of the defaults to integrate the elastic-plastic "
        "profile", "1", None)

    @model_validator(mode="after")
    def _one_thickness(self) -> Self:
        given = [k for k in ("thickness", "thickness_file", "thickness_attribute")
                 if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError("give exactly one of thickness, thickness_file, thickness_attribute"
                             f" (got {', '.join(given) or 'none'})")
        if self.thickness is None and any(self.thickness_gradient):
            raise ValueError("thickness_gradient tapers a constant thickness: it needs thickness")
        return self


class _Hardening(Strict):
    """Isotropic hardening Y(ep) of sim.materials.plasticity. The initial flow stress is always
    ``material.yield_stress``; each law takes its own fields only (a field of another law is an
    error naming it, never silently ignored):

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

    law: str = doc("the hardening law: perfect, linear, swift or voce")


class PerfectHardening(_Hardening):
    """Perfect plasticity: Y = yield_stress."""

    law: Literal["perfect"] = doc("perfect plasticity")


class LinearHardening(_Hardening):
    """Y = yield_stress + modulus ep."""

    law: Literal["linear"] = doc("linear hardening")
    modulus: bounded(0.0, MAX_STRESS, lo_open=False) = doc("the hardening modulus H", "Pa")


class SwiftHardening(_Hardening):
    """Y = K (e0 + ep)^n; e0 by default such that Y(0) = yield_stress."""

    law: Literal["swift"] = doc("Swift's power law")
    K: Stress = doc("the strength coefficient", "Pa")
    n: bounded(0.0, 10.0, lo_open=False) = doc(
        "the hardening exponent; metals' are below 1, and (e0 + ep)^n stays representable up "
        "to 10", "1")
    e0: bounded(0.0, MAX_STRAIN) | None = doc(
        "the strain offset; unset: (yield_stress / K)^(1/n)", "1", None)


class VoceHardening(_Hardening):
    """Y = yield_stress + (saturation - yield_stress)(1 - exp(-rate ep))."""

    law: Literal["voce"] = doc("Voce's saturating law")
    saturation: Stress = doc("the saturation flow stress Ysat", "Pa")
    rate: bounded(0.0, 1e6) = doc(
        "the saturation rate C (> 0: rate 0 is law perfect); 1e6 saturates within a "
        "micro-strain", "1")


# the hardening of one law, with that law's fields only
Hardening = Annotated[PerfectHardening | LinearHardening | SwiftHardening | VoceHardening,
                      Field(discriminator="law")]


class _FLC(Strict):
    """A forming limit curve (sim.frames.forming_limits): the limit major strain over the minor
    strain, both true (log) in-plane strains of the mid-surface, and the zone thresholds of the
    forming limit diagram. Plastic materials only."""

    kind: str = doc("points (a measured curve) or keeler_brazier")
    margin: bounded(0.0, 1.0, lo_open=False) = doc(
        "the marginal zone: this far (true major strain) below the curve", "1", 0.1)
    insufficient_stretch: bounded(0.0, 1.0, lo_open=False) = doc(
        "insufficient stretch: both strains smaller than this in size", "1", 0.02)
    max_thinning: bounded(0.0, 1.0, lo_open=True) | None = doc(
        "excessive thinning: the share of the rest thickness whose loss fails the part whatever "
        "its strains (a criterion beside the curve, as forming packages apply one); the "
        "summary's maximum thinning is flagged from it; unset: the rule of thumb, 20 %", "1",
        None)


class PointsFLC(_FLC):
    """A measured curve: interpolated linearly, held constant beyond its ends."""

    kind: Literal["points"] = doc("a measured curve")
    points: list[tuple[bounded(-MAX_STRAIN, MAX_STRAIN, lo_open=False),
                       bounded(0.0, MAX_STRAIN)]] = doc(
        "[minor, major] true strains, minor increasing, major > 0; at least 2", "1")

    @model_validator(mode="after")
    def _curve(self) -> Self:
        if len(self.points) < 2:
            raise ValueError("points: a curve needs at least 2 [minor, major] points")
        minor = [p[0] for p in self.points]
        if any(b <= a for a, b in zip(minor, minor[1:], strict=False)):
            raise ValueError("points: the minor strains must increase")
        return self


class KeelerBrazierFLC(_FLC):
    """The curve from thickness and hardening exponent, FLD0 [%] = (23.3 + 14.13 t [mm]) n /
    0.21 (engineering major strain at plane strain; Keeler and Brazier 1977), a correlation
    for steels."""

    kind: Literal["keeler_brazier"] = doc("the Keeler-Brazier correlation")
    n: bounded(0.0, 1.0) | None = doc(
        "the hardening exponent; unset: hardening.n of a swift law", "1", None)
    thickness: Length | None = doc("the sheet thickness; unset: shell.thickness", "m", None)


# a forming limit curve of one kind, with that kind's fields only
FLCSpec = Annotated[PointsFLC | KeelerBrazierFLC, Field(discriminator="kind")]


# r-values of rolled sheets lie within 0.2-3; a hundred is far beyond any, and keeps Hill's
# coefficients (ratios of them) well inside float range
_Ratio = bounded(0.0, 100.0)


class Hill48Spec(Strict):
    """Hill's 1948 orthotropic yield criterion (sim.materials.hill) in place of von Mises:
    either the r-values r0, r45, r90 (plastic width over thickness strain in uniaxial tension
    at 0, 45 and 90 degrees to the rolling direction) or Hill's F, G, H, N with G + H = 1, and
    the rolling direction. ``material.yield_stress`` and the hardening law are the flow stress
    in tension along the rolling direction. The material axes of each element are the rolling
    direction projected on its rest mid-surface, the transverse direction, and the normal."""

    r0: _Ratio | None = doc("the r-value along the rolling direction", "1", None)
    r45: _Ratio | None = doc("the r-value at 45 degrees to the rolling direction", "1", None)
    r90: _Ratio | None = doc("the r-value across the rolling direction", "1", None)
    # Hill's criterion with 1 the rolling, 2 the transverse direction, 3 the normal:
    # F (s22 - s33)^2 + G (s33 - s11)^2 + H (s11 - s22)^2 + 2 L s23^2 + 2 M s31^2 + 2 N s12^2
    # = yield_stress^2
    F: _Ratio | None = doc("Hill's F, of (σ_TD − σ_normal)², instead of the r-values; "
                           "r90 = H / F", "1", None)
    G: _Ratio | None = doc("Hill's G, of (σ_normal − σ_RD)²; G + H = 1 (yield_stress along "
                           "the rolling direction), r0 = H / G", "1", None)
    H: _Ratio | None = doc("Hill's H, of (σ_RD − σ_TD)²; G + H = 1", "1", None)
    N: _Ratio | None = doc("Hill's N, of 2 τ_RD,TD² (in-plane shear); r45 = N / (F + G) − 1/2",
                           "1", None)
    L: _Ratio = doc("Hill's L, of 2 τ_TD,normal² (transverse shear; von Mises' 1.5 unless "
                    "measured)", "1", 1.5)
    M: _Ratio = doc("Hill's M, of 2 τ_normal,RD² (transverse shear; von Mises' 1.5 unless "
                    "measured)", "1", 1.5)
    rolling_direction: Direction | None = doc(
        "the rolling direction as a vector in scene coordinates, projected on the sheet's "
        "plane at each element; needed unless the sheet is isotropic in its plane "
        "(r0 = r45 = r90)", "1", None)
    rolling_angle: bounded(-360.0, 360.0, lo_open=False) | None = doc(
        "the rolling direction as an angle from the x axis about z (the vector "
        "(cos, sin, 0)), instead of rolling_direction", "deg", None)

    @model_validator(mode="after")
    def _one_form(self) -> Self:
        rs = [k for k in ("r0", "r45", "r90") if getattr(self, k) is not None]
        cs = [k for k in ("F", "G", "H", "N") if getattr(self, k) is not None]
        if rs and cs or not (len(rs) == 3 or len(cs) == 4):
            raise ValueError("give either r0, r45, r90 or F, G, H, N (got "
                             f"{', '.join(rs + cs) or 'none'})")
        if cs and abs(self.G + self.H - 1.0) > 1e-6:
            raise ValueError(f"G + H = {self.G + self.H:.6g} must be 1: yield_stress is the flow "
                             "stress along the rolling direction")
        if self.rolling_direction is not None and self.rolling_angle is not None:
            raise ValueError("give one of rolling_direction and rolling_angle")
        if self.rolling_vector() is None:
            raise ValueError("rolling_direction: missing; an r-value that varies in the "
                             f"sheet's plane (r0, r45, r90 = {self.r_values()}) needs the rolling "
                             "direction (or rolling_angle)")
        return self

    def coefficients(self) -> tuple[float, float, float, float]:
        """(F, G, H, N), normalised G + H = 1."""
        if self.F is not None:
            return self.F, self.G, self.H, self.N
        G = 1.0 / (1.0 + self.r0)
        H = self.r0 * G
        F = H / self.r90
        return F, G, H, (self.r45 + 0.5) * (F + G)

    def r_values(self) -> tuple[float, float, float]:
        F, G, H, N = self.coefficients()
        return H / G, N / (F + G) - 0.5, H / F

    def planar_isotropic(self) -> bool:
        r0, r45, r90 = self.r_values()
        return abs(r0 - r45) <= 1e-12 * r0 and abs(r0 - r90) <= 1e-12 * r0

    def rolling_vector(self) -> tuple[float, float, float] | None:
        """The rolling direction in scene coordinates (x for a sheet isotropic in its plane,
        where it does not matter), or None when missing."""
        if self.rolling_angle is not None:
            a = math.radians(self.rolling_angle)
            return (math.cos(a), math.sin(a), 0.0)
        if self.rolling_direction is None and self.planar_isotropic():
            return (1.0, 0.0, 0.0)
        return self.rolling_direction


class MaterialSpec(Strict):
    """The sheet's material: a hyperelastic model, elastic-plastic (von Mises with
    isotropic hardening, sim.materials.plasticity), or linear elasticity in a geometrically
    linear analysis (sim.terms.small_strain)."""

    model: Literal["neo_hookean", "hencky", "plastic", "linear_elastic"] = doc(
        "neo_hookean or hencky (elastic), plastic, or linear_elastic: small strain and small "
        "displacement (a geometrically linear analysis, energy 1/2 eps:C:eps with eps = "
        "sym grad u), for the classical linear benchmarks", default="neo_hookean")
    E: Stress = doc("Young's modulus", "Pa")
    nu: Annotated[float, Field(ge=0.0, lt=0.5)] = doc("Poisson's ratio", "1")
    density: bounded(0.0, MAX_DENSITY) = doc("the mass density (inertia, gravity)", "kg/m^3",
                                             1000.0)
    yield_stress: Stress | None = doc("the initial flow stress; plastic model only", "Pa",
                                      None)
    hardening: Hardening = doc(
        "the isotropic hardening law Y(ep) (sim.materials.plasticity), its initial flow stress "
        "yield_stress; plastic model only. A softening law is rejected: the incremental "
        "potential is convex only for a nondecreasing Y, and softening localises into a "
        "mesh-dependent band", default=PerfectHardening(law="perfect"))
    flc: FLCSpec | None = doc(
        "the forming limit curve: major and minor strains, zones and the FLD of a run; "
        "plastic model only", default=None)
    hill48: Hill48Spec | None = doc(
        "an anisotropic sheet: Hill's 1948 yield criterion instead of von Mises (r-values, "
        "rolling direction); plastic model only", default=None)

    @model_validator(mode="after")
    def _plastic_fields(self) -> Self:
        if self.model != "plastic":
            if self.flc is not None:
                raise ValueError(f"flc: forming limits are for model 'plastic' (not "
                                 f"{self.model!r})")
            if self.hill48 is not None:
                raise ValueError(f"hill48: a yield criterion, for model 'plastic' (not "
                                 f"{self.model!r})")
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
        if self.flc and self.flc.kind == "keeler_brazier" and self.flc.n is None \
                and not (h.law == "swift" and h.n > 0):
            raise ValueError(f"flc.n: Keeler-Brazier needs a hardening exponent n > 0 (the "
                             f"default, a swift law's n, is not there: law {h.law!r}"
                             f"{f', n = {h.n}' if h.law == 'swift' else ''})")
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



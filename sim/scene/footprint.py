"""Where a generated blank's nodes lie (a flat one's, a tube's, a curved patch's), known
without meshing it: the distances from the z axis of its nodes and of its boundary nodes. With
them a scene is checked, when it is read, for a ring region that selects no node (an edit of
the blank's radius that leaves the rim ring outside the blank), which the build
(sim.model.dirichlet.region_mask) would otherwise find only when the model is made: the page's
form says so at the field as it is edited.

Each mesh kind that knows its ranges says so (``radial_ranges`` of sim.scene.sheet's mesh
tables, made by the helpers here). The ranges hold every node the build makes (a superset: a ring
inside them may still fall between nodes, which the build then names), so the check never
refuses a scene that builds.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from sim.geometry import trimesh as meshes
from sim.scene.boundary import REGION_TOLERANCE, RegionSpec

Ranges = list[tuple[float, float]]


@dataclass(frozen=True)
class RadialRanges:
    """Intervals of the distance from the z axis (m) that hold every node of a built mesh
    (``nodes``) and every boundary node (``boundary``)."""

    nodes: Ranges
    boundary: Ranges
    height: float = 0.0  # the mesh's extent along z (a tube's), which its radii do not bound


class Blank(Protocol):
    """A mesh table (sim.scene.sheet.MeshSpec) as the check reads it."""

    imperfection: float

    def radial_ranges(self) -> RadialRanges | None: ...


def annulus_ranges(r_inner: float, r_outer: float, h: float) -> RadialRanges:
    """The ranges of sim.geometry.trimesh.annulus (a disk: ``r_inner`` 0): its vertices lie on
    circles and every other node on their chords, so a rim of radius r with n vertices holds
    its nodes from r cos(pi / n) to r; the boundary is the rims (a disk's centre is not one),
    all the nodes lie between the hole's rim and the outer circle."""
    rims = [(r * np.cos(np.pi / meshes.ring_vertices(r, h)), r)
            for r in (r_inner, r_outer) if r > 0.0]
    return RadialRanges([(rims[0][0] if r_inner > 0.0 else 0.0, r_outer)], rims)


def tube_ranges(radius: float, height: float, h: float) -> RadialRanges:
    """The ranges of sim.geometry.trimesh.cylinder_band: its vertices on circles of
    ``radius``, every other node on their chords (from radius cos(pi / n) to radius, n
    vertices around), the two rims its boundary at the same radii."""
    n, _ = meshes.band_divisions(radius, height, h)
    span = [(radius * np.cos(np.pi / n), radius)]
    return RadialRanges(span, span, height)


def cylinder_patch_ranges(radius: float, length: float, angle: float,
                          cells: int) -> RadialRanges:
    """The ranges of sim.geometry.trimesh.cylinder_patch (about the x axis, from the top by
    ``angle``): seen from above a grid of x from 0 to ``length`` by y = radius sin(theta), from
    its vertex on the axis to its far corner. Past a quarter turn y comes back: the top of the
    vertices' grid is below the radius, and the curved elements' edge nodes on the exact surface
    rise above it, so the radius bounds them. Every side spans the same: the boundary's."""
    y = radius * (np.sin(np.linspace(0.0, angle, cells + 1)).max() if angle <= np.pi / 2
                  else 1.0)
    span = [(0.0, float(np.hypot(length, y)))]
    return RadialRanges(span, span, radius * (1.0 - np.cos(angle)))


def sphere_patch_ranges(radius: float, hole: float, azimuth: float,
                        cells: int) -> RadialRanges:
    """The ranges of sim.geometry.trimesh.sphere_patch (from the polar hole's rim down to the
    equator, ``cells`` steps of azimuth / cells around): from the rim's chords, nearest the
    axis, to the equator's vertices; a meridian side joins the two, so the boundary spans the
    same."""
    near = radius * np.sin(hole) * np.cos(0.5 * azimuth / cells)
    span = [(float(near), radius)]
    return RadialRanges(span, span, radius * np.cos(hole))


def rectangle_ranges(origin: tuple[float, float], size: tuple[float, float]) -> RadialRanges:
    """The ranges of a rectangle in z = 0 from ``origin`` to ``origin + size`` (a grid of it:
    the rectangle's and a flat strip's meshes)."""
    (x0, y0), (lx, ly) = origin, size
    return loop_ranges([np.array([[x0, y0], [x0 + lx, y0], [x0 + lx, y0 + ly], [x0, y0 + ly]])])


def loop_ranges(loops: Sequence[np.ndarray]) -> RadialRanges:
    """The ranges of a mesh whose boundary nodes lie on the chords of ``loops`` (each
    ``(n, 2)``: the outer one, then the holes) and whose other nodes lie between them: for the
    boundary, each loop's span from its nearest point to the axis to its farthest vertex; for
    all nodes, the polygon's (its nearest point is 0 when it holds the axis)."""
    import shapely

    axis = shapely.Point(0.0, 0.0)
    inside = float(axis.distance(shapely.Polygon(loops[0], loops[1:])))
    return RadialRanges([(inside, _farthest(loops[0]))],
                        [(float(axis.distance(shapely.LinearRing(p))), _farthest(p))
                         for p in loops])


def mesh_ranges(V: np.ndarray, F: np.ndarray) -> RadialRanges:
    """The ranges of a triangle mesh read from a file (``V (n_v, 3)``, ``F (n_f, 3)``), whose
    nodes the build places on its triangles (vertices, edge and face nodes of the element):
    for all nodes the union over the triangles of their radial spans (from the triangle's
    nearest point to the axis, in the plane, to its farthest vertex), for the boundary that of
    the edges used by one triangle only; height: its extent along z."""
    edges = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    unique, count = np.unique(edges, axis=0, return_counts=True)
    rim = unique[count == 1]
    P = V[:, :2]
    r = np.hypot(P[:, 0], P[:, 1])
    near = np.minimum.reduce([_segment_distance(P[F[:, i]], P[F[:, (i + 1) % 3]])
                              for i in range(3)])
    near[_holds_axis(P[F])] = 0.0
    nodes = _union(near, r[F].max(axis=1))
    boundary = _union(_segment_distance(P[rim[:, 0]], P[rim[:, 1]]), r[rim].max(axis=1)) \
        if len(rim) else []
    return RadialRanges(nodes, boundary, float(np.ptp(V[:, 2])))


def _segment_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance from the origin of each segment a-b in the plane ``(n, 2)``."""
    d = b - a
    dd = np.einsum("ij,ij->i", d, d)
    t = np.clip(-np.einsum("ij,ij->i", a, d) / np.where(dd > 0.0, dd, 1.0), 0.0, 1.0)
    q = a + t[:, None] * d
    return np.hypot(q[:, 0], q[:, 1])


def _holds_axis(T: np.ndarray) -> np.ndarray:
    """Whether each triangle ``(n, 3, 2)`` holds the origin (on its edge included)."""
    a, b = T, np.roll(T, -1, axis=1)
    c = [a[:, i, 0] * b[:, i, 1] - a[:, i, 1] * b[:, i, 0] for i in range(3)]
    return ((c[0] >= 0) & (c[1] >= 0) & (c[2] >= 0)) | ((c[0] <= 0) & (c[1] <= 0) & (c[2] <= 0))


def _union(lo: np.ndarray, hi: np.ndarray) -> Ranges:
    """The intervals [lo_i, hi_i] merged where they overlap, ascending."""
    out: Ranges = []
    for a, b in sorted(zip(lo.tolist(), hi.tolist(), strict=True)):
        if out and a <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], b))
        else:
            out.append((a, b))
    return out


def _farthest(p: np.ndarray) -> float:
    return float(np.hypot(p[:, 0], p[:, 1]).max())


def tolerance(mesh: Blank, ranges: RadialRanges) -> float:
    """How far past a ring's bounds the check still counts a node (m): at least region_mask's
    REGION_TOLERANCE of the mesh's extent, bounded here by twice its largest radius in the
    plane or its height out of it (an imperfection's, a tube's). Doubled, since the ranges'
    ends (cos(pi / n), shapely's distances) and the nodes' radii (made by the mesher) are
    computed apart and may differ in their last bits, far less than the tolerance itself."""
    extent = max(2.0 * max(hi for _, hi in ranges.nodes), abs(mesh.imperfection), ranges.height)
    return 2.0 * REGION_TOLERANCE * extent


def ranges_needed(mesh: Blank, regions: Sequence[RegionSpec]) -> RadialRanges | None:
    """``mesh``'s radial ranges where a check reads them: for its ring regions, or cheap (a
    fine outline's are not: without a ring it is left to the build's checks)."""
    if any(r.ring is not None for r in regions) or getattr(mesh, "kind", "") != "outline":
        return mesh.radial_ranges()
    return None


def sheet_problem(thickness: float | None, ranges: RadialRanges | None) -> str | None:
    """A constant thickness more than the blank is across at all (twice its largest radius,
    or its height along z), as ``shell.thickness: ...``: a typo (100 mm on a 60 mm disk)
    refused when the scene is read, not after Start (the build's check_sheet, which measures
    the built blank, holds the finer rule)."""
    if thickness is None or ranges is None:
        return None
    across = max(2.0 * max(hi for _, hi in ranges.nodes), ranges.height)
    if thickness <= across:
        return None
    return (f"shell.thickness: {1e3 * thickness:.4g} mm thick, more than the blank is across "
            f"({1e3 * across:.4g} mm at most): not a sheet")


def ring_problem(mesh: Blank, regions: Sequence[RegionSpec],
                 ranges: RadialRanges | None = None) -> str | None:
    """The first ring region of ``regions`` that selects no node of ``mesh`` (no interval of its
    radial_ranges, ``ranges`` when already read, meets the ring), as ``regions.N.ring: ...``;
    None when each may select some or the mesh is known only once built."""
    rings = [(i, r) for i, r in enumerate(regions) if r.ring is not None]
    if not rings:
        return None
    ranges = ranges or mesh.radial_ranges()
    if ranges is None:
        return None
    tol = tolerance(mesh, ranges)
    for i, region in rings:
        spans = ranges.boundary if region.boundary else ranges.nodes
        if not any(a <= region.ring.outer + tol and region.ring.r_min - tol <= b
                   for a, b in spans):
            return f"regions.{i}.ring: {_missed(region, spans)}"
    return None


def _missed(region: RegionSpec, spans: Ranges) -> str:
    # in mm, as the form shows a ring's radii (the scene file's are in m)
    which = "boundary node" if region.boundary else "node"
    where = " or ".join(f"{1e3 * a:.4g} to {1e3 * b:.4g} mm" for a, b in spans)
    ring = region.ring
    span = (f"{1e3 * ring.r_min:.4g} mm or more" if ring.r_max is None
            else f"{1e3 * ring.r_min:.4g} to {1e3 * ring.r_max:.4g} mm")
    return (f"region {region.name!r} selects no node: no {which} of the blank lies {span} "
            f"from the z axis (they lie {where} from it)")

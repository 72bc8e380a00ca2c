"""Where a flat generated blank's nodes lie, known without meshing it: the distances from the z
axis of its nodes and of its boundary nodes. With them a scene is checked, when it is read,
for a ring region that selects no node (an edit of the blank's radius that leaves the rim
ring outside the blank), which the build (sim.model.dirichlet.region_mask) would otherwise
find only when the model is made: the page's form says so at the field as it is edited.

The ranges hold every node the build makes (a superset: a ring inside them may still fall
between nodes, which the build then names), so the check never refuses a scene that builds.
"""

from __future__ import annotations

import numpy as np

from sim.geometry import outline
from sim.geometry import trimesh as meshes
from sim.scene.boundary import RegionSpec
from sim.scene.sheet import MeshSpec

Ranges = list[tuple[float, float]]


def radial_ranges(mesh: MeshSpec, boundary: bool) -> Ranges | None:
    """Intervals of the distance from the z axis (m) that hold every node of the built mesh
    (only its boundary nodes: ``boundary``); None for a mesh known only once built (a file, a
    drawing, a curved patch, a cylinder)."""
    import shapely

    if mesh.kind in ("disk", "annulus"):
        # vertices on circles, edge nodes on their chords: the hole's lie inside its circle
        r0 = getattr(mesh, "r_inner", 0.0)
        n0 = meshes.ring_vertices(r0, mesh.edge_length)
        return [(r0 * np.cos(np.pi / n0), mesh.r_outer)]
    if mesh.kind == "rectangle":
        (x0, y0), (lx, ly) = mesh.origin, mesh.size
        loops = [np.array([[x0, y0], [x0 + lx, y0], [x0 + lx, y0 + ly], [x0, y0 + ly]])]
    elif mesh.kind == "outline" and mesh.path is None:
        # the loops as meshed: resampled at the edge length, every boundary node on their
        # chords (a band's finer division too) and every other node inside them
        shape = mesh.shape()
        loops = [outline.resample(p, mesh.edge_length) for p in (shape.outer, *shape.holes)]
    else:
        return None
    # the nearest point to the axis: 0 inside; the farthest: a vertex (of the outer loop)
    axis = shapely.Point(0.0, 0.0)
    if boundary:
        return [(axis.distance(shapely.LinearRing(p)), _farthest(p)) for p in loops]
    return [(axis.distance(shapely.Polygon(loops[0], loops[1:])), _farthest(loops[0]))]


def _farthest(p: np.ndarray) -> float:
    return float(np.hypot(p[:, 0], p[:, 1]).max())


def ring_problem(mesh: MeshSpec, region: RegionSpec) -> str | None:
    """Why ``region``'s ring selects no node of ``mesh`` (no interval of radial_ranges meets
    it), or None: it may select some, or the mesh is known only once built."""
    ranges = radial_ranges(mesh, region.boundary)
    if region.ring is None or ranges is None:
        return None
    # region_mask's tolerance is 1e-9 of the mesh's extent: at most twice its largest radius
    # in the plane, or the imperfection's height out of it (doubled, to stay on the safe side)
    extent = max(2.0 * max(hi for _, hi in ranges), abs(mesh.imperfection))
    tol = 2e-9 * extent + 1e-300
    lo, hi = region.ring.r_min - tol, region.ring.r_max + tol
    if any(a <= hi and lo <= b for a, b in ranges):
        return None
    which = "boundary node" if region.boundary else "node"
    where = ", ".join(f"{a:.4g}-{b:.4g} m" for a, b in ranges)
    return (f"selects no node: no {which} of the blank lies {region.ring.r_min:.4g}-"
            f"{region.ring.r_max:.4g} m from the z axis (they lie within {where} of it)")

"""Builders of SDF programs (sim.tools.program): primitives, the forming tools made of them
(punch, die ring, blank holder, stars, extruded polygons), CSG and placement. Each returns a
complete, validated program; the combinators splice their operands' bodies, so programs
nest freely."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from sim.tools.polygon import ccw, offset_polygon, rounded_polygon, star_points
from sim.tools.pose import pose
from sim.tools.program import (
    OP_BOX,
    OP_INTERSECT,
    OP_PLANE,
    OP_POP_FRAME,
    OP_PUSH_FRAME,
    OP_REVOLVE,
    OP_RSWEEP,
    OP_SUBTRACT,
    OP_SWEEP,
    OP_UNION,
    RCORNER,
    body,
    program,
    record,
)


def plane(point: npt.ArrayLike, normal: npt.ArrayLike) -> np.ndarray:
    """Half-space tool {n.(x - p) <= 0}: the material lies opposite to ``normal``; p, n (3,)."""
    n = np.asarray(normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    return program(record(OP_PLANE, np.concatenate([np.asarray(point, float), n])))


def rounded_box(half_extents: npt.ArrayLike, radius: float,
                center: npt.ArrayLike = (0.0, 0.0, 0.0)) -> np.ndarray:
    """Box of half extents ``half_extents`` (3,) centred at ``center`` (3,), edges rounded."""
    h = np.asarray(half_extents, dtype=np.float64)
    if h.shape != (3,) or np.any(h <= 0):
        raise ValueError("half_extents must be 3 positive numbers")
    if not 0.0 <= radius <= h.min():
        raise ValueError("radius must lie in [0, min(half_extents)]")
    return program(record(OP_BOX, np.concatenate([np.asarray(center, float), h, [radius]])))


def box(half_extents: npt.ArrayLike, center: npt.ArrayLike = (0.0, 0.0, 0.0)) -> np.ndarray:
    """Sharp-edged box (a rounded box with radius 0)."""
    return rounded_box(half_extents, 0.0, center)


def revolved(r0: float, r1: float, z0: float, z1: float, radius: float = 0.0) -> np.ndarray:
    """Solid of revolution about z of the rounded rectangle [r0, r1] x [z0, z1] (rho, z).

    r0 <= 0: the solid reaches the axis (a capped cylinder; no corner at the axis).
    """
    lo = -np.inf if r0 <= 0.0 else float(r0)
    if not (r1 > max(r0, 0.0) and z1 > z0 and np.isfinite(r1)):
        raise ValueError("revolved: need max(r0, 0) < r1 < inf and z0 < z1")
    width = r1 - lo if np.isfinite(lo) else 2.0 * r1
    if not 0.0 <= radius <= 0.5 * min(width, z1 - z0):
        raise ValueError("revolved: corner radius larger than half the profile")
    return program(record(OP_REVOLVE, [lo, r1, z0, z1, radius]))


def punch(radius: float, height: float, edge_radius: float) -> np.ndarray:
    """Cylindrical punch: rho <= radius, 0 <= z <= height, nose (z = 0) edge rounded.

    The local origin is the centre of the nose face; both rims are rounded with edge_radius
    (the upper one never touches the sheet).
    """
    return revolved(0.0, radius, 0.0, height, edge_radius)


def die_ring(opening_radius: float, outer_radius: float, height: float,
             shoulder_radius: float) -> np.ndarray:
    """Die: opening_radius <= rho <= outer_radius, -height <= z <= 0, shoulder rounded.

    The top face is z = 0, the shoulder is the rounded rim at (opening_radius, 0); the other
    three rims of the ring cross-section carry the same radius.
    """
    return revolved(opening_radius, outer_radius, -height, 0.0, shoulder_radius)


def blank_holder(inner_radius: float, outer_radius: float, height: float,
                 edge_radius: float = 0.0) -> np.ndarray:
    """Blank holder ring: inner_radius <= rho <= outer_radius, 0 <= z <= height."""
    return revolved(inner_radius, outer_radius, 0.0, height, edge_radius)


def sweep(points2d: npt.ArrayLike, lo: float, hi: float, z0: float, z1: float,
          radius: float = 0.0) -> np.ndarray:
    """Raw SWEEP primitive (see module docstring); points2d (m, 2), made counter-clockwise."""
    p = ccw(points2d)
    if not (z1 > z0 and hi > lo and not (np.isinf(lo) and np.isinf(hi))):
        raise ValueError("sweep: need lo < hi (not both infinite) and z0 < z1")
    width = hi - lo if np.isfinite(hi - lo) else np.inf
    if not 0.0 <= radius <= 0.5 * min(width, z1 - z0):
        raise ValueError("sweep: corner radius larger than half the profile")
    return program(record(OP_SWEEP, np.concatenate([[lo, hi, z0, z1, radius, p.shape[0]],
                                                      p.ravel()])))


def rounded_sweep(corners: npt.ArrayLike, lo: float, hi: float, z0: float, z1: float,
                  radius: float = 0.0) -> np.ndarray:
    """Raw RSWEEP primitive: SWEEP (see the module docstring) over a rounded polygon
    (``rounded_polygon``), w its exact signed distance."""
    C = np.asarray(corners, dtype=np.float64)
    if C.ndim != 2 or C.shape[1] != RCORNER or C.shape[0] < 3:
        raise ValueError("corners must be (m >= 3, 8) rows of rounded_polygon")
    if not (z1 > z0 and hi > lo and not (np.isinf(lo) and np.isinf(hi))):
        raise ValueError("sweep: need lo < hi (not both infinite) and z0 < z1")
    width = hi - lo if np.isfinite(hi - lo) else np.inf
    if not 0.0 <= radius <= 0.5 * min(width, z1 - z0):
        raise ValueError("sweep: corner radius larger than half the profile")
    return program(record(OP_RSWEEP, np.concatenate([[lo, hi, z0, z1, radius, C.shape[0]],
                                                       C.ravel()])))


def extruded_polygon(points2d: npt.ArrayLike, z0: float, z1: float, corner_radius: float = 0.0,
                     edge_radius: float = 0.0, reflex_radius: float = 0.0) -> np.ndarray:
    """Prism over a simple 2-D polygon ``points2d`` (m, 2) between z0 and z1.

    corner_radius rounds the convex vertical edges, reflex_radius the reflex ones (0: sharp,
    a C0 ridge of the distance on the bisector outside). edge_radius rounds the rims of both
    caps; it must not exceed corner_radius (the cap rounding follows the outline offset
    inward by edge_radius, whose convex arcs have radius corner_radius - edge_radius).
    Without reflex rounding the polygon is offset inward by corner_radius and swept (SWEEP);
    with it the rounded polygon is swept (RSWEEP). Both are exact distances.
    """
    if corner_radius < 0.0 or edge_radius < 0.0 or edge_radius > corner_radius:
        raise ValueError("need 0 <= edge_radius <= corner_radius")
    if reflex_radius < 0.0:
        raise ValueError("need reflex_radius >= 0")
    if reflex_radius > 0.0:
        p = ccw(points2d)
        u = np.roll(p, -1, axis=0) - p
        v = p - np.roll(p, 1, axis=0)
        convex = v[:, 0] * u[:, 1] - v[:, 1] * u[:, 0] >= 0.0
        corners = rounded_polygon(p, np.where(convex, corner_radius, reflex_radius))
        return rounded_sweep(corners, -np.inf, 0.0, z0, z1, edge_radius)
    inner = offset_polygon(points2d, -corner_radius) if corner_radius > 0 else ccw(points2d)
    return sweep(inner, -np.inf, corner_radius, z0, z1, edge_radius)


def star(n_points: int, r_outer: float, r_inner: float, height: float, corner_radius: float = 0.0,
         edge_radius: float = 0.0, phase: float = 0.0, valley_radius: float = 0.0) -> np.ndarray:
    """Star-shaped prism (punch, or a form block), 0 <= z <= height; tips rounded by
    corner_radius, valleys (reflex corners) by valley_radius (0: sharp)."""
    return extruded_polygon(star_points(n_points, r_outer, r_inner, phase), 0.0, height,
                            corner_radius, edge_radius, valley_radius)


def star_die(n_points: int, r_outer: float, r_inner: float, height: float, shoulder_radius: float,
             corner_radius: float = 0.0, width: float | None = None, phase: float = 0.0,
             valley_radius: float | None = None) -> np.ndarray:
    """Die plate with a star-shaped opening: top face z = 0, bottom z = -height.

    The opening is the star with its tips rounded by corner_radius and its valleys by
    valley_radius (default max(corner_radius, shoulder_radius)): both are arcs of the exact
    rounded outline (RSWEEP), so the distance is C1 in the opening, valleys included; only a
    valley_radius of 0 leaves a sharp vertical edge there (C0 on its bisector). The shoulder
    (rim of the opening) is rounded by shoulder_radius exactly; that needs the shoulder's
    centre line, the outline offset by shoulder_radius into the plate, to stay regular, i.e.
    valley_radius >= shoulder_radius. The plate extends ``width`` (default r_inner) beyond
    the opening, so its outer outline is an offset curve of the star (the SDF is exact for any
    width; for widths at which that outline would fold the display mesh falls back to
    implicit meshing).
    """
    width = float(r_inner if width is None else width)
    if width <= 2.0 * shoulder_radius:
        raise ValueError("star_die: width must exceed twice the shoulder radius")
    rv = max(corner_radius, shoulder_radius) if valley_radius is None else float(valley_radius)
    if rv < shoulder_radius:
        raise ValueError("star_die: valley_radius must be >= the shoulder radius")
    pts = star_points(n_points, r_outer, r_inner, phase)
    radii = np.where(np.arange(len(pts)) % 2 == 0, corner_radius, rv)
    return rounded_sweep(rounded_polygon(pts, radii), 0.0, width, -height, 0.0,
                         shoulder_radius)


def _combine(op: int, a: np.ndarray, b: np.ndarray, blend: float) -> np.ndarray:
    if blend < 0.0:
        raise ValueError("blend must be >= 0")
    return program(np.concatenate([body(a), body(b), record(op, [blend])]))


def union(a: np.ndarray, b: np.ndarray, blend: float = 0.0) -> np.ndarray:
    """a or b: exact min for blend = 0 (C0 crease), cubic smooth min (C2) of width blend."""
    return _combine(OP_UNION, a, b, blend)


def intersect(a: np.ndarray, b: np.ndarray, blend: float = 0.0) -> np.ndarray:
    """a and b: exact max for blend = 0, smooth max of width blend."""
    return _combine(OP_INTERSECT, a, b, blend)


def subtract(a: np.ndarray, b: np.ndarray, blend: float = 0.0) -> np.ndarray:
    """a minus b = max(a, -b): exact for blend = 0, smooth (filleted) for blend > 0."""
    return _combine(OP_SUBTRACT, a, b, blend)


def moved(a: np.ndarray, R: npt.ArrayLike | None = None,
          t: npt.ArrayLike | None = None) -> np.ndarray:
    """Place program a with pose (R (3, 3), t (3,)) inside a tool: x_a = R^T (x - t)."""
    R, t = pose(R, t)
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-12) or np.linalg.det(R) < 0:
        raise ValueError("R must be a proper rotation")
    return program(np.concatenate([record(OP_PUSH_FRAME, np.concatenate([R.ravel(), t])),
                                    body(a), record(OP_POP_FRAME, [])]))



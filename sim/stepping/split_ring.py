"""The split-ring (Demeri) springback test as a stage after a formed cup.

A ring is cut from the cup's wall and split along a meridian; the residual hoop stresses of
the wall, released by the split, open it (Demeri, Lou and Saran, SAE 2000-01-0413; Coer et al.
2018 on AA5754-O). Here, from a run's final state (final.npz: the positions, the committed
plastic state, the scene, sim.frames.output.write):

1. the band: the elements whose formed mid-surface centroid lies between two heights above the
   cup's bottom (the lowest point of the formed mid-surface), each on the wall (its surface
   steeper than ``WALL``), without the elements that would hang on by a vertex;
2. the closed ring is released: no tools, no neighbouring material, held statically
   determinately (sim.geometry.rigid, as the springback stage holds a part), Newton to
   equilibrium with the carried plastic state (elastic unloading; re-yield where it comes);
3. the ring is split: the in-plane nodes shared by the elements on either side of the meridian
   plane at ``cut_angle`` (the elements' formed centroids) are duplicated for the elements
   below it (those just short of a full turn), and the ring released again.

The plastic state lives in the rest (blank) configuration (G = F Fp^-1, sim.terms.elasticity),
so the ring's elements keep their rest positions and carry their Fp^-1 and plastic strain as
they are; a duplicated node is a copy of its node, at rest and formed. The energy terms and
Newton are the run's, unchanged.

What is measured (lengths in m): the opening, the gap between the cut's two faces along the
ring's circumference at the ring's mid-height (the mid-surface of each duplicated vertex
against its twin, interpolated in height), and the ring's diameters: the mean (a least-squares
circle through the mid-surface) and along 0 and 90 degrees to the cut's meridian (the mean
radius within ``WINDOW`` of the direction and of its opposite, or beyond the cut's faces where
the gap spans the direction), formed, released and split.
The cup's axis is the scene's z axis through the origin.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim.elements import get_element
from sim.frames.fields import mid_surface
from sim.geometry.quadrature import Rule
from sim.geometry.rigid import determinate_support
from sim.geometry.shell import Shell, extrude
from sim.geometry.trimesh import TriMesh, patches, small_patches
from sim.model import terms as parts
from sim.model.build import newton_settings
from sim.model.sheet import mesh_and_thickness, rule_of
from sim.scene.load import Scene, scene_from_dict
from sim.solve.assembly import build_pattern
from sim.solve.linsolve import make_solver
from sim.solve.newton import Iterated, minimise
from sim.solve.problem import Problem
from sim.stepping.wall import WALL
from sim.terms.elasticity import Elasticity

# half-width (degrees) of the sector whose mean radius gives a diameter's end: three to four
# vertex columns of the 2 mm cup's wall (R = 17 mm), so a diameter averages over the mesh
WINDOW = 7.5
# what split_ring does, in the order it does it, in a forming engineer's words (its progress
# names them by key): a ring of a fine cup takes minutes, its releases most of them
STAGES = {"band": "cutting the band from the wall",
          "closed": "releasing the closed ring",
          "split": "splitting the ring along its meridian",
          "opened": "releasing the split ring",
          "measure": "measuring the opening and the diameters"}


class SplitRingError(ValueError):
    """Bad input: no run there, a run without what the stage needs, heights off the wall."""


@dataclass(frozen=True)
class Report:
    """Where the test is: its ``stage`` (a key of STAGES, or a caller's own, such as reading
    the run) and, in a release, Newton's last iterate: its ``iteration`` (0: the ring as cut),
    ``residual`` and the residual it converges below, ``target`` (N)."""

    stage: str
    iteration: int | None = None
    residual: float | None = None
    target: float | None = None


Progress = Callable[[Report], None]


def _quiet(report: Report) -> None:
    """No one is told."""


def _iterations(progress: Progress, stage: str) -> Iterated:
    """Newton's iterates as reports of ``stage``."""
    return lambda it, residual, target: progress(Report(stage, it, residual, target))


@dataclass
class Formed:
    """A run's final state: its scene, the sheet's shell and quadrature rule as the run built
    them, the formed positions ``x (n_nodes, 3)`` and the plastic state per element and
    quadrature point ``fp_inv (n_elem, n_qp, 3, 3)``, ``ep (n_elem, n_qp)``."""

    scene: Scene
    shell: Shell
    rule: Rule
    x: np.ndarray
    fp_inv: np.ndarray
    ep: np.ndarray


def sheet_of(scene: Scene) -> tuple[Shell, Rule]:
    """The sheet's shell and quadrature rule as ``build_model`` makes them (no tools)."""
    elem = get_element(scene.shell.element)
    mesh, h, _ = mesh_and_thickness(scene)
    rule_spec, _ = rule_of(scene, elem, mesh)
    return extrude(mesh, h, elem), elem.quadrature(rule_spec)


def open_formed(folder: Path) -> Formed:
    """The final state of the run in ``folder``; SplitRingError naming what is missing."""
    final = folder / "final.npz"
    if not folder.is_dir():
        raise SplitRingError(f"RUN: {folder}: no such run folder")
    if not final.is_file():
        raise SplitRingError(f"RUN: {folder}: no final.npz (a run that ended before its final "
                             "state)")
    with np.load(final) as z:
        data = dict(z)
    if "scene" not in data:
        raise SplitRingError(f"RUN: {final}: no scene in it (written before the split-ring "
                             "stage existed): run the scene again")
    scene = scene_from_dict(json.loads(str(data["scene"])))
    if "fp_inv" not in data or "ep" not in data:
        raise SplitRingError(f"RUN: {final}: no plastic state (fp_inv, ep): material.model is "
                             f"{scene.material.model!r}; the split ring opens by the residual "
                             "stresses of plastic forming (material.model = 'plastic')")
    shell, rule = sheet_of(scene)
    if data["conn"].shape != shell.conn.shape or not np.array_equal(data["conn"], shell.conn):
        raise SplitRingError(f"RUN: {final}: its mesh is not the one its scene builds here")
    return Formed(scene, shell, rule, data["deformed"], data["fp_inv"], data["ep"])


@dataclass
class Ring:
    """The band cut from the part: its own shell (``nodes``: the part's node of each of its
    nodes, a duplicated node sharing its twin's), ``elements`` the part's element of each of
    its elements; ``twins (k, 2)``: per mid-surface vertex duplicated by :func:`cut`, the
    vertex of the elements above the meridian plane and its copy, taken by those below (none
    in a closed ring). In-plane nodes that are not vertices (a quadratic element's) are
    numbered after the vertices but not edge by edge as ``extrude`` numbers them: nothing the
    ring reads (its energy, its mid-surface and skins) depends on that."""

    shell: Shell
    nodes: np.ndarray
    elements: np.ndarray
    twins: np.ndarray


def _sub_shell(shell: Shell, faces: np.ndarray, copy: np.ndarray, below: np.ndarray) -> Ring:
    """The shell of elements ``faces`` (element ids), the in-plane nodes ``copy (n_plane,)
    bool`` duplicated for the elements ``below (len(faces),) bool``. In-plane numbering as
    :func:`sim.geometry.shell.extrude` has it, vertices first."""
    n_plane, n_v, q = shell.n_plane, shell.n_vertices, shell.element.q
    n_tri = shell.conn.shape[1] // (q + 1)
    tri = shell.conn[faces, :n_tri]  # layer-0 nodes: the in-plane ids
    used = np.unique(tri)
    dup = np.unique(tri[below][copy[tri[below]]])
    # (old in-plane id, copy flag) in the new order: vertices first, then the other nodes
    old = np.concatenate([used[used < n_v], dup[dup < n_v], used[used >= n_v], dup[dup >= n_v]])
    twin = np.concatenate([np.zeros((used < n_v).sum(), bool), np.ones((dup < n_v).sum(), bool),
                           np.zeros((used >= n_v).sum(), bool), np.ones((dup >= n_v).sum(), bool)])
    new_id = {(int(a), bool(c)): i for i, (a, c) in enumerate(zip(old, twin, strict=True))}
    n_new = len(old)
    conn = np.empty((len(faces), shell.conn.shape[1]), np.int64)
    for e, f in enumerate(faces):
        for j, g in enumerate(shell.conn[f]):
            k, a = divmod(int(g), n_plane)
            conn[e, j] = k * n_new + new_id[(a, bool(below[e] and copy[a]))]
    nodes = np.concatenate([k * n_plane + old for k in range(q + 1)])
    n_vert = int((old < n_v).sum())
    mesh = TriMesh(shell.mesh.vertices[old[:n_vert]], conn[:, :3])
    sub = Shell(shell.element, mesh, shell.thickness[old[:n_vert]], shell.rest[nodes], conn,
                n_new, shell.plane_mid[old])
    pairs = [(new_id[(int(a), False)], new_id[(int(a), True)]) for a in dup if a < n_v]
    return Ring(sub, nodes, np.asarray(faces), np.array(pairs, np.int64).reshape(-1, 2))


def _prune(shell: Shell, keep: np.ndarray) -> np.ndarray:
    """``keep (n_elem,) bool`` without the patches of one or two elements that hang on by a
    vertex (they have spurious modes under Q3T's one-point rule, sim.elements.q3t; a run
    takes the 3 x 3 rule for a mesh with such patches, sim.model.sheet, but the ring keeps the
    run's rule), repeated until none is left."""
    keep = keep.copy()
    while True:
        ids = np.flatnonzero(keep)
        # all pruned: no patch is left to label (the caller says the band is no ring)
        small = small_patches(shell.mesh.faces[ids]) if len(ids) else []
        if not len(small):
            return keep
        keep[ids[small]] = False


def heights(formed: Formed) -> tuple[np.ndarray, float, float, np.ndarray]:
    """Per element, its formed mid-surface centroid ``(n_elem, 3)``; the cup's bottom and top
    (the lowest and highest z of the formed mid-surface) and each element's inclination from
    the horizontal (degrees)."""
    mid = mid_surface(formed, formed.x)
    F = formed.shell.mesh.faces
    c = mid[F].mean(1)
    n = np.cross(mid[F[:, 1]] - mid[F[:, 0]], mid[F[:, 2]] - mid[F[:, 0]])
    n /= np.linalg.norm(n, axis=1)[:, None]
    tilt = np.degrees(np.arccos(np.clip(np.abs(n[:, 2]), 0, 1)))
    return c, float(mid[:, 2].min()), float(mid[:, 2].max()), tilt


def band(formed: Formed, z1: float, z2: float) -> np.ndarray:
    """The elements (ids) of the wall between heights ``z1 < z2`` (m above the cup's bottom);
    SplitRingError naming ``heights`` when the band is off the part, off its wall or not a
    closed ring around the axis."""
    c, bottom, top, tilt = heights(formed)
    h, top = c[:, 2] - bottom, top - bottom
    if not 0.0 <= z1 < z2:
        raise SplitRingError(f"heights: {1e3 * z1:g}, {1e3 * z2:g} mm: need 0 <= z1 < z2 (mm "
                             "above the cup's bottom)")
    if z2 > top:
        raise SplitRingError(f"heights: {1e3 * z2:g} mm is above the part (its top is "
                             f"{1e3 * top:.2f} mm above the bottom)")
    keep = (h >= z1) & (h <= z2)
    if not keep.any():
        raise SplitRingError(f"heights: no element between {1e3 * z1:g} and {1e3 * z2:g} mm")
    off = keep & (tilt < WALL)
    if off.any():
        raise SplitRingError(
            f"heights: {1e3 * z1:g}-{1e3 * z2:g} mm is not all on the wall: {off.sum()} "
            f"element(s) there are inclined less than {WALL:g} degrees from the horizontal "
            f"(lowest {tilt[off].min():.0f} deg at {1e3 * h[off].min():.2f} mm): the ring is "
            "cut from the steep wall")
    keep = _prune(formed.shell, keep)
    ids = np.flatnonzero(keep)
    angles = np.sort(np.arctan2(c[ids, 1], c[ids, 0]))
    gap = np.degrees(np.diff(np.concatenate([angles, angles[:1] + 2 * np.pi])).max()
                     ) if len(ids) else 360.0
    if len(ids) < 3 or gap > 30.0 or patches(formed.shell.mesh.faces[ids]).max() > 0:
        raise SplitRingError(f"heights: {1e3 * z1:g}-{1e3 * z2:g} mm is not one closed ring "
                             "around the axis: the elements whose centres lie in the band "
                             "leave gaps (widen it, or cut from a run on a finer mesh)")
    return ids


def cut(formed: Formed, ids: np.ndarray, cut_angle: float = 0.0) -> Ring:
    """The ring of elements ``ids`` split along the meridian plane at ``cut_angle`` (rad about
    z from x): the in-plane nodes that elements on both sides of the plane share on the
    ``cut_angle`` half share no more; the elements just below the plane (centroid at a
    negative angle from it) take the copies."""
    sh = formed.shell
    mid = mid_surface(formed, formed.x)
    ca, sa = math.cos(cut_angle), math.sin(cut_angle)
    n_tri = sh.conn.shape[1] // (sh.element.q + 1)
    tri = sh.conn[ids, :n_tri]
    pos = formed.x[: sh.n_plane]  # each in-plane node's side, from its bottom-skin node
    c = mid[sh.mesh.faces[ids]].mean(1)
    below = (-c[:, 0] * sa + c[:, 1] * ca) < 0
    on = np.zeros(sh.n_plane, bool)
    np.logical_or.at(on, tri[below].ravel(), True)
    above = np.zeros(sh.n_plane, bool)
    np.logical_or.at(above, tri[~below].ravel(), True)
    copy = on & above & (pos[:, 0] * ca + pos[:, 1] * sa > 0)
    ring = _sub_shell(sh, ids, copy, below)
    if patches(ring.shell.mesh.faces).max() > 0:
        raise SplitRingError("heights: the split ring has elements hanging on by a vertex at "
                             "the cut: widen the band or move the cut (--cut-angle)")
    return ring


@dataclass
class Stage:
    """The ring's term and problem: its elasticity with the carried plastic state, held by
    the determinate supports of its rigid-body modes."""

    ring: Ring
    elasticity: Elasticity
    problem: Problem
    support: list[tuple[int, int]]

    @property
    def shell(self) -> Shell:
        return self.ring.shell


def stage(formed: Formed, ring: Ring, fp_inv: np.ndarray, ep: np.ndarray,
          x: np.ndarray) -> Stage:
    """The ring's problem at positions ``x`` (n_ring_nodes, 3), its elements carrying
    ``fp_inv``, ``ep`` (per ring element)."""
    sh = ring.shell
    pattern = build_pattern(sh.conn, sh.n_nodes, None)
    el = parts.elasticity(formed.scene, sh, formed.rule, pattern)
    if el.plastic:
        el.fp_inv[:], el.ep[:] = fp_inv, ep
    held = np.zeros((sh.n_nodes, 3), bool)
    support = determinate_support(x, held, sh.layer_nodes(0))
    for node, comp in support:
        held[node, comp] = True
    problem = Problem([el], pattern, make_solver(pattern, formed.scene.solver.linear_solver),
                      held)
    return Stage(ring, el, problem, support)


def release(formed: Formed, st: Stage, x: np.ndarray,
            iterated: Iterated | None = None) -> tuple[np.ndarray, dict]:
    """Static equilibrium of the free ring from ``x``, committed (re-yield, if any, enters its
    plastic state); the solver's numbers. Its force reference is the force the release
    frees: the residual at ``x`` (zero for a stress-free ring, which then stays where it is).
    ``iterated``: told of each Newton iterate (sim.solve.newton.Iterated)."""
    g0 = st.problem.gradient(x)
    level = float(np.linalg.norm(g0[~st.problem.fixed]))
    res = minimise(st.problem, x, newton_settings(formed.scene, st.shell), level,
                   iterated=iterated)
    if not res.converged:
        raise RuntimeError(f"the ring's release did not converge: {res.reason}")
    st.elasticity.commit(res.x)
    g = st.problem.gradient(res.x)
    reaction = max((abs(float(g[n, c])) for n, c in st.support), default=0.0)
    return res.x, {"iterations": res.iterations, "released_force": level,
                   "residual": float(res.residuals[-1]) if res.residuals else 0.0,
                   "support_reaction": reaction}


def circle(P: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre ``(2,)`` and radius of the least-squares circle (algebraic fit) through the
    x-y projection of points ``P (n, 3)``."""
    x, y = P[:, 0], P[:, 1]
    A = np.column_stack([x, y, np.ones_like(x)])
    (D, E, F), *_ = np.linalg.lstsq(A, -(x * x + y * y), rcond=None)
    c = np.array([-D / 2, -E / 2])
    return c, float(math.sqrt(max(c @ c - F, 0.0)))


def diameters(P: np.ndarray, cut_angle: float) -> dict:
    """The ring's diameters from its mid-surface vertices ``P (n, 3)``: the mean (twice the
    least-squares circle's radius) and along 0 and 90 degrees to the cut's meridian (the mean
    distance from the circle's centre within WINDOW degrees of each end; where a split ring's
    gap is wider than that, as it is once it opens by more than about 2 WINDOW R, within
    WINDOW beyond the nearer of the cut's faces)."""
    c, R = circle(P)
    d = P[:, :2] - c
    r, phi = np.hypot(d[:, 0], d[:, 1]), np.arctan2(d[:, 1], d[:, 0]) - cut_angle
    win = math.radians(WINDOW)

    def across(a: float) -> float:
        ends = []
        for b in (a, a + math.pi):
            off = np.abs(np.angle(np.exp(1j * (phi - b))))
            near = off <= win
            if not near.any():  # the split ring's gap spans b: its faces' ends instead
                near = off <= off.min() + win
            ends.append(float(r[near].mean()))
        return ends[0] + ends[1]

    return {"mean": 2 * R, "d0": across(0.0), "d90": across(math.pi / 2),
            "centre": c.tolist()}


def opening(ring: Ring, P: np.ndarray, P_formed: np.ndarray, z_mid: float,
            cut_angle: float) -> dict:
    """The gap between the cut's faces: per duplicated mid-surface vertex and its twin, the
    twin (above the meridian plane) less its copy, along the ring's circumference there
    (positive: the ring opened) and in full; at the ring's mid-height ``z_mid`` (absolute z of
    the formed state) interpolated along the cut by the vertices' formed height."""
    a, b = ring.twins[:, 0], ring.twins[:, 1]
    gap = P[a] - P[b]
    c, _ = circle(P)
    m = 0.5 * (P[a] + P[b])
    radial = (m[:, :2] - c) / np.linalg.norm(m[:, :2] - c, axis=1)[:, None]
    hoop = np.column_stack([-radial[:, 1], radial[:, 0], np.zeros(len(a))])
    along = np.einsum("ij,ij->i", gap, hoop)
    full = np.linalg.norm(gap, axis=1)
    z = P_formed[a, 2]
    order = np.argsort(z)
    return {"at_mid_height": float(np.interp(z_mid, z[order], along[order])),
            "distance_at_mid_height": float(np.interp(z_mid, z[order], full[order])),
            "min": float(along.min()), "max": float(along.max()),
            "vertices_on_cut": len(a)}


def _reyield(before: np.ndarray, after: np.ndarray) -> dict:
    grew = after - before
    return {"fraction": float(np.mean(grew > 0)), "max": float(grew.max(initial=0.0))}


@dataclass
class Result:
    """What the test gives (SI: m); ``states``: the ring's positions formed, released closed
    and split (n_ring_nodes, 3)."""

    summary: dict
    ring: Ring
    states: dict[str, np.ndarray]


def split_ring(formed: Formed, z1: float, z2: float, cut_angle: float = 0.0,
               progress: Progress = _quiet) -> Result:
    """The split-ring test on the formed state between heights ``z1 < z2`` (m above the cup's
    bottom), cut at ``cut_angle`` (rad from x about z). ``progress`` is told of each stage as
    it starts (STAGES, in their order) and of each Newton iterate of the releases."""
    progress(Report("band"))
    ids = band(formed, z1, z2)
    closed_ring = _sub_shell(formed.shell, ids, np.zeros(formed.shell.n_plane, bool),
                             np.zeros(len(ids), bool))
    # split now, not after the first release: a cut the ring cannot take is refused at once
    split = cut(formed, ids, cut_angle)
    progress(Report("closed"))
    x_formed = formed.x[closed_ring.nodes]
    st = stage(formed, closed_ring, formed.fp_inv[ids], formed.ep[ids], x_formed)
    x_closed, solve_closed = release(formed, st, x_formed, _iterations(progress, "closed"))
    progress(Report("split"))
    # the split ring's nodes from the closed ring's: a copy starts where its twin is
    where = {int(n): i for i, n in enumerate(closed_ring.nodes)}
    to_closed = np.array([where[int(n)] for n in split.nodes])
    x_start = x_closed[to_closed]
    st2 = stage(formed, split, st.elasticity.fp_inv, st.elasticity.ep, x_start)
    progress(Report("opened"))
    x_split, solve_split = release(formed, st2, x_start, _iterations(progress, "opened"))
    progress(Report("measure"))
    mid_formed = mid_surface(st2, formed.x[split.nodes])
    mid_closed, mid_split = mid_surface(st2, x_start), mid_surface(st2, x_split)
    _, bottom, _, _ = heights(formed)
    z_mid = bottom + 0.5 * (z1 + z2)
    summary = {
        "heights": [z1, z2], "cut_angle": math.degrees(cut_angle), "bottom_z": bottom,
        # the residual bending stress that opens the ring is integrated on these points
        "section_points": len(np.unique(formed.rule.points[:, 2])),
        "elements": len(ids), "nodes": split.shell.n_nodes,
        "duplicated_nodes": split.shell.n_nodes - closed_ring.shell.n_nodes,
        "ring_height": float(np.ptp(mid_formed[:, 2])),
        "opening": opening(split, mid_split, mid_formed, z_mid, cut_angle),
        "diameters": {"formed": diameters(mid_formed, cut_angle),
                      "released": diameters(mid_closed, cut_angle),
                      "split": diameters(mid_split, cut_angle)},
        # where a release yielded again: the share of quadrature points whose plastic strain
        # grew, and the largest growth
        "reyield": {"closed": _reyield(formed.ep[ids], st.elasticity.ep),
                    "split": _reyield(st.elasticity.ep, st2.elasticity.ep)},
        "solver": {"closed": solve_closed, "split": solve_split}}
    return Result(summary, split, {"formed": formed.x[split.nodes], "released": x_start,
                                   "split": x_split})

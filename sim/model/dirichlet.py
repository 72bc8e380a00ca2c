"""The prescribed DoFs of a scene: regions as node masks, its BCs as held DoFs with their
displacements, bends and keyframed motions, and what the release stage frees and holds."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.geometry import trimesh as meshes
from sim.geometry.shell import Shell
from sim.scene.boundary import REGION_TOLERANCE, BCSpec, RegionSpec
from sim.scene.load import Scene


def region_mask(shell: Shell, r: RegionSpec) -> np.ndarray:
    """Selected in-plane nodes ``(n_plane,)`` by their rest mid-surface position."""
    X = shell.plane_mid
    scale = np.ptp(shell.mesh.vertices, axis=0).max()
    tol = REGION_TOLERANCE * scale
    if r.box is not None:
        mask = np.all((X >= np.array(r.box.min) - tol) & (X <= np.array(r.box.max) + tol), 1)
    elif r.ring is not None:
        rho = np.hypot(X[:, 0], X[:, 1])
        mask = (rho >= r.ring.r_min - tol) & (rho <= r.ring.outer + tol)
    else:
        n = np.asarray(r.plane.normal, float)
        n = n / np.linalg.norm(n)
        mask = np.abs((X - np.asarray(r.plane.point)) @ n) <= r.plane.tolerance
    if r.boundary:
        bnd = np.zeros(shell.n_plane, bool)
        bnd[np.unique(meshes.boundary_edges(shell.mesh.faces))] = True
        if shell.element.p > 1:  # edge nodes between two boundary vertices
            mask_v = bnd[: shell.n_vertices]
            for_e = _edge_node_owner(shell)
            bnd[shell.n_vertices: shell.n_vertices + len(for_e)] = mask_v[for_e].all(1)
        mask &= bnd
    if not mask.any():
        raise ValueError(f"regions.{r.name}: selects no node")
    return mask


def _edge_node_owner(shell: Shell) -> np.ndarray:
    uniq, _ = meshes.edges(shell.mesh.faces)
    return np.repeat(uniq, shell.element.p - 1, axis=0)


def arc_positions(X: np.ndarray, phi: float, a: float) -> np.ndarray:
    """End section at x = a of a strip bent about y into an arc of curvature phi / a (its
    symmetry plane x = 0 fixed): a point at height Z sits at radius 1/k - Z from the centre
    (0, ., 1/k). Series for small phi so the straight state is exact. X shape (n, 3)."""
    if abs(phi) < 1e-8:
        sinc, cosc = 1.0 - phi**2 / 6, phi / 2 - phi**3 / 24
    else:
        sinc, cosc = np.sin(phi) / phi, (1 - np.cos(phi)) / phi
    Z = X[:, 2]
    out = X.copy()
    out[:, 0] = a * sinc - Z * np.sin(phi)
    out[:, 2] = a * cosc + Z * np.cos(phi)
    return out



def column_nodes(shell: Shell, plane_mask: np.ndarray, layers: str = "all") -> np.ndarray:
    """The nodes of the in-plane nodes ``plane_mask`` on the thickness ``layers`` (all, bottom,
    top or mid)."""
    q, n = shell.element.q, shell.n_plane
    idx = np.flatnonzero(plane_mask)
    if layers == "all":
        ks = range(q + 1)
    elif layers == "bottom":
        ks = [0]
    elif layers == "top":
        ks = [q]
    else:
        if q % 2:
            raise ValueError("layers = 'mid' needs an element with a mid-surface layer")
        ks = [q // 2]
    return np.concatenate([k * n + idx for k in ks])


@dataclass
class Dirichlet:
    """The held DoFs ``(n_nodes + n_tool_dofs, 3)`` and how they move."""

    fixed: np.ndarray  # bool
    prescribed: np.ndarray  # displacement at the end of the ramp on fixed DoFs
    bends: list  # (node ids, BendSpec) moved along arcs
    # keyframed BCs: (node ids (m,), component ids (c,), times (k,), displacements (k, c)),
    # times starting at 0 with zero displacement
    motions: list
    released: np.ndarray | None  # bool: DoFs freed for springback (a scene with a release)
    release_support: np.ndarray | None  # bool: held only for springback


def dirichlet(scene: Scene, shell: Shell, regions: dict[str, np.ndarray], tools: list,
              n_total: int) -> Dirichlet:
    """The scene's BCs on a model of ``n_total`` rows, the rows past the shell's nodes the z
    offsets of force-controlled ``tools`` (held in x and y)."""
    fixed = np.zeros((n_total, 3), bool)
    fixed[shell.n_nodes:, :2] = True  # force-controlled tools move in z only
    out = Dirichlet(fixed, np.zeros((n_total, 3)), [], [], None, None)
    release_support = np.zeros((n_total, 3), bool)
    for i, bc in enumerate(scene.bcs):
        try:
            nodes = column_nodes(shell, regions[bc.region], bc.layers)
        except ValueError as exc:
            raise ValueError(f"bcs.{i}.layers: {exc}") from None
        comps = ["xyz".index(c) for c in bc.components]
        if bc.release_only:
            release_support[np.ix_(nodes, comps)] = True
        else:
            _hold(out, i, bc, nodes, comps)
    if scene.stepping.release:
        out.released = np.zeros_like(fixed)
        for bc in scene.bcs:
            if bc.release:
                nodes = column_nodes(shell, regions[bc.region], bc.layers)
                out.released[np.ix_(nodes, ["xyz".index(c) for c in bc.components])] = True
        retracted = {s.name for s in scene.tools if s.release}
        for t in tools:  # a retracted force-controlled tool's offset is held
            if t.vdof is not None and t.tool in retracted:
                release_support[t.vdof] = True
        out.release_support = release_support
    return out


def _hold(out: Dirichlet, i: int, bc: BCSpec, nodes: np.ndarray, comps: list[int]) -> None:
    """BC ``i`` holds ``comps`` of ``nodes``: displaced, bent or moved along keyframes."""
    if bc.bend is not None:
        # 'x' alone: the end section is turned by its layers' x but free to move across
        # the strip, so it carries a pure moment (no shear force; up to WALL_BEND,
        # sim.scene.boundary)
        if "x" not in bc.components:
            raise ValueError(f"bcs.{i}.bend: a bent end prescribes x (its rotation): "
                             "components must include 'x'")
        out.bends.append((nodes, bc.bend))
    if bc.keyframes:
        kf = np.asarray(bc.keyframes, float)
        if kf[0, 0] > 0:  # from rest at t = 0
            kf = np.vstack([np.zeros(kf.shape[1]), kf])
        out.motions.append((nodes, comps, kf[:, 0], kf[:, 1:]))
    for k in comps:
        out.fixed[nodes, k] = True
        out.prescribed[nodes, k] = bc.displacement[k]

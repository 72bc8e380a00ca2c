"""A scene's model size before it is built: vertices, elements, nodes and DoFs from the mesh
parameters alone (a generated mesh is not made, a mesh file is only read), and the memory the
build takes, so that a scene too large for the machine is refused at once, naming the field that
sets its size, instead of building for minutes until the machine runs out of memory.

Memory: the build's peak, which the solve has not exceeded in any measurement (the factor of
these thin-shell Hessians is smaller than the build's element arrays). Measured as peak RSS on
the AMD EPYC machine (cantilever strips and the cup disk; linear, q3t, quadratic, quartic;
0.2-1.35 M DoFs, 1-9 GiB): the process's base plus 43 bytes per entry of the elements' dense
DoF matrices, n_elem (3 n_en)^2, within 4 % on every case. BYTES_PER_ENTRY keeps a margin.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from sim.elements import get_element
from sim.geometry import outline
from sim.geometry import trimesh as meshes
from sim.model.sheet import outline_of
from sim.scene.load import Scene, SceneError
from sim.scene.sheet import MeshSpec
from sim.text import figure

BASE_BYTES = 0.3 * 2**30  # the solver process before any model (numpy, numba, MKL)
BYTES_PER_ENTRY = 48
# half of this 24 GiB machine: the other half for the server (its frame history, the viewer),
# the browser and the system
DEFAULT_LIMIT = 12 * 2**30
MAX_RINGS = 10**6  # an annulus with more rings is counted in closed form


@dataclass(frozen=True)
class ModelSize:
    vertices: int
    elements: int
    nodes: int
    dofs: int
    bytes: float  # peak memory of the build
    field: str  # the scene field that sets the size


def mesh_counts(spec: MeshSpec) -> tuple[int, int] | None:
    """Vertices and triangles of the mid-surface mesh the build will make (a file: read;
    None when it cannot be, the build says why). An outline's drawing that cannot be read or
    is no blank's size: SceneError naming the field, before any run."""
    if spec.kind == "file":
        return _file_counts(spec.path)
    if spec.kind in ("cylinder_patch", "sphere_patch"):
        return (spec.cells + 1) ** 2, 2 * spec.cells**2
    if spec.kind == "strip":
        return (spec.cells + 1) * (spec.across + 1), 2 * spec.cells * spec.across
    if spec.kind == "outline":
        try:
            n_v, n_f = outline.estimate(outline_of(spec), spec.edge_length)
        except outline.OutlineError as exc:  # refused here, before a run is started
            raise SceneError(f"mesh.{exc.field}: {exc}") from None
        extra = sum(b.triangles(spec.edge_length) for b in spec.bands)
        return n_v + int(extra / 2), n_f + int(extra)  # Euler: about a vertex per two
    e = spec.edge_length
    if spec.kind == "rectangle":
        nx, ny = (meshes.divisions(s, e) for s in spec.size)
        return (nx + 1) * (ny + 1), 2 * nx * ny
    if spec.kind == "cylinder_band":
        nt, nz = meshes.band_divisions(spec.radius, spec.height, e)
        return nt * (nz + 1), 2 * nt * nz
    if spec.kind in ("annulus", "disk"):
        r0 = 0.0 if spec.kind == "disk" else spec.r_inner
        if meshes.divisions(spec.r_outer - r0, e) > MAX_RINGS:  # the sum below, in closed form
            v = (spec.r_outer - r0) / e * math.pi * (r0 + spec.r_outer) / e
            return int(v), int(2 * v)
        _, counts = meshes.rings(r0, spec.r_outer, e)
        # each band between rings is stitched into n0 + n1 triangles (n1 around the centre)
        bands = zip(counts[:-1], counts[1:], strict=True)
        return sum(counts), sum(a + b - (a == 1) for a, b in bands)
    raise ValueError(f"mesh kind {spec.kind!r}: no count")


def _file_counts(path: str) -> tuple[int, int] | None:
    import trimesh

    try:
        m = trimesh.load(path, force="mesh", process=False)
        return len(m.vertices), len(m.faces)
    except Exception:  # noqa: BLE001 - trimesh's parsers raise anything; the build says why
        return None


def estimate(scene: Scene) -> ModelSize | None:
    """The size of ``scene``'s model; None for a mesh file that cannot be read (the build
    says why)."""
    elem = get_element(scene.shell.element)
    counts = mesh_counts(scene.mesh)
    if counts is None:
        return None
    n_v, n_f = counts
    n_e = n_v + n_f  # Euler: V - E + F is 1 for a disk, 0 for a ring or band
    p = elem.p
    n_plane = n_v + n_e * (p - 1) + n_f * (p - 1) * (p - 2) // 2
    nodes = n_plane * elem.n_layers
    k = 3 * elem.n_nodes
    return ModelSize(n_v, n_f, nodes, 3 * nodes, BASE_BYTES + BYTES_PER_ENTRY * n_f * k * k,
                     size_field(scene.mesh))


def size_field(spec: MeshSpec) -> str:
    """The scene field that sets the mesh's size."""
    if spec.kind == "file":
        return "mesh.path"
    return "mesh.cells" if hasattr(spec, "cells") else "mesh.edge_length"


def check(scene: Scene, limit: float, how: str = "--max-memory") -> ModelSize | None:
    """SceneError naming the field when the model would need more than ``limit`` bytes;
    ``how``: how the limit is changed."""
    size = estimate(scene)
    if size is not None and size.bytes > limit:
        raise SceneError(
            f"{size.field}: the model would have about {figure(size.vertices)} vertices, "
            f"{figure(size.elements)} {scene.shell.element} elements and {figure(size.dofs)} "
            f"DoFs, and need about {figure(size.bytes / 2**30)} GiB to build, above the limit "
            f"of {figure(limit / 2**30)} GiB ({how}); use a coarser mesh")
    return size

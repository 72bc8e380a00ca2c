"""Mid-surface triangle meshes: generators at a target edge length, file loading, normals, edges.

All lengths in metres. Generators return vertices ``(n_v, 3)`` and faces ``(n_f, 3)`` with
counter-clockwise orientation about the +z (or outward radial) normal.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class TriMesh:
    """Vertices ``(n_v, 3)`` float64 and faces ``(n_f, 3)`` int64 of the sheet mid-surface."""

    vertices: np.ndarray
    faces: np.ndarray


def _grid(nx: int, ny: int) -> np.ndarray:
    """Faces of an (nx+1) x (ny+1) vertex grid, cells split along alternating diagonals so the
    mesh has no preferred direction (a uniform diagonal stiffens bending anisotropically)."""
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    i, j = i.ravel(), j.ravel()
    v00 = i * (ny + 1) + j
    v10, v01, v11 = v00 + ny + 1, v00 + 1, v00 + ny + 2
    flip = (i + j) % 2 == 1
    a = np.where(flip, np.stack([v00, v10, v01], 1).T, np.stack([v00, v10, v11], 1).T).T
    b = np.where(flip, np.stack([v10, v11, v01], 1).T, np.stack([v00, v11, v01], 1).T).T
    return np.concatenate([a, b]).astype(np.int64)


def divisions(length: float, edge_length: float) -> int:
    """Cells of about ``edge_length`` along ``length`` (at least one)."""
    return max(1, int(round(length / edge_length)))


def rectangle(size: tuple[float, float], edge_length: float,
              origin: tuple[float, float] = (0.0, 0.0)) -> TriMesh:
    """A plate of ``size`` (Lx, Ly) in the z = 0 plane, lower-left corner at ``origin``."""
    nx, ny = divisions(size[0], edge_length), divisions(size[1], edge_length)
    x, y = np.meshgrid(np.linspace(0, size[0], nx + 1), np.linspace(0, size[1], ny + 1),
                       indexing="ij")
    V = np.column_stack([x.ravel() + origin[0], y.ravel() + origin[1], np.zeros(x.size)])
    return TriMesh(V, _grid(nx, ny))


def annulus(r_inner: float, r_outer: float, edge_length: float) -> TriMesh:
    """A ring (or, with ``r_inner == 0``, a disk) centred at the origin in z = 0.

    Rings of vertices at roughly ``edge_length`` spacing, each ring triangulated to the next.
    """
    radii, counts = rings(r_inner, r_outer, edge_length)
    n_rings = len(radii) - 1
    starts = np.concatenate([[0], np.cumsum(counts)])
    verts, faces = [], []
    for r, n in zip(radii, counts, strict=True):
        t = np.arange(n) * 2 * np.pi / n
        verts.append(np.column_stack([r * np.cos(t), r * np.sin(t), np.zeros(n)]))
    for k in range(n_rings):
        faces.append(_stitch(starts[k], counts[k], starts[k + 1], counts[k + 1]))
    return TriMesh(np.concatenate(verts), np.concatenate(faces).astype(np.int64))


def rings(r_inner: float, r_outer: float, edge_length: float) -> tuple[np.ndarray, list[int]]:
    """The radii of an annulus's vertex rings and the vertices on each (one at radius 0)."""
    radii = np.linspace(r_inner, r_outer, divisions(r_outer - r_inner, edge_length) + 1)
    return radii, [1 if r == 0 else max(6, int(round(2 * np.pi * r / edge_length)))
                   for r in radii]


def band_divisions(radius: float, height: float, edge_length: float) -> tuple[int, int]:
    """Columns around and rows up a cylinder_band: a multiple of 4 columns puts vertices on
    both axes, where scenes hold the band."""
    return (max(8, 4 * int(round(2 * np.pi * radius / edge_length / 4))),
            divisions(height, edge_length))


def _stitch(s0: int, n0: int, s1: int, n1: int) -> np.ndarray:
    """Triangulate the band between two closed vertex rings by merging their angular orders."""
    i = j = 0
    tris = []
    while i < n0 or j < n1:
        advance_inner = n0 > 1 and i < n0 and (j >= n1 or (i + 1) / n0 <= (j + 1) / n1)
        if advance_inner:
            tris.append((s0 + i, s1 + j % n1, s0 + (i + 1) % n0))
            i += 1
        else:
            tris.append((s0 + i % n0, s1 + j, s1 + (j + 1) % n1))
            j += 1
            if n0 == 1 and j >= n1:
                break
    return np.array(tris)


def cylinder_band(radius: float, height: float, edge_length: float) -> TriMesh:
    """A cylindrical band (the cookie-cutter strip): axis z, z in [0, height], normals outward."""
    nt, nz = band_divisions(radius, height, edge_length)
    t, z = np.meshgrid(np.arange(nt + 1) * 2 * np.pi / nt, np.linspace(0, height, nz + 1),
                       indexing="ij")
    V = np.column_stack([radius * np.cos(t.ravel()), radius * np.sin(t.ravel()), z.ravel()])
    F = _grid(nt, nz)
    # close the seam: the last column of vertices is the first one
    seam = np.arange(nt * (nz + 1), (nt + 1) * (nz + 1))
    F = np.where(F >= nt * (nz + 1), F - nt * (nz + 1), F)
    V = np.delete(V, seam, axis=0)
    return TriMesh(V, F)


class MeshFileError(ValueError):
    """A mesh file that is missing or cannot be read."""


def load(path: str | Path, scale: float = 1.0) -> TriMesh:
    """Any OBJ/PLY/STL trimesh reads; ``scale`` converts the file's length unit to metres."""
    return load_with_values(path, scale)[0]


def load_with_values(path: str | Path, scale: float = 1.0, values: np.ndarray | None = None,
                     attribute: str | None = None) -> tuple[TriMesh, np.ndarray | None]:
    """:func:`load`, carrying one value per vertex of the file (``values (n_file,)`` in the
    file's vertex order, or the PLY vertex property ``attribute``) through trimesh's merging
    of duplicate vertices (the first of duplicates keeps its value) and removal of unused
    ones. Returns the mesh and the values per mesh vertex (None without any)."""
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise MeshFileError(f"no mesh file {str(path)!r}")
    try:
        m = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh's parsers raise anything on a malformed file
        raise MeshFileError(f"{path.name}: not a readable mesh ({exc})") from None
    if not hasattr(m, "faces") or len(m.faces) == 0:
        raise MeshFileError(f"{path.name}: no triangles")
    if attribute is not None:
        raw = m.metadata.get("_ply_raw", {}).get("vertex", {}).get("data")
        # ASCII PLY: a dict of columns; binary: a structured array
        names = tuple(raw) if isinstance(raw, dict) else (raw.dtype.names or ()) \
            if raw is not None else ()
        if attribute not in names:
            raise ValueError(f"{path.name}: no vertex property {attribute!r} "
                             f"(has {', '.join(n for n in names) or 'none'})")
        values = np.asarray(raw[attribute], float)
    if values is not None:
        values = np.asarray(values, float).ravel()
        if len(values) != len(m.vertices):
            raise ValueError(f"{len(values)} values for the {len(m.vertices)} vertices of "
                             f"{path.name}")
        m.vertex_attributes["value"] = values
    m.process()  # merge duplicates (STL has no shared vertices), drop unused
    out = np.asarray(m.vertex_attributes["value"], float) if values is not None else None
    return TriMesh(np.asarray(m.vertices, float) * scale, np.asarray(m.faces, np.int64)), out


def vertex_normals(mesh: TriMesh) -> np.ndarray:
    """Area-weighted unit vertex normals ``(n_v, 3)``."""
    V, F = mesh.vertices, mesh.faces
    fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    n = np.zeros_like(V)
    for c in range(3):
        np.add.at(n, F[:, c], fn)
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    if np.any(norm == 0):
        raise ValueError("mesh has vertices without a defined normal (unused or degenerate)")
    return n / norm


def edges(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unique edges ``(n_e, 2)`` (sorted vertex pairs) and, per face, its three edge ids
    ``(n_f, 3)`` for local edges (0,1), (1,2), (2,0)."""
    loc = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    uniq, inv = np.unique(np.sort(loc, axis=1), axis=0, return_inverse=True)
    return uniq, inv.reshape(3, -1).T


def small_patches(faces: np.ndarray, size: int = 2) -> np.ndarray:
    """Faces in edge-connected patches of at most ``size`` faces (a lone triangle, a pair, or
    such a patch hanging off the rest by a vertex only)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    _, face_edges = edges(faces)
    n_f = len(faces)
    f = np.repeat(np.arange(n_f), 3)
    A = coo_matrix((np.ones(3 * n_f), (f, face_edges.ravel())))
    _, label = connected_components(A @ A.T, directed=False)
    return np.flatnonzero(np.bincount(label)[label] <= size)


def boundary_edges(faces: np.ndarray) -> np.ndarray:
    """Edges used by exactly one face, as sorted vertex pairs ``(n_b, 2)``."""
    uniq, face_edges = edges(faces)
    count = np.bincount(face_edges.ravel(), minlength=len(uniq))
    return uniq[count == 1]

"""Mid-surface triangle meshes: generators at a target edge length, file loading, normals, edges.

All lengths in metres. Generators return vertices ``(n_v, 3)`` and faces ``(n_f, 3)`` with
counter-clockwise orientation about the +z (or outward radial) normal.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from sim.scene.fields import MAX_LENGTH

if TYPE_CHECKING:  # loaded when a mesh file is read
    import trimesh


@dataclass(frozen=True)
class Cylinder:
    """The cylinder of ``radius`` around the x axis."""

    radius: float

    def project(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The nearest points on it of ``X (n, 3)`` and the outward unit normals there: radially
        in the plane across the axis, which keeps every plane through the axis and every plane
        across it (symmetry planes, diaphragms) where it was."""
        n = X.copy()
        n[:, 0] = 0.0
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        P = self.radius * n
        P[:, 0] = X[:, 0]
        return P, n


@dataclass(frozen=True)
class Sphere:
    """The sphere of ``radius`` around the origin."""

    radius: float

    def project(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The nearest points on it of ``X (n, 3)`` and the outward unit normals: radially,
        which keeps every plane and cone through the centre (symmetry planes, a polar hole's
        rim) where it was."""
        n = X / np.linalg.norm(X, axis=1, keepdims=True)
        return self.radius * n, n


@dataclass(frozen=True)
class TriMesh:
    """Vertices ``(n_v, 3)`` float64 and faces ``(n_f, 3)`` int64 of the sheet mid-surface;
    ``surface``, when the mesh approximates a known one (a generated cylinder or sphere), is
    where the extrusion puts higher-order nodes and takes normals from, so that curved
    elements lie on the shell rather than on the triangles' flat chords."""

    vertices: np.ndarray
    faces: np.ndarray
    surface: Cylinder | Sphere | None = None


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
    return radii, [ring_vertices(r, edge_length) for r in radii]


def ring_vertices(r: float, edge_length: float) -> int:
    """The vertices on an annulus's ring of radius ``r`` (one at radius 0)."""
    return 1 if r == 0 else max(6, int(round(2 * np.pi * r / edge_length)))


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


def _patch(s: np.ndarray, t: np.ndarray, point: Callable) -> tuple[np.ndarray, np.ndarray]:
    """Vertices ``point(s, t)`` of the grid of parameters ``s (n_s + 1,)`` x ``t (n_t + 1,)``
    and its faces (``_grid``), counter-clockwise about d/ds x d/dt."""
    S, T = np.meshgrid(s, t, indexing="ij")
    return point(S.ravel(), T.ravel()), _grid(len(s) - 1, len(t) - 1)


def cylinder_patch(radius: float, length: float, angle: float, cells: int) -> TriMesh:
    """Part of a cylinder around the x axis: x in [0, length], and from the top (+z) by
    ``angle`` (rad) towards +y; ``cells`` x ``cells`` quadrilaterals of two triangles each,
    normals outward."""
    def point(x: np.ndarray, a: np.ndarray) -> np.ndarray:
        return np.column_stack([x, radius * np.sin(a), radius * np.cos(a)])

    V, F = _patch(np.linspace(0, length, cells + 1), np.linspace(0, angle, cells + 1), point)
    return TriMesh(V, F, Cylinder(radius))


def sphere_patch(radius: float, hole: float, azimuth: float, cells: int) -> TriMesh:
    """Part of a sphere around the origin: from the polar angle ``hole`` (rad, from +z) down to
    the equator z = 0, and from the x axis by ``azimuth`` (rad) towards +y; ``cells`` x
    ``cells`` quadrilaterals of two triangles each, normals outward."""
    def point(polar: np.ndarray, az: np.ndarray) -> np.ndarray:
        return radius * np.column_stack([np.sin(polar) * np.cos(az),
                                         np.sin(polar) * np.sin(az), np.cos(polar)])

    V, F = _patch(np.linspace(hole, np.pi / 2, cells + 1),
                  np.linspace(0, azimuth, cells + 1), point)
    return TriMesh(V, F, Sphere(radius))


def strip(length: float, width: float, twist: float, cells: int, across: int) -> TriMesh:
    """A strip along the x axis: x in [0, length], its width centred on the axis along
    (0, cos a, sin a) with a = twist x / length (flat in z = 0 when ``twist`` is 0); ``cells``
    x ``across`` quadrilaterals of two triangles each, normals +z at x = 0."""
    def point(x: np.ndarray, s: np.ndarray) -> np.ndarray:
        a = twist * x / length
        return np.column_stack([x, s * np.cos(a), s * np.sin(a)])

    V, F = _patch(np.linspace(0, length, cells + 1),
                  np.linspace(-width / 2, width / 2, across + 1), point)
    return TriMesh(V, F)


class MeshFileError(ValueError):
    """A mesh file that is missing or cannot be read."""


def load(path: str | Path, scale: float = 1.0, merge: bool | None = None) -> TriMesh:
    """Any OBJ/PLY/STL trimesh reads; ``scale`` converts the file's length unit to metres."""
    return load_with_values(path, scale, merge=merge)[0]


def _cut_short(path: Path) -> str | None:
    """Why a binary STL gave no triangles when its header counts some and the file is shorter
    than they take (80 bytes of header, a count, 50 bytes a triangle): a copy or an upload
    that did not finish, which trimesh reads as an empty text STL."""
    if path.suffix.lower() != ".stl":
        return None
    size = path.stat().st_size
    with path.open("rb") as f:
        head = f.read(84)
    n = int.from_bytes(head[80:84], "little") if len(head) == 84 else 0
    # a text file's four bytes there count at least 0x0a0a0a0a (168 million) triangles; a
    # binary count under 2^24 (0.8 GB of triangles) has a zero high byte
    if n == 0 or head[83] != 0 or size >= 84 + 50 * n:
        return None
    return (f"{path.name}: a binary STL of {n} triangles cut short: {size} bytes of the "
            f"{84 + 50 * n} they take (a copy or an upload that did not finish?)")


def load_with_values(path: str | Path, scale: float = 1.0, values: np.ndarray | None = None,
                     attribute: str | None = None, merge: bool | None = None,
                     ) -> tuple[TriMesh, np.ndarray | None, dict]:
    """A mesh file as its file says: every vertex and triangle as written (a slit whose sides
    are two rows of coincident vertices stays open). Coincident vertices are merged only when
    ``merge`` is true, or when it is None and the file is an STL, which stores every
    triangle's corners apart. Vertices no triangle uses are dropped. Carries one value per
    vertex of the file (``values (n_file,)`` in the file's vertex order, or the PLY vertex
    property ``attribute``) through both (the first of merged vertices keeps its value).

    Returns the mesh, the values per mesh vertex (None without any) and a report of what was
    read: ``file_vertices``, ``vertices``, ``triangles``, ``merged`` (vertices merged into an
    earlier coincident one), ``merged_groups`` (the first ten groups, as file vertex indices)
    and ``unused`` (vertices dropped)."""
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise MeshFileError(f"no mesh file {str(path)!r}")
    try:
        m = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh's parsers raise anything on a malformed file
        raise MeshFileError(f"{path.name}: not a readable mesh ({exc})") from None
    if not hasattr(m, "faces") or len(m.faces) == 0:
        raise MeshFileError(_cut_short(path) or f"{path.name}: no triangles: not a "
                            f"{path.suffix} mesh file (text, another format?), or an empty one")
    if attribute is not None:
        values = _ply_property(m, path, attribute)
    V, F = np.asarray(m.vertices, float) * scale, np.asarray(m.faces, np.int64)
    _check_coordinates(V, path)
    if values is not None:
        values = np.asarray(values, float).ravel()
        if len(values) != len(V):
            raise ValueError(f"{len(values)} values for the {len(V)} vertices of {path.name}")
    if merge is None:
        merge = path.suffix.lower() == ".stl"
    keep, F, groups = _merged(V, F) if merge else (np.arange(len(V)), F, [])
    collapsed = np.flatnonzero((F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2])
                               | (F[:, 2] == F[:, 0]))
    if len(collapsed):
        raise MeshFileError(f"{path.name}: {len(collapsed)} triangles have a repeated vertex "
                            f"(first: {collapsed[:5].tolist()})"
                            f"{' once coincident vertices are merged' if groups else ''}")
    used = np.unique(F)  # the vertices triangles use, in file order
    renumber = np.full(len(keep), -1)
    renumber[used] = np.arange(len(used))
    report = {"file": path.name, "file_vertices": len(V), "vertices": len(used),
              "triangles": len(F), "merged": len(V) - len(keep), "merged_groups": groups,
              "unused": len(keep) - len(used)}
    keep = keep[used]
    out = values[keep] if values is not None else None
    return TriMesh(V[keep], renumber[F]), out, report


def _ply_property(m: trimesh.Trimesh, path: Path, attribute: str) -> np.ndarray:
    raw = m.metadata.get("_ply_raw", {}).get("vertex", {}).get("data")
    # ASCII PLY: a dict of columns; binary: a structured array
    names = tuple(raw) if isinstance(raw, dict) else (raw.dtype.names or ()) \
        if raw is not None else ()
    if attribute not in names:
        raise ValueError(f"{path.name}: no vertex property {attribute!r} "
                         f"(has {', '.join(n for n in names) or 'none'})")
    return np.asarray(raw[attribute], float)


def _check_coordinates(V: np.ndarray, path: Path) -> None:
    """Finite, and within the scene's bound on lengths (sim.scene.fields.MAX_LENGTH) once scaled."""
    bad = np.flatnonzero(~np.isfinite(V).all(1) | (np.abs(V) > MAX_LENGTH).any(1))
    if len(bad):
        raise MeshFileError(f"{path.name}: vertex {bad[0]} at {V[bad[0]].tolist()} m is not "
                            f"finite or beyond {MAX_LENGTH:.0e} m ({len(bad)} such vertices)")


def _merged(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[list[int]]]:
    """Coincident vertices (equal to 1e-9 of the mesh's extent) merged into the first of
    them: the file vertex each merged vertex is (``(n,)``, in file order), the faces on the
    merged vertices, and the first ten groups merged (file indices, in file order)."""
    extent = float(np.ptp(V, axis=0).max()) or 1.0
    _, first, inverse = np.unique(np.round(V / (1e-9 * extent)), axis=0, return_index=True,
                                  return_inverse=True)
    order = np.argsort(first)  # merged vertices keep the file's order
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    new = rank[inverse.ravel()]
    multiple = np.flatnonzero(np.bincount(new) > 1)[:10]
    return first[order], new[F], [np.flatnonzero(new == g).tolist() for g in multiple]


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


def patches(faces: np.ndarray) -> np.ndarray:
    """Per face, the label (0, 1, ...) of its edge-connected patch: faces that touch at a
    vertex only are in different patches."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    _, face_edges = edges(faces)
    n_f = len(faces)
    f = np.repeat(np.arange(n_f), 3)
    A = coo_matrix((np.ones(3 * n_f), (f, face_edges.ravel())))
    return connected_components(A @ A.T, directed=False)[1]


def small_patches(faces: np.ndarray, size: int = 2) -> np.ndarray:
    """Faces in edge-connected patches of at most ``size`` faces (a lone triangle, a pair, or
    such a patch hanging off the rest by a vertex only)."""
    label = patches(faces)
    return np.flatnonzero(np.bincount(label)[label] <= size)


def boundary_edges(faces: np.ndarray) -> np.ndarray:
    """Edges used by exactly one face, as sorted vertex pairs ``(n_b, 2)``."""
    uniq, face_edges = edges(faces)
    count = np.bincount(face_edges.ravel(), minlength=len(uniq))
    return uniq[count == 1]


def oriented_boundary_edges(faces: np.ndarray) -> np.ndarray:
    """Boundary edges ``(n_b, 2)`` in the orientation of the one face that holds each (so the
    sheet lies to the left of each, seen along the faces' normal)."""
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    _, inv, count = np.unique(np.sort(directed, axis=1), axis=0, return_inverse=True,
                              return_counts=True)
    return directed[count[inv.ravel()] == 1]

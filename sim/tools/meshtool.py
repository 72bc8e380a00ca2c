"""Tools from triangle meshes: a surface file (STL, OBJ, PLY) checked and turned into a GRID
record (sim.tools.grid), a smooth signed distance the contact term evaluates like any other.

Preparation samples the exact signed distance to the triangles at the nodes of a regular grid
of spacing h near the surface: libigl's AABB tree gives the nearest point, the sign is that of
the angle-weighted pseudo-normal of the nearest feature (Baerentzen and Aanaes 2005), which is
exact for a closed, consistently wound surface and gives an open one its side. The samples are
turned into the coefficients of a tricubic B-spline by the local quasi-interpolant
c = P_x P_y P_z f, P = (-1, 8, -1) / 6 per axis, which reproduces cubics (error O(h^4) on a
smooth distance), so no global system is solved and only the bricks near the surface are
sampled. The B-spline is C2: the contact term's Hessian is that of the field it integrates.
The faceted mesh's own distance is C1 at best across its edges; the spline smooths it over a
few h, so a spacing near the facets' size follows the CAD surface rather than its facets.

Why libigl: its signed distance (AABB tree, pseudo-normals, fast winding numbers) is a
well-kept C++ library with wheels; trimesh's proximity queries are pure Python and far slower.

The prepared record is cached by the file's SHA-256 and the preparation's parameters under
``$Q3T_CACHE`` (default ``~/.cache/q3t``) ``/meshtools``, written whole (a temporary file
renamed), and kept in memory for the process's last four tools.
"""

from __future__ import annotations

import functools
import hashlib
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim.tools.program import OP_GRID, program, record

BRICK = 6  # cells per brick side
BAND = 3  # the spline is exact (sampled) wherever |d| < BAND h, and beyond
FORMAT = 1  # of the cached records: bump when the layout or the sampling changes
MAX_NODES = 60_000_000  # grid nodes of a tool's box (a bool each): the memory bound
MAX_EXTENT = 5.0  # m: a tool larger than a press bed is a file in other units
MIN_EXTENT = 1e-4  # m
FLAT = 1e-10  # a triangle this much smaller than the median area is degenerate


class MeshToolError(ValueError):
    """A tool mesh that cannot be used; the message names the problem."""


@dataclass(frozen=True)
class MeshOptions:
    """How a mesh file becomes a tool: ``scale`` file units to m, ``spacing`` h (m) of the
    grid, ``open`` an open surface (the tool behind its faces), ``flip`` the tool in front."""

    scale: float = 1.0
    spacing: float = 5e-4
    open: bool = False
    flip: bool = False


def read_surface(path: str | Path, opts: MeshOptions,
                 check_size: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The surface V (n, 3) m, F (k, 3) of a file, checked (MeshToolError naming the problem);
    a closed one wound with outward normals, an open one flipped when ``flip``. Without
    ``check_size`` its size is not checked (a file whose scale is not known yet)."""
    from sim.geometry import trimesh as meshes

    try:
        m = meshes.load(path, opts.scale, merge=True)
    except ValueError as exc:
        raise MeshToolError(str(exc)) from None
    V, F = m.vertices, m.faces
    name = Path(path).name
    problem = ((check_size and _size_problem(V, opts)) or _triangle_problem(V, F)
               or _topology_problem(V, F, opts))
    if problem:
        raise MeshToolError(f"{name}: {problem}")
    if opts.open:
        return V, (F[:, ::-1] if opts.flip else F)
    if _volume(V, F) < 0:
        F = F[:, ::-1]
    problem = _self_intersection(V, F)
    if problem:
        raise MeshToolError(f"{name}: {problem}")
    return V, F


def _size_problem(V: np.ndarray, opts: MeshOptions) -> str | None:
    ext = float((V.max(0) - V.min(0)).max())
    if not MIN_EXTENT <= ext <= MAX_EXTENT:
        return (f"absurd size: {ext:.3g} m across with scale = {opts.scale:g} (a tool is "
                f"{MIN_EXTENT:g}-{MAX_EXTENT:g} m; a file in mm needs scale = 0.001)")
    cells = (V.max(0) - V.min(0)) / opts.spacing + 2 * (BRICK + 2)
    if float(np.prod(cells)) > MAX_NODES:
        return (f"spacing {opts.spacing:g} m is too fine for a tool {ext:.3g} m across (over "
                f"{MAX_NODES:.0e} grid nodes): give a larger spacing")
    return None


def _triangle_problem(V: np.ndarray, F: np.ndarray) -> str | None:
    area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    flat = np.flatnonzero(area <= FLAT * np.median(area))
    if len(flat):
        return (f"{len(flat)} degenerate (zero-area) triangles (first: {flat[:5].tolist()})")
    return None


def _topology_problem(V: np.ndarray, F: np.ndarray, opts: MeshOptions) -> str | None:
    directed = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    _, inverse, count = np.unique(np.sort(directed, axis=1), axis=0, return_inverse=True,
                                  return_counts=True)
    if (count > 2).any():
        return f"{int((count > 2).sum())} edges shared by more than two triangles"
    forward = np.bincount(inverse.ravel(), weights=directed[:, 0] < directed[:, 1])
    if ((count == 2) & (forward != 1)).any():
        return (f"{int(((count == 2) & (forward != 1)).sum())} edges between triangles wound "
                "opposite ways (an inconsistent orientation)")
    if not opts.open and (count == 1).any():
        return (f"open: {int((count == 1).sum())} boundary edges, and the shape needs a closed "
                "surface (or set open = true: the tool lies behind the faces' normals)")
    return None


def _volume(V: np.ndarray, F: np.ndarray) -> float:
    return float(np.einsum("ij,ij->i", V[F[:, 0]], np.cross(V[F[:, 1]], V[F[:, 2]])).sum() / 6)


def _self_intersection(V: np.ndarray, F: np.ndarray) -> str | None:
    """A closed surface wound outward has winding number 0 just outside each face and 1 just
    inside; a part of it inside another part (an overlap, a fold) shows 1 or 2 there."""
    import igl

    N = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    N /= np.linalg.norm(N, axis=1)[:, None]
    # off each face by a hair: well inside the faces' neighbours, beyond round-off
    eps = 1e-6 * float((V.max(0) - V.min(0)).max())
    C = V[F].mean(1)
    Q = np.concatenate([C + eps * N, C - eps * N])
    w = igl.fast_winding_number(np.ascontiguousarray(V), np.ascontiguousarray(F), Q)
    bad = np.flatnonzero((np.abs(w[:len(F)]) > 0.5) | (np.abs(w[len(F):] - 1) > 0.5))
    if len(bad):
        return (f"self-intersecting: {len(bad)} triangles lie inside the tool's own material "
                f"(first: {bad[:5].tolist()})")
    return None


def grid_params(V: np.ndarray, F: np.ndarray, h: float) -> tuple[np.ndarray, dict]:
    """GRID record parameters (sim.tools.grid) of the surface V (n, 3), F (k, 3) at spacing h,
    and a report of what was sampled and stored."""
    t0 = time.perf_counter()
    B = BRICK
    L = B * h
    lo = V.min(0) - L  # one brick of far field around the surface
    nb = np.ceil((V.max(0) + L - lo) / L).astype(int)
    corners = np.stack(np.meshgrid(*[np.arange(n + 1) for n in nb], indexing="ij"), -1)
    far = _signed_distance(V, F, lo + L * corners.reshape(-1, 3)).reshape(nb + 1)
    # a brick holds a point with |d| < BAND h if a corner is within that plus half its diagonal
    reach = BAND * h + 0.5 * math.sqrt(3.0) * L
    near = np.abs(far) <= reach
    active = np.zeros(nb, bool)
    for a, b, c in np.ndindex(2, 2, 2):
        active |= near[a:a + nb[0], b:b + nb[1], c:c + nb[2]]
    bricks = np.argwhere(active)
    table = np.full(nb, -1.0)
    table[tuple(bricks.T)] = np.arange(len(bricks))
    coef, n_samples = _coefficients(V, F, lo, h, nb, bricks)
    head = [*lo, h, B, *nb, len(bricks), 0.0]
    params = np.concatenate([head, table.ravel(), far.ravel(), coef.ravel()])
    return params, {"triangles": len(F), "spacing": h, "bricks": len(bricks),
                    "samples": n_samples, "bytes": params.nbytes,
                    "seconds": round(time.perf_counter() - t0, 2)}


def _coefficients(V: np.ndarray, F: np.ndarray, lo: np.ndarray, h: float, nb: np.ndarray,
                  bricks: np.ndarray) -> tuple[np.ndarray, int]:
    """B-spline coefficients (n_bricks, B + 3, B + 3, B + 3) of the active bricks: the exact
    distance sampled at the nodes their stencils and the prefilter reach (B + 5 per axis,
    global nodes I B - 2 ...), prefiltered per axis."""
    B = BRICK
    n = nb * B + 5  # nodes, shifted by 2
    need = np.zeros(n, bool)
    for I, J, K in bricks * B:
        need[I:I + B + 5, J:J + B + 5, K:K + B + 5] = True
    idx = np.flatnonzero(need)  # sorted: a brick's nodes are found by bisection
    del need
    vals = _signed_distance(V, F, lo + h * (np.stack(np.unravel_index(idx, n), -1) - 2))
    off = np.arange(B + 5)
    ii = (bricks[:, 0, None] * B + off)[:, :, None, None]
    jj = (bricks[:, 1, None] * B + off)[:, None, :, None]
    kk = (bricks[:, 2, None] * B + off)[:, None, None, :]
    f = vals[np.searchsorted(idx, (ii * n[1] + jj) * n[2] + kk)]
    for axis in (1, 2, 3):
        f = _prefilter(f, axis)
    return f, len(idx)


def _prefilter(f: np.ndarray, axis: int) -> np.ndarray:
    """(-f[i-1] + 8 f[i] - f[i+1]) / 6 along ``axis``: the cubic B-spline quasi-interpolant."""
    a = np.moveaxis(f, axis, 0)
    return np.moveaxis((8.0 * a[1:-1] - a[:-2] - a[2:]) / 6.0, 0, axis)


def _signed_distance(V: np.ndarray, F: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Exact signed distance (> 0 in front of the faces) of points P (n, 3), in chunks (the
    nearest points and normals libigl also returns are 7 floats a point)."""
    import igl

    V = np.ascontiguousarray(V, float)
    F = np.ascontiguousarray(F, np.int64)
    out = np.empty(len(P))
    chunk = 1 << 19
    for s in range(0, len(P), chunk):
        out[s:s + chunk] = igl.signed_distance(
            np.ascontiguousarray(P[s:s + chunk]), V, F,
            sign_type=igl.SIGNED_DISTANCE_TYPE_PSEUDONORMAL)[0]
    return out


def cache_dir() -> Path:
    return Path(os.environ.get("Q3T_CACHE") or Path.home() / ".cache" / "q3t") / "meshtools"


def _digest(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest() if Path(path).is_file() else ""


def _cached(digest: str, opts: MeshOptions) -> Path:
    key = hashlib.sha256(f"{FORMAT} {digest} {opts}".encode()).hexdigest()[:32]
    return cache_dir() / f"{key}.npy"


def mesh_program(path: str | Path, opts: MeshOptions) -> np.ndarray:
    """The SDF program of a mesh file's tool (cached by the file's content and ``opts``)."""
    return _program(str(path), _digest(path), opts)


@functools.lru_cache(maxsize=4)  # a worker's last few tools; each tens of MB
def _program(path: str, digest: str, opts: MeshOptions) -> np.ndarray:
    cached = _cached(digest, opts)
    if digest and cached.is_file():
        return program(record(OP_GRID, np.load(cached)))
    V, F = read_surface(path, opts)
    params, _ = grid_params(V, F, opts.spacing)
    cached.parent.mkdir(parents=True, exist_ok=True)
    tmp = cached.with_suffix(f".{os.getpid()}.tmp")
    with open(tmp, "wb") as fh:
        np.save(fh, params)
    os.replace(tmp, cached)
    return program(record(OP_GRID, params))

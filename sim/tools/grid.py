"""numba kernel of the GRID primitive (sim.tools.program): a signed distance sampled on a
regular grid near a surface and interpolated there by tricubic B-splines, the smooth
distance of a tool made from a triangle mesh (sim.tools.meshtool prepares it).

Record parameters (after opcode and count)::

    ox oy oz h B nx ny nz n_active 0   (GRID_HEAD = 10)
    table (nx ny nz)                   brick (I, J, K) -> its index among the active ones, or -1
    far ((nx + 1) (ny + 1) (nz + 1))   the exact distance at the bricks' corners
    coef (n_active (B + 3)^3)          each active brick's B-spline coefficients, with a halo

Space is cut into nx x ny x nz bricks of B x B x B cells of side h from the origin o. Inside an
active brick (one that can hold a point within a few cells of the surface) the distance is the
tricubic B-spline s(x) = sum_ijk c_ijk b((x - o)/h - i) b(.. - j) b(.. - k): C2, so g and H are
its exact derivatives. Every brick stores the coefficients of the nodes its cells' 4 x 4 x 4
stencils reach (B + 3 per axis, shared nodes copied), so s is one C2 function across active
bricks. Elsewhere (farther from the surface than any contact reaches) d is the trilinear
interpolant of ``far``, and outside the grid's box that value at the nearest box point plus
the distance to the box: a continuous, correctly signed stand-in that pushes a stray point
back out, not an exact distance.

Shapes: prog (n_prog,), b the index of the record's first parameter, x (3,) the point in the
grid's frame, g (3,) and H (3, 3) the results.
"""

from __future__ import annotations

import math

import numba
import numpy as np

GRID_HEAD = 10


def grid_sizes(p: np.ndarray) -> tuple[int, int, int]:
    """(table, far, coef) lengths of a GRID record's parameters ``p`` (from its head)."""
    B, nx, ny, nz, na = (int(v) for v in p[4:9])
    return nx * ny * nz, (nx + 1) * (ny + 1) * (nz + 1), na * (B + 3) ** 3


@numba.njit(cache=True, inline="always")
def _basis(t: float) -> tuple:
    """Uniform cubic B-spline weights of the 4 nodes of a cell at t in [0, 1], with their
    first and second derivatives."""
    s = 1.0 - t
    t2 = t * t
    w = (s * s * s / 6.0, (3.0 * t2 * t - 6.0 * t2 + 4.0) / 6.0,
         (-3.0 * t2 * t + 3.0 * t2 + 3.0 * t + 1.0) / 6.0, t2 * t / 6.0)
    dw = (-0.5 * s * s, 1.5 * t2 - 2.0 * t, -1.5 * t2 + t + 0.5, 0.5 * t2)
    ddw = (s, 3.0 * t - 2.0, 1.0 - 3.0 * t, t)
    return w, dw, ddw


@numba.njit(cache=True)
def _cell(u: float, n: int) -> tuple[int, float]:
    """Cell index in [0, n) and local coordinate in [0, 1] of grid coordinate u in [0, n]."""
    i = int(math.floor(u))
    if i > n - 1:
        i = n - 1
    if i < 0:
        i = 0
    return i, u - i


@numba.njit(cache=True)
def _spline(prog: np.ndarray, base: int, n1: int, tx: float, ty: float, tz: float, ix: int,
            iy: int, iz: int, h: float, derivs: bool, g: np.ndarray, H: np.ndarray) -> float:
    """The tricubic B-spline of the brick coefficients at prog[base:], cell (ix, iy, iz)."""
    wx, dwx, ddwx = _basis(tx)
    wy, dwy, ddwy = _basis(ty)
    wz, dwz, ddwz = _basis(tz)
    d = 0.0
    gx = gy = gz = 0.0
    hxx = hyy = hzz = hxy = hxz = hyz = 0.0
    for a in range(4):
        for c in range(4):
            o = base + ((ix + a) * n1 + iy + c) * n1 + iz
            s0 = 0.0
            s1 = 0.0
            s2 = 0.0
            for e in range(4):
                co = prog[o + e]
                s0 += co * wz[e]
                if derivs:
                    s1 += co * dwz[e]
                    s2 += co * ddwz[e]
            d += wx[a] * wy[c] * s0
            if derivs:
                gx += dwx[a] * wy[c] * s0
                gy += wx[a] * dwy[c] * s0
                gz += wx[a] * wy[c] * s1
                hxx += ddwx[a] * wy[c] * s0
                hyy += wx[a] * ddwy[c] * s0
                hzz += wx[a] * wy[c] * s2
                hxy += dwx[a] * dwy[c] * s0
                hxz += dwx[a] * wy[c] * s1
                hyz += wx[a] * dwy[c] * s1
    if derivs:
        g[0] = gx / h
        g[1] = gy / h
        g[2] = gz / h
        q = 1.0 / (h * h)
        H[0, 0] = hxx * q
        H[1, 1] = hyy * q
        H[2, 2] = hzz * q
        H[0, 1] = H[1, 0] = hxy * q
        H[0, 2] = H[2, 0] = hxz * q
        H[1, 2] = H[2, 1] = hyz * q
    return d


@numba.njit(cache=True)
def _far(prog: np.ndarray, base: int, nx: int, ny: int, nz: int, u: np.ndarray, L: float,
         derivs: bool, g: np.ndarray, H: np.ndarray) -> float:
    """Trilinear interpolant of the corner distances at prog[base:] at brick coordinate u (3,)
    (bricks of side L), with its exact gradient and (mixed-only) Hessian."""
    i, tx = _cell(u[0], nx)
    j, ty = _cell(u[1], ny)
    k, tz = _cell(u[2], nz)
    d = 0.0
    for v in range(3):
        g[v] = 0.0
        for w in range(3):
            H[v, w] = 0.0
    for a in range(2):
        for c in range(2):
            for e in range(2):
                f = prog[base + ((i + a) * (ny + 1) + j + c) * (nz + 1) + k + e]
                wx, dx = (tx, 1.0) if a else (1.0 - tx, -1.0)
                wy, dy = (ty, 1.0) if c else (1.0 - ty, -1.0)
                wz, dz = (tz, 1.0) if e else (1.0 - tz, -1.0)
                d += f * wx * wy * wz
                if derivs:
                    g[0] += f * dx * wy * wz / L
                    g[1] += f * wx * dy * wz / L
                    g[2] += f * wx * wy * dz / L
                    H[0, 1] += f * dx * dy * wz / (L * L)
                    H[0, 2] += f * dx * wy * dz / (L * L)
                    H[1, 2] += f * wx * dy * dz / (L * L)
    H[1, 0] = H[0, 1]
    H[2, 0] = H[0, 2]
    H[2, 1] = H[1, 2]
    return d


@numba.njit(cache=True)
def prim_grid(prog: np.ndarray, b: int, x: np.ndarray, derivs: bool, g: np.ndarray,
              H: np.ndarray, q: np.ndarray, s: np.ndarray) -> float:
    """d at x (3,) (and g, H with derivs); q, s (3,) scratch."""
    h = prog[b + 3]
    B = int(prog[b + 4])
    nx = int(prog[b + 5])
    ny = int(prog[b + 6])
    nz = int(prog[b + 7])
    na = int(prog[b + 8])
    tab = b + GRID_HEAD
    far = tab + nx * ny * nz
    coef = far + (nx + 1) * (ny + 1) * (nz + 1)
    L = B * h
    out = 0.0  # squared distance to the grid's box
    for v in range(3):
        n = (nx, ny, nz)[v]
        u = (x[v] - prog[b + v]) / L
        c = min(max(u, 0.0), float(n))
        s[v] = (u - c) * L
        out += s[v] * s[v]
        q[v] = c
    if out > 0.0:
        r = math.sqrt(out)
        d = _far(prog, far, nx, ny, nz, q, L, False, g, H) + r
        if derivs:
            for v in range(3):
                g[v] = s[v] / r
            for v in range(3):
                for w in range(3):
                    H[v, w] = ((1.0 if v == w else 0.0) - g[v] * g[w]) / r
        return d
    I, _ = _cell(q[0], nx)
    J, _ = _cell(q[1], ny)
    K, _ = _cell(q[2], nz)
    brick = int(prog[tab + (I * ny + J) * nz + K])
    if brick < 0 or brick >= na:
        return _far(prog, far, nx, ny, nz, q, L, derivs, g, H)
    ix, tx = _cell((q[0] - I) * B, B)
    iy, ty = _cell((q[1] - J) * B, B)
    iz, tz = _cell((q[2] - K) * B, B)
    n1 = B + 3
    return _spline(prog, coef + brick * n1 * n1 * n1, n1, tx, ty, tz, ix, iy, iz, h, derivs,
                   g, H)

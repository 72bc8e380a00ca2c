"""numba kernels of the SDF primitives (sim.tools.program): plane, rounded box, the
rounded-rectangle profile revolved about z or swept along a (rounded) polygon. Each
writes d and, with ``derivs``, g and H of one point into the caller's workspace.

Shapes: prog (n_prog,) the program, b the index of the record's first parameter in it,
x (3,) the point in the primitive's frame, g (3,) and H (3, 3) the results; scratch q, s
(3,), prof (6,) the profile's (f, f_u, f_z, f_uu, f_uz, f_zz), gw (2,) and Hw (2, 2) the
gradient and Hessian of the in-plane distance w."""

from __future__ import annotations

import math

import numba
import numpy as np

from sim.tools.program import RCORNER


@numba.njit(cache=True)
def _clear(g: np.ndarray, H: np.ndarray) -> None:
    for i in range(3):
        g[i] = 0.0
        for j in range(3):
            H[i, j] = 0.0


@numba.njit(cache=True)
def prim_plane(prog: np.ndarray, b: int, x: np.ndarray, derivs: bool, g: np.ndarray,
               H: np.ndarray) -> float:
    d = 0.0
    for i in range(3):
        d += prog[b + 3 + i] * (x[i] - prog[b + i])
    if derivs:
        _clear(g, H)
        for i in range(3):
            g[i] = prog[b + 3 + i]
    return d


@numba.njit(cache=True)
def prim_box(prog: np.ndarray, b: int, x: np.ndarray, derivs: bool, g: np.ndarray, H: np.ndarray,
             q: np.ndarray, s: np.ndarray) -> float:
    """Rounded box: d = |q+| + min(max q, 0) - r with q = |x - c| - (h - r)."""
    r = prog[b + 6]
    for i in range(3):
        y = x[i] - prog[b + i]
        s[i] = 1.0 if y >= 0.0 else -1.0
        q[i] = abs(y) - (prog[b + 3 + i] - r)
    ss = 0.0
    for i in range(3):
        if q[i] > 0.0:
            ss += q[i] * q[i]
    if ss > 0.0:
        L = math.sqrt(ss)
        d = L - r
        if derivs:
            for i in range(3):
                g[i] = s[i] * q[i] / L if q[i] > 0.0 else 0.0
            for i in range(3):
                for j in range(3):
                    H[i, j] = -g[i] * g[j] / L
                if q[i] > 0.0:
                    H[i, i] += 1.0 / L
        return d
    im = 0
    for i in range(1, 3):
        if q[i] > q[im]:
            im = i
    if derivs:
        _clear(g, H)
        g[im] = s[im]
    return q[im] - r


@numba.njit(cache=True)
def _rrect2(u: float, z: float, lo: float, hi: float, z0: float, z1: float, r: float,
            out: np.ndarray) -> None:
    """Rounded rectangle [lo, hi] x [z0, z1] (radius r) in the (u, z) plane.

    out = (f, f_u, f_z, f_uu, f_uz, f_zz); lo may be -inf, hi may be +inf.
    """
    qa = lo + r - u
    qb = u - (hi - r)
    if qa > qb:
        qu = qa
        su = -1.0
    else:
        qu = qb
        su = 1.0
    qa = z0 + r - z
    qb = z - (z1 - r)
    if qa > qb:
        qz = qa
        sz = -1.0
    else:
        qz = qb
        sz = 1.0
    pu = qu if qu > 0.0 else 0.0
    pz = qz if qz > 0.0 else 0.0
    if pu > 0.0 or pz > 0.0:
        L = math.sqrt(pu * pu + pz * pz)
        gu = su * pu / L
        gz = sz * pz / L
        out[0] = L - r
        out[1] = gu
        out[2] = gz
        out[3] = ((1.0 if qu > 0.0 else 0.0) - gu * gu) / L
        out[4] = -gu * gz / L
        out[5] = ((1.0 if qz > 0.0 else 0.0) - gz * gz) / L
    else:
        if qu >= qz:
            out[0] = qu - r
            out[1] = su
            out[2] = 0.0
        else:
            out[0] = qz - r
            out[1] = 0.0
            out[2] = sz
        out[3] = 0.0
        out[4] = 0.0
        out[5] = 0.0


@numba.njit(cache=True)
def _segment_nearest(wx: float, wy: float, ex: float, ey: float,
                     L2: float) -> tuple[float, float, int]:
    """The point of segment a + t e, t in [0, 1], nearest to p, with w = p - a and L2 = |e|^2:
    (squared distance, t, 1 if it is an end point else 0)."""
    t = (wx * ex + wy * ey) / L2
    k = 0
    if t <= 0.0:
        t = 0.0
        k = 1
    elif t >= 1.0:
        t = 1.0
        k = 1
    dx = wx - t * ex
    dy = wy - t * ey
    return dx * dx + dy * dy, t, k


@numba.njit(cache=True)
def _edge_or_point(px: float, py: float, qx: float, qy: float, nx: float, ny: float, best: float,
                   inside: bool, on_edge: bool, derivs: bool, gw: np.ndarray,
                   Hw: np.ndarray) -> float:
    """The nearest feature of a polygon scan: an edge's interior (``on_edge``: the line through
    q with outward normal n; w = n.(p - q), gw = n, Hw = 0) or a point q at squared distance
    ``best`` (w = +-|p - q|, gw = +-e, Hw = +-(I - e e^T) / |p - q|, the sign from the
    even-odd test's ``inside``). Fills gw (2,) and Hw (2, 2) when derivs; returns w."""
    if on_edge:
        if derivs:
            gw[0] = nx
            gw[1] = ny
            Hw[:, :] = 0.0
        return nx * (px - qx) + ny * (py - qy)
    sgn = -1.0 if inside else 1.0
    dist = math.sqrt(best)
    if derivs:
        if dist > 0.0:
            ex = (px - qx) / dist
            ey = (py - qy) / dist
            gw[0] = sgn * ex
            gw[1] = sgn * ey
            Hw[0, 0] = sgn * (1.0 - ex * ex) / dist
            Hw[0, 1] = -sgn * ex * ey / dist
            Hw[1, 0] = Hw[0, 1]
            Hw[1, 1] = sgn * (1.0 - ey * ey) / dist
        else:  # exactly on the point: a finite stand-in
            gw[0] = nx
            gw[1] = ny
            Hw[:, :] = 0.0
    return sgn * dist


@numba.njit(cache=True)
def _polygon_sd(prog: np.ndarray, base: int, m: int, px: float, py: float, derivs: bool,
                gw: np.ndarray, Hw: np.ndarray) -> float:
    """Signed distance w to the CCW polygon stored at prog[base: base + 2 m] (> 0 outside).

    Fills gw (2,) and Hw (2, 2) when derivs. Edge interior nearest: w = n.(p - a), gw = n,
    Hw = 0. Vertex nearest: w = +-|p - v|, gw = +-e, Hw = +-(I - e e^T) / |p - v|, the sign
    from an even-odd crossing test.
    """
    best = np.inf
    kind = 0  # 0 edge interior, 1 vertex
    cx = 0.0
    cy = 0.0
    nx = 1.0
    ny = 0.0
    inside = False
    j = m - 1
    for i in range(m):
        ax = prog[base + 2 * j]
        ay = prog[base + 2 * j + 1]
        bx = prog[base + 2 * i]
        by = prog[base + 2 * i + 1]
        ex = bx - ax
        ey = by - ay
        L2 = ex * ex + ey * ey
        dd, t, k = _segment_nearest(px - ax, py - ay, ex, ey, L2)
        if dd < best:
            best = dd
            kind = k
            cx = ax + t * ex
            cy = ay + t * ey
            L = math.sqrt(L2)
            nx = ey / L
            ny = -ex / L
        if (ay > py) != (by > py):
            xint = ax + (py - ay) * ex / ey
            if px < xint:
                inside = not inside
        j = i
    return _edge_or_point(px, py, cx, cy, nx, ny, best, inside, kind == 0, derivs, gw, Hw)


@numba.njit(cache=True)
def _compose_profile(prof: np.ndarray, gw: np.ndarray, Hw: np.ndarray, hw_scale: float,
                     derivs: bool, g: np.ndarray, H: np.ndarray) -> float:
    """d = f(w(x, y), z): chain rule from the profile derivatives and those of w.

    g = f_u grad w + f_z e_z,
    H = f_uu gw gw^T + f_uz (gw e_z^T + e_z gw^T) + f_zz e_z e_z^T + hw_scale Hw
    (hw_scale = f_u, or 1 when the caller has folded f_u into Hw).
    """
    if derivs:
        fu = prof[1]
        g[0] = fu * gw[0]
        g[1] = fu * gw[1]
        g[2] = prof[2]
        for i in range(2):
            for j in range(2):
                H[i, j] = prof[3] * gw[i] * gw[j] + hw_scale * Hw[i, j]
            H[i, 2] = prof[4] * gw[i]
            H[2, i] = H[i, 2]
        H[2, 2] = prof[5]
    return prof[0]


@numba.njit(cache=True)
def prim_revolve(prog: np.ndarray, b: int, x: np.ndarray, derivs: bool, g: np.ndarray,
                 H: np.ndarray, prof: np.ndarray, gw: np.ndarray, Hw: np.ndarray) -> float:
    rho = math.sqrt(x[0] * x[0] + x[1] * x[1])
    _rrect2(rho, x[2], prog[b], prog[b + 1], prog[b + 2], prog[b + 3], prog[b + 4], prof)
    if derivs:
        if rho > 0.0:
            er0 = x[0] / rho
            er1 = x[1] / rho
            c = prof[1] / rho
        else:  # on the axis: e_r := +x, curvature term -> its smooth limit f_uu
            er0 = 1.0
            er1 = 0.0
            c = prof[3]
        gw[0] = er0
        gw[1] = er1
        # f_u Hess(rho) = (f_u / rho) e_theta e_theta^T, e_theta = (-er1, er0)
        Hw[0, 0] = c * er1 * er1
        Hw[0, 1] = -c * er0 * er1
        Hw[1, 0] = Hw[0, 1]
        Hw[1, 1] = c * er0 * er0
        _compose_profile(prof, gw, Hw, 1.0, True, g, H)
    return prof[0]


@numba.njit(cache=True)
def prim_sweep(prog: np.ndarray, b: int, x: np.ndarray, derivs: bool, g: np.ndarray, H: np.ndarray,
               prof: np.ndarray, gw: np.ndarray, Hw: np.ndarray) -> float:
    m = int(prog[b + 5])
    w = _polygon_sd(prog, b + 6, m, x[0], x[1], derivs, gw, Hw)
    _rrect2(w, x[2], prog[b], prog[b + 1], prog[b + 2], prog[b + 3], prog[b + 4], prof)
    return _compose_profile(prof, gw, Hw, prof[1], derivs, g, H)


@numba.njit(cache=True)
def _rpolygon_sd(prog: np.ndarray, base: int, m: int, px: float, py: float, derivs: bool,
                 gw: np.ndarray, Hw: np.ndarray) -> float:
    """Signed distance w to the rounded polygon stored at prog[base: base + 8 m] (> 0 outside).

    Corner i is an arc of radius rc about (cx, cy) from its tangent point a on the incoming
    edge to b on the outgoing one, s = +1 for a convex corner (centre inside), -1 for a
    reflex one; the edges run from b_i to a_{i+1}; rc = 0 is a sharp corner (a = b = c).
    Nearest feature: edge interior w = n.(p - b), gw = n, Hw = 0; arc interior (p - c in the
    cone of a - c and b - c) w = s (|p - c| - rc), gw = s e, Hw = s (I - e e^T) / |p - c|;
    an edge end (sharp corner) as in _polygon_sd, the sign from an even-odd crossing test of
    the chord polygon a_0 b_0 a_1 b_1 ... (arcs and chords enclose no point whose nearest
    feature is an edge end).
    """
    best = np.inf
    kind = 0  # 0 edge interior, 1 edge end, 2 arc
    qx = 0.0
    qy = 0.0
    nx = 1.0
    ny = 0.0
    sg = 1.0
    arc_rho = 0.0
    arc_rc = 0.0
    inside = False
    for i in range(m):
        o = base + RCORNER * i
        cx = prog[o]
        cy = prog[o + 1]
        rc = prog[o + 2]
        s = prog[o + 3]
        ax = prog[o + 4]
        ay = prog[o + 5]
        bx = prog[o + 6]
        by = prog[o + 7]
        o2 = base + RCORNER * ((i + 1) % m)
        ex0 = prog[o2 + 4]
        ey0 = prog[o2 + 5]
        if rc > 0.0:
            vx = px - cx
            vy = py - cy
            turn = (ax - cx) * (by - cy) - (ay - cy) * (bx - cx)
            c1 = (ax - cx) * vy - (ay - cy) * vx
            c2 = vx * (by - cy) - vy * (bx - cx)
            if c1 * turn >= 0.0 and c2 * turn >= 0.0:
                rho = math.sqrt(vx * vx + vy * vy)
                dd = (rho - rc) * (rho - rc)
                if dd < best:
                    best = dd
                    kind = 2
                    sg = s
                    arc_rho = rho
                    arc_rc = rc
                    if rho > 0.0:
                        nx = vx / rho
                        ny = vy / rho
                    else:  # at the centre: finite stand-in
                        nx = (ax - cx) / rc
                        ny = (ay - cy) / rc
            # chord a -> b for the crossing test
            if (ay > py) != (by > py):
                if px < ax + (py - ay) * (bx - ax) / (by - ay):
                    inside = not inside
        ex = ex0 - bx
        ey = ey0 - by
        L2 = ex * ex + ey * ey
        if L2 > 0.0:
            dd, t, k = _segment_nearest(px - bx, py - by, ex, ey, L2)
            if dd < best:
                best = dd
                kind = k
                qx = bx + t * ex
                qy = by + t * ey
                L = math.sqrt(L2)
                nx = ey / L
                ny = -ex / L
            if (by > py) != (ey0 > py):
                if px < bx + (py - by) * ex / ey:
                    inside = not inside
    if kind == 2:
        if derivs:
            gw[0] = sg * nx
            gw[1] = sg * ny
            c = sg / arc_rho if arc_rho > 0.0 else 0.0
            Hw[0, 0] = c * (1.0 - nx * nx)
            Hw[0, 1] = -c * nx * ny
            Hw[1, 0] = Hw[0, 1]
            Hw[1, 1] = c * (1.0 - ny * ny)
        return sg * (arc_rho - arc_rc)
    return _edge_or_point(px, py, qx, qy, nx, ny, best, inside, kind == 0, derivs, gw, Hw)


@numba.njit(cache=True)
def prim_rsweep(prog: np.ndarray, b: int, x: np.ndarray, derivs: bool, g: np.ndarray, H: np.ndarray,
                prof: np.ndarray, gw: np.ndarray, Hw: np.ndarray) -> float:
    m = int(prog[b + 5])
    w = _rpolygon_sd(prog, b + 6, m, x[0], x[1], derivs, gw, Hw)
    _rrect2(w, x[2], prog[b], prog[b + 1], prog[b + 2], prog[b + 3], prog[b + 4], prof)
    return _compose_profile(prof, gw, Hw, prof[1], derivs, g, H)


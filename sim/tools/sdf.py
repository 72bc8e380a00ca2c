"""Rigid forming tools as signed distance functions with exact gradients and Hessians.

A tool shape is a small program: a float64 1-D array holding a list of primitives and CSG
operations in postfix (reverse Polish) order. One numba kernel, ``sdf_eval(prog, X)``, runs it
for every point of ``X`` (n, 3), given in the tool's local frame, and returns the signed
distance d (n,), its gradient g (n, 3) and Hessian H (n, 3, 3). Sign convention: d > 0
outside the tool (in the air), d < 0 inside the tool material, so g is the outward normal on
the surface. Units: whatever the caller uses, in this project SI (m); d in m, g
dimensionless, H in 1/m.

Program layout
--------------
::

    prog = [MAGIC, n_body, record, record, ...]        MAGIC = 1503.0, n_body = len(prog) - 2
    record = [opcode, n_params, p_0, ..., p_{n_params-1}]

Records are run left to right on a value stack (each value is a triple d, g, H expressed in
the tool frame); primitives push one value, binary operations pop two (a pushed before b) and
push one. A valid program leaves exactly one value; the stack is at most MAX_STACK deep and
frames nest at most MAX_FRAMES deep. Every builder below returns a complete program, and the
combinators (``union`` ...) splice the bodies of their operands, so programs nest freely.

=====  =============  ========================================================================
code   name           parameters (n_params)
=====  =============  ========================================================================
1      PLANE          px py pz nx ny nz (6): half-space n.(x - p) <= 0, |n| = 1; d = n.(x - p)
2      BOX            cx cy cz hx hy hz r (7): box centre c, half extents h, all edges and
                      corners rounded with radius r (0 <= r <= min h; r = 0 a sharp box)
3      REVOLVE        lo hi z0 z1 r (5): solid of revolution about the z axis whose (rho, z)
                      profile is the rectangle [lo, hi] x [z0, z1] with corners rounded by r;
                      lo = -inf (builders write that for lo <= 0) means the solid reaches the
                      axis (punch: no inner wall, no corner at rho = 0)
4      SWEEP          lo hi z0 z1 r m x_0 y_0 ... x_{m-1} y_{m-1} (6 + 2 m): the same rounded
                      rectangle profile, but with rho replaced by w(x, y), the signed distance
                      to the counter-clockwise simple polygon (x_i, y_i): the solid is
                      {lo <= w <= hi, z0 <= z <= z1} rounded by r in the (w, z) plane.
                      lo = -inf: a prism over the polygon dilated by hi (an extruded polygon,
                      convex corners rounded by hi); finite lo: a plate around a polygonal
                      opening (star die)
5      RSWEEP         lo hi z0 z1 r m, then 8 per corner: cx cy rc s ax ay bx by (6 + 8 m): SWEEP
                      with w the signed distance to a rounded polygon: straight edges from
                      b_i to a_{i+1} and, at corner i, an arc of radius rc about (cx, cy) from
                      a_i to b_i (s = +1 convex, -1 reflex; rc = 0 a sharp corner,
                      a = b = c). Convex and reflex corners can both be rounded (star die)
10     UNION          k (1): min(a, b); k > 0 a smooth union with blend width k
11     INTERSECT      k (1): max(a, b); k > 0 smooth
12     SUBTRACT       k (1): a minus b = max(a, -b); k > 0 smooth
20     PUSH_FRAME     R (9, row major) t (3) (12): the records up to the matching POP_FRAME
                      describe a part placed with pose (R, t) in the enclosing frame,
                      x_part = R^T (x - t); its results are rotated back to the tool frame
21     POP_FRAME      (0)
=====  =============  ========================================================================

Infinite bounds are stored as IEEE inf (REVOLVE / SWEEP ``lo`` or ``hi``, never both).

Exactness and smoothness
------------------------
PLANE, BOX, REVOLVE and SWEEP are exact Euclidean distances (|g| = 1), with analytic g and H
(no finite differences), in the usual sense for an SDF: d is C-infinity away from the surface's
medial axis and the boundaries between feature regions (face / edge / corner Voronoi
regions), C1 across the latter (the Hessian jumps where the surface curvature jumps, e.g.
where a flat face meets a rounding) and only C0 on the medial axis (the centre plane of a box,
the axis of a punch when its wall is closest, the bisector of a sharp polygon corner). There
the kernel picks one branch and returns finite values, never NaN: ties go to the first
candidate; on the revolution axis (rho = 0) the radial direction is taken as +x and the
curvature term f_rho / rho is replaced by its smooth limit f_rho,rho (exact when the profile
is smooth there, e.g. under the punch nose); at a polygon vertex the edge normal is used and
the vertex curvature term dropped. Close to (not on) such a set the Hessian is the exact,
large, value (e.g. ~1 / rho near the axis of a ring's inner wall).

SWEEP is exact wherever the offset curves of the polygon are regular: everywhere for a convex
polygon outside, and away from the bisectors of the sharp (reflex) corners; on those
bisectors it is the correct value with a C0 ridge (the sharp vertical edge of the swept solid).
Only convex polygon corners are rounded by the offset construction; reflex ones stay sharp.
RSWEEP rounds both, and its w (distance to a G1 outline of segments and arcs) is exact and
C1 everywhere except on the outline's medial axis (at distance rc inside a convex arc, rc
outside a reflex one, and the bisectors of sharp corners).

Hard UNION / INTERSECT / SUBTRACT (k = 0) keep the exact min / max of the operands. That is
the exact distance outside a union; inside a union and for intersections / subtractions it
is a bound that is exact wherever one operand's surface is the nearest. It is only C0 where
the two operands are equal, which includes the crease where two surfaces meet. With k > 0
the cubic polynomial smooth minimum
    h = max(k - |a - b|, 0) / k,   smin(a, b) = min(a, b) - k h^3 / 6
is used (smax(a, b) = -smin(-a, -b)); it is C2 in (a, b), so a penalty energy built on it is
C1 with a continuous Hessian across the blend, the surface gets a fillet of width ~k, and the
value deviates from the exact min by at most k / 6 and only where |a - b| < k (there |g| < 1:
the blend is not an exact distance). Outside |a - b| < k the exact min / max is kept.

Poses: a tool is placed in the world by (R, t): x_world = R x_local + t, so
x_local = R^T (x_world - t). ``sdf_world`` evaluates at world points and returns g = R g_local,
H = R H_local R^T.
"""

from __future__ import annotations

import math

import numba
import numpy as np

MAGIC = 1503.0
HEADER = 2
MAX_STACK = 16
MAX_FRAMES = 8

OP_PLANE = 1
OP_BOX = 2
OP_REVOLVE = 3
OP_SWEEP = 4
OP_RSWEEP = 5
OP_UNION = 10
OP_INTERSECT = 11
OP_SUBTRACT = 12
OP_PUSH_FRAME = 20
OP_POP_FRAME = 21

_NPARAM = {OP_PLANE: 6, OP_BOX: 7, OP_REVOLVE: 5, OP_UNION: 1, OP_INTERSECT: 1,
           OP_SUBTRACT: 1, OP_PUSH_FRAME: 12, OP_POP_FRAME: 0}
_PRIMITIVES = (OP_PLANE, OP_BOX, OP_REVOLVE, OP_SWEEP, OP_RSWEEP)
_BINARY = (OP_UNION, OP_INTERSECT, OP_SUBTRACT)

# ----------------------------------------------------------------------------------------------
# numba kernels
# ----------------------------------------------------------------------------------------------


@numba.njit(cache=True)
def _clear(g, H):
    for i in range(3):
        g[i] = 0.0
        for j in range(3):
            H[i, j] = 0.0


@numba.njit(cache=True)
def _prim_plane(prog, b, x, derivs, g, H):
    d = 0.0
    for i in range(3):
        d += prog[b + 3 + i] * (x[i] - prog[b + i])
    if derivs:
        _clear(g, H)
        for i in range(3):
            g[i] = prog[b + 3 + i]
    return d


@numba.njit(cache=True)
def _prim_box(prog, b, x, derivs, g, H, q, s):
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
def _rrect2(u, z, lo, hi, z0, z1, r, out):
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
def _segment_nearest(wx, wy, ex, ey, L2):
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
def _edge_or_point(px, py, qx, qy, nx, ny, best, inside, on_edge, derivs, gw, Hw):
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
def _polygon_sd(prog, base, m, px, py, derivs, gw, Hw):
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
def _compose_profile(prof, gw, Hw, hw_scale, derivs, g, H):
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
def _prim_revolve(prog, b, x, derivs, g, H, prof, gw, Hw):
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
def _prim_sweep(prog, b, x, derivs, g, H, prof, gw, Hw):
    m = int(prog[b + 5])
    w = _polygon_sd(prog, b + 6, m, x[0], x[1], derivs, gw, Hw)
    _rrect2(w, x[2], prog[b], prog[b + 1], prog[b + 2], prog[b + 3], prog[b + 4], prof)
    return _compose_profile(prof, gw, Hw, prof[1], derivs, g, H)


RCORNER = 8  # values per corner of a rounded polygon: cx cy rc s ax ay bx by


@numba.njit(cache=True)
def _rpolygon_sd(prog, base, m, px, py, derivs, gw, Hw):
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
def _prim_rsweep(prog, b, x, derivs, g, H, prof, gw, Hw):
    m = int(prog[b + 5])
    w = _rpolygon_sd(prog, b + 6, m, x[0], x[1], derivs, gw, Hw)
    _rrect2(w, x[2], prog[b], prog[b + 1], prog[b + 2], prog[b + 3], prog[b + 4], prof)
    return _compose_profile(prof, gw, Hw, prof[1], derivs, g, H)


@numba.njit(cache=True)
def _smin(st_d, st_g, st_H, ia, ib, k, derivs):
    """Stack slot ia := smin(slot ia, slot ib) (cubic polynomial blend, exact min if k <= 0)."""
    a = st_d[ia]
    b = st_d[ib]
    diff = abs(a - b)
    if k <= 0.0 or diff >= k:
        if b < a:
            st_d[ia] = b
            if derivs:
                for i in range(3):
                    st_g[ia, i] = st_g[ib, i]
                    for j in range(3):
                        st_H[ia, i, j] = st_H[ib, i, j]
        return
    h = 1.0 - diff / k
    if a <= b:
        wa = 1.0 - 0.5 * h * h
        st_d[ia] = a - k * h * h * h / 6.0
    else:
        wa = 0.5 * h * h
        st_d[ia] = b - k * h * h * h / 6.0
    wb = 1.0 - wa
    if derivs:
        c = h / k
        for i in range(3):
            for j in range(3):
                st_H[ia, i, j] = (wa * st_H[ia, i, j] + wb * st_H[ib, i, j]
                                  - c * (st_g[ia, i] - st_g[ib, i]) * (st_g[ia, j] - st_g[ib, j]))
        for i in range(3):
            st_g[ia, i] = wa * st_g[ia, i] + wb * st_g[ib, i]


@numba.njit(cache=True)
def _negate(st_d, st_g, st_H, i0, derivs):
    st_d[i0] = -st_d[i0]
    if derivs:
        for i in range(3):
            st_g[i0, i] = -st_g[i0, i]
            for j in range(3):
                st_H[i0, i, j] = -st_H[i0, i, j]


@numba.njit(cache=True)
def _rotate_back(R, g, H, tmp, derivs):
    """g := R g, H := R H R^T (R: part frame -> tool frame)."""
    if not derivs:
        return
    for i in range(3):
        tmp[i, 0] = R[i, 0] * g[0] + R[i, 1] * g[1] + R[i, 2] * g[2]
    for i in range(3):
        g[i] = tmp[i, 0]
    for i in range(3):
        for j in range(3):
            tmp[i, j] = R[i, 0] * H[0, j] + R[i, 1] * H[1, j] + R[i, 2] * H[2, j]
    for i in range(3):
        for j in range(3):
            H[i, j] = tmp[i, 0] * R[j, 0] + tmp[i, 1] * R[j, 1] + tmp[i, 2] * R[j, 2]


@numba.njit(cache=True)
def _workspace():
    st_d = np.empty(MAX_STACK)
    st_g = np.empty((MAX_STACK, 3))
    st_H = np.empty((MAX_STACK, 3, 3))
    fr_R = np.empty((MAX_FRAMES + 1, 3, 3))
    fr_x = np.empty((MAX_FRAMES + 1, 3))
    sc = np.empty(8)
    sc2 = np.empty(4)
    tmp = np.empty((3, 3))
    return st_d, st_g, st_H, fr_R, fr_x, sc, sc2, tmp


# explicit signatures: one compilation each, instead of one per literal value of the flags
_F1 = numba.float64[::1]
_F2 = numba.float64[:, ::1]
_F3 = numba.float64[:, :, ::1]
_B = numba.boolean


@numba.njit(numba.float64(_F1, _F1, _B, _F1, _F2, _F3, _F3, _F2, _F1, _F1, _F2), cache=True)
def _eval_point(prog, x, derivs, st_d, st_g, st_H, fr_R, fr_x, sc, sc2, tmp):
    """Run the program at one point x (tool frame). Result in st_d[0], st_g[0], st_H[0]."""
    if prog.shape[0] < HEADER + 2 or prog[0] != MAGIC:
        raise ValueError("not an SDF program (bad magic)")
    n = HEADER + int(prog[1])
    if n > prog.shape[0]:
        raise ValueError("SDF program truncated")
    lev = 0
    for i in range(3):
        fr_x[0, i] = x[i]
        for j in range(3):
            fr_R[0, i, j] = 1.0 if i == j else 0.0
    sp = 0
    pc = HEADER
    q = sc[0:3]
    s = sc[3:6]
    prof = sc[0:6]
    gw = sc2[0:2]
    while pc < n:
        op = int(prog[pc])
        npar = int(prog[pc + 1])
        b = pc + 2
        if op == OP_PUSH_FRAME:
            if lev >= MAX_FRAMES:
                raise ValueError("SDF program: frames nested too deep")
            # child local point: x_c = R^T (x_parent - t); cumulative R_c = R_parent R
            for i in range(3):
                acc = 0.0
                for j in range(3):
                    acc += prog[b + 3 * j + i] * (fr_x[lev, j] - prog[b + 9 + j])
                fr_x[lev + 1, i] = acc
            for i in range(3):
                for j in range(3):
                    acc = 0.0
                    for k in range(3):
                        acc += fr_R[lev, i, k] * prog[b + 3 * k + j]
                    fr_R[lev + 1, i, j] = acc
            lev += 1
        elif op == OP_POP_FRAME:
            if lev == 0:
                raise ValueError("SDF program: unbalanced POP_FRAME")
            lev -= 1
        elif op == OP_UNION or op == OP_INTERSECT or op == OP_SUBTRACT:
            if sp < 2:
                raise ValueError("SDF program: stack underflow")
            k = prog[b]
            ia = sp - 2
            ib = sp - 1
            if op == OP_UNION:
                _smin(st_d, st_g, st_H, ia, ib, k, derivs)
            else:
                # max(a, c) = -min(-a, -c) with c = b (intersect) or c = -b (subtract)
                _negate(st_d, st_g, st_H, ia, derivs)
                if op == OP_INTERSECT:
                    _negate(st_d, st_g, st_H, ib, derivs)
                _smin(st_d, st_g, st_H, ia, ib, k, derivs)
                _negate(st_d, st_g, st_H, ia, derivs)
            sp -= 1
        else:
            if sp >= MAX_STACK:
                raise ValueError("SDF program: stack overflow")
            xl = fr_x[lev]
            g = st_g[sp]
            H = st_H[sp]
            if op == OP_PLANE:
                d = _prim_plane(prog, b, xl, derivs, g, H)
            elif op == OP_BOX:
                d = _prim_box(prog, b, xl, derivs, g, H, q, s)
            elif op == OP_REVOLVE:
                d = _prim_revolve(prog, b, xl, derivs, g, H, prof, gw, tmp[0:2, 0:2])
            elif op == OP_SWEEP:
                d = _prim_sweep(prog, b, xl, derivs, g, H, prof, gw, tmp[0:2, 0:2])
            elif op == OP_RSWEEP:
                d = _prim_rsweep(prog, b, xl, derivs, g, H, prof, gw, tmp[0:2, 0:2])
            else:
                raise ValueError("SDF program: unknown opcode")
            if lev > 0:
                _rotate_back(fr_R[lev], g, H, tmp, derivs)
            st_d[sp] = d
            sp += 1
        pc = b + npar
    if sp != 1 or lev != 0:
        raise ValueError("SDF program: does not leave exactly one value")
    return st_d[0]


@numba.njit(numba.types.Tuple((_F1, _F2, _F3))(_F1, _F2, _F1, _F2, _B, _B), cache=True)
def _run(prog, R, t, X, posed, derivs):
    """All points: x_local = R^T (x - t) when posed; g, H rotated back by R when posed."""
    n = X.shape[0]
    d = np.empty(n)
    g = np.empty((n if derivs else 0, 3))
    H = np.empty((n if derivs else 0, 3, 3))
    st_d, st_g, st_H, fr_R, fr_x, sc, sc2, tmp = _workspace()
    xl = np.empty(3)
    for p in range(n):
        if posed:
            for i in range(3):
                xl[i] = (R[0, i] * (X[p, 0] - t[0]) + R[1, i] * (X[p, 1] - t[1])
                         + R[2, i] * (X[p, 2] - t[2]))
        else:
            for i in range(3):
                xl[i] = X[p, i]
        d[p] = _eval_point(prog, xl, derivs, st_d, st_g, st_H, fr_R, fr_x, sc, sc2, tmp)
        if derivs:
            if posed:
                _rotate_back(R, st_g[0], st_H[0], tmp, True)
            for i in range(3):
                g[p, i] = st_g[0, i]
                for j in range(3):
                    H[p, i, j] = st_H[0, i, j]
    return d, g, H


@numba.njit(cache=True)
def sdf_eval(prog, X):
    """d (n,), g (n, 3), H (n, 3, 3) of the program at points X (n, 3) in the tool frame."""
    return _run(np.ascontiguousarray(prog), np.eye(3), np.zeros(3), np.ascontiguousarray(X),
                False, True)


@numba.njit(cache=True)
def sdf_distance(prog, X):
    """Signed distance only (no derivatives, cheaper) at points X (n, 3) in the tool frame."""
    return _run(np.ascontiguousarray(prog), np.eye(3), np.zeros(3), np.ascontiguousarray(X),
                False, False)[0]


@numba.njit(cache=True)
def sdf_world(prog, R, t, X):
    """d, g, H at world points X (n, 3) of a tool with pose (R, t).

    x_local = R^T (x - t); g_world = R g_local, H_world = R H_local R^T.
    """
    return _run(np.ascontiguousarray(prog), np.ascontiguousarray(R), np.ascontiguousarray(t),
                np.ascontiguousarray(X), True, True)


@numba.njit(cache=True)
def sdf_world_distance(prog, R, t, X):
    """Signed distance only at world points X (n, 3) of a tool with pose (R, t)."""
    return _run(np.ascontiguousarray(prog), np.ascontiguousarray(R), np.ascontiguousarray(t),
                np.ascontiguousarray(X), True, False)[0]


# ----------------------------------------------------------------------------------------------
# poses
# ----------------------------------------------------------------------------------------------


def rotation(axis, angle):
    """Rotation matrix (3, 3) by ``angle`` (rad) about ``axis`` (Rodrigues)."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    K = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


def _pose(R, t):
    R = np.eye(3) if R is None else np.ascontiguousarray(R, dtype=np.float64)
    t = np.zeros(3) if t is None else np.ascontiguousarray(t, dtype=np.float64)
    if R.shape != (3, 3) or t.shape != (3,):
        raise ValueError("pose: R must be (3, 3) and t (3,)")
    return R, t


def transform(X, R, t):
    """Local -> world: x_world = R x_local + t for points X (n, 3) (applies the tool pose)."""
    R, t = _pose(R, t)
    return np.asarray(X, dtype=np.float64) @ R.T + t


def to_local(X, R, t):
    """World -> local: x_local = R^T (x_world - t) for points X (n, 3) (inverse of transform)."""
    R, t = _pose(R, t)
    return (np.asarray(X, dtype=np.float64) - t) @ R


def to_world_derivatives(g, H, R):
    """Rotate local gradients (n, 3) and Hessians (n, 3, 3) to the world: R g, R H R^T."""
    return g @ R.T, np.einsum("ij,njk,lk->nil", R, H, R)


# ----------------------------------------------------------------------------------------------
# builders
# ----------------------------------------------------------------------------------------------


def _record(op, params):
    params = np.asarray(params, dtype=np.float64).ravel()
    return np.concatenate([[float(op), float(params.size)], params])


def _program(body):
    body = np.asarray(body, dtype=np.float64)
    prog = np.concatenate([[MAGIC, float(body.size)], body])
    validate(prog)
    return prog


def _body(prog):
    prog = np.asarray(prog, dtype=np.float64)
    validate(prog)
    return prog[HEADER:]


def _records(prog):
    """Yield (opcode, params) of a validated program."""
    n = HEADER + int(prog[1])
    pc = HEADER
    while pc < n:
        op = int(prog[pc])
        npar = int(prog[pc + 1])
        yield op, prog[pc + 2: pc + 2 + npar]
        pc += 2 + npar


def validate(prog):
    """Check magic, record structure, stack discipline and parameters; raise ValueError."""
    prog = np.asarray(prog)
    if prog.ndim != 1 or prog.dtype != np.float64:
        raise ValueError("SDF program must be a float64 1-D array")
    if prog.size < HEADER + 2 or prog[0] != MAGIC:
        raise ValueError("not an SDF program (bad magic)")
    n = HEADER + int(prog[1])
    if n != prog.size:
        raise ValueError("SDF program length does not match its header")
    pc = HEADER
    sp = 0
    frames = []
    while pc < n:
        if pc + 2 > n:
            raise ValueError("SDF program: truncated record")
        op = int(prog[pc])
        npar = int(prog[pc + 1])
        if pc + 2 + npar > n:
            raise ValueError("SDF program: truncated record")
        p = prog[pc + 2: pc + 2 + npar]
        if op == OP_SWEEP:
            if npar < 6 or npar != 6 + 2 * int(p[5]) or int(p[5]) < 3:
                raise ValueError("SDF program: bad SWEEP record")
        elif op == OP_RSWEEP:
            if npar < 6 or npar != 6 + RCORNER * int(p[5]) or int(p[5]) < 3:
                raise ValueError("SDF program: bad RSWEEP record")
        elif op not in _NPARAM or npar != _NPARAM[op]:
            raise ValueError(f"SDF program: unknown opcode {op} or bad parameter count")
        if op in _PRIMITIVES:
            sp += 1
            if sp > MAX_STACK:
                raise ValueError(f"SDF program: stack deeper than {MAX_STACK}")
        elif op in _BINARY:
            if sp - (frames[-1] if frames else 0) < 2:
                raise ValueError("SDF program: stack underflow")
            sp -= 1
        elif op == OP_PUSH_FRAME:
            frames.append(sp)
            if len(frames) > MAX_FRAMES:
                raise ValueError("SDF program: frames nested too deep")
        elif op == OP_POP_FRAME:
            if not frames or sp != frames.pop() + 1:
                raise ValueError("SDF program: a frame must wrap exactly one value")
        pc += 2 + npar
    if sp != 1 or frames:
        raise ValueError("SDF program: does not leave exactly one value")
    return True


def plane(point, normal):
    """Half-space tool {n.(x - p) <= 0}: the material lies opposite to ``normal``."""
    n = np.asarray(normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    return _program(_record(OP_PLANE, np.concatenate([np.asarray(point, float), n])))


def rounded_box(half_extents, radius, center=(0.0, 0.0, 0.0)):
    """Box of half extents ``half_extents`` centred at ``center``, edges rounded by radius."""
    h = np.asarray(half_extents, dtype=np.float64)
    if h.shape != (3,) or np.any(h <= 0):
        raise ValueError("half_extents must be 3 positive numbers")
    if not 0.0 <= radius <= h.min():
        raise ValueError("radius must lie in [0, min(half_extents)]")
    return _program(_record(OP_BOX, np.concatenate([np.asarray(center, float), h, [radius]])))


def box(half_extents, center=(0.0, 0.0, 0.0)):
    """Sharp-edged box (a rounded box with radius 0)."""
    return rounded_box(half_extents, 0.0, center)


def revolved(r0, r1, z0, z1, radius=0.0):
    """Solid of revolution about z of the rounded rectangle [r0, r1] x [z0, z1] (rho, z).

    r0 <= 0: the solid reaches the axis (a capped cylinder; no corner at the axis).
    """
    lo = -np.inf if r0 <= 0.0 else float(r0)
    if not (r1 > max(r0, 0.0) and z1 > z0 and np.isfinite(r1)):
        raise ValueError("revolved: need max(r0, 0) < r1 < inf and z0 < z1")
    width = r1 - lo if np.isfinite(lo) else 2.0 * r1
    if not 0.0 <= radius <= 0.5 * min(width, z1 - z0):
        raise ValueError("revolved: corner radius larger than half the profile")
    return _program(_record(OP_REVOLVE, [lo, r1, z0, z1, radius]))


def punch(radius, height, edge_radius):
    """Cylindrical punch: rho <= radius, 0 <= z <= height, nose (z = 0) edge rounded.

    The local origin is the centre of the nose face; both rims are rounded with edge_radius
    (the upper one never touches the sheet).
    """
    return revolved(0.0, radius, 0.0, height, edge_radius)


def die_ring(opening_radius, outer_radius, height, shoulder_radius):
    """Die: opening_radius <= rho <= outer_radius, -height <= z <= 0, shoulder rounded.

    The top face is z = 0, the shoulder is the rounded rim at (opening_radius, 0); the other
    three rims of the ring cross-section carry the same radius.
    """
    return revolved(opening_radius, outer_radius, -height, 0.0, shoulder_radius)


def blank_holder(inner_radius, outer_radius, height, edge_radius=0.0):
    """Blank holder ring: inner_radius <= rho <= outer_radius, 0 <= z <= height."""
    return revolved(inner_radius, outer_radius, 0.0, height, edge_radius)


def polygon_area(points):
    """Signed area of a 2-D polygon (> 0 when counter-clockwise)."""
    p = np.asarray(points, dtype=np.float64)
    q = np.roll(p, -1, axis=0)
    return 0.5 * float(np.sum(p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]))


def _ccw(points):
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if p.shape[0] < 3:
        raise ValueError("polygon needs at least 3 vertices")
    a = polygon_area(p)
    if a == 0.0:
        raise ValueError("degenerate polygon")
    return p if a > 0 else p[::-1].copy()


def edge_normals(points):
    """Outward unit normals (m, 2) of the edges i -> i + 1 of a CCW polygon."""
    p = np.asarray(points, dtype=np.float64)
    e = np.roll(p, -1, axis=0) - p
    n = np.stack([e[:, 1], -e[:, 0]], axis=1)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def is_simple_polygon(P):
    """True if the closed polyline P (n, 2) has no two non-adjacent edges that intersect."""
    A = P
    B = np.roll(P, -1, axis=0)
    n = len(P)

    def orient(p, q, r):
        return np.sign((q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1])
                       - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0]))

    a, b = A[:, None, :], B[:, None, :]
    c, d = A[None, :, :], B[None, :, :]
    cross = (orient(a, b, c) * orient(a, b, d) < 0) & (orient(c, d, a) * orient(c, d, b) < 0)
    i, j = np.triu_indices(n, k=2)
    adjacent = (i == 0) & (j == n - 1)
    return not np.any(cross[i, j] & ~adjacent)


def offset_polygon(points, dist):
    """Mitred offset of a CCW polygon by ``dist`` (> 0 outward, < 0 inward).

    Every edge moves by dist along its outward normal and vertices are the intersections of
    neighbouring moved edges. Raises ValueError if an edge would flip (offset too large).
    """
    p = _ccw(points)
    n = edge_normals(p)
    n_prev = np.roll(n, 1, axis=0)
    den = 1.0 + np.sum(n_prev * n, axis=1)
    if np.any(den < 1e-9):
        raise ValueError("polygon has a cusp (edge reversal)")
    q = p + dist * (n_prev + n) / den[:, None]
    e0 = np.roll(p, -1, axis=0) - p
    e1 = np.roll(q, -1, axis=0) - q
    if np.any(np.sum(e0 * e1, axis=1) <= 0.0) or not is_simple_polygon(q):
        raise ValueError(f"polygon offset by {dist} inverts an edge: offset too large")
    return q


def sweep(points2d, lo, hi, z0, z1, radius=0.0):
    """Raw SWEEP primitive (see module docstring); points2d are made counter-clockwise."""
    p = _ccw(points2d)
    if not (z1 > z0 and hi > lo and not (np.isinf(lo) and np.isinf(hi))):
        raise ValueError("sweep: need lo < hi (not both infinite) and z0 < z1")
    width = hi - lo if np.isfinite(hi - lo) else np.inf
    if not 0.0 <= radius <= 0.5 * min(width, z1 - z0):
        raise ValueError("sweep: corner radius larger than half the profile")
    return _program(_record(OP_SWEEP, np.concatenate([[lo, hi, z0, z1, radius, p.shape[0]],
                                                      p.ravel()])))


def rounded_polygon(points, radii):
    """Corners (m, 8) of a simple polygon whose vertex i is rounded by an arc of radius
    radii[i] tangent to both edges: convex and reflex corners alike (0 keeps it sharp).

    Row i: cx cy rc s ax ay bx by (arc centre, radius, +1 convex / -1 reflex, tangent points
    on the incoming and outgoing edge), counter-clockwise, the layout of an RSWEEP record.
    Raises ValueError when two roundings would overlap on an edge or the outline folds.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    r = np.broadcast_to(np.asarray(radii, dtype=np.float64), (len(p),)).copy()
    if np.any(r < 0) or not np.all(np.isfinite(r)):
        raise ValueError("corner radii must be finite and >= 0")
    if len(p) < 3 or polygon_area(p) == 0.0:
        raise ValueError("polygon needs at least 3 vertices and a nonzero area")
    if polygon_area(p) < 0.0:  # made counter-clockwise: the radii follow their vertices
        p, r = p[::-1].copy(), r[::-1].copy()
    u_out = np.roll(p, -1, axis=0) - p
    length = np.linalg.norm(u_out, axis=1)
    if np.any(length <= 0.0):
        raise ValueError("polygon has repeated vertices")
    u_out /= length[:, None]
    u_in = np.roll(u_out, 1, axis=0)
    cross = u_in[:, 0] * u_out[:, 1] - u_in[:, 1] * u_out[:, 0]
    phi = np.arctan2(np.abs(cross), np.sum(u_in * u_out, axis=1))  # turning angle
    if np.any(phi > np.pi - 1e-6):
        raise ValueError("polygon has a cusp (edge reversal)")
    r[phi < 1e-12] = 0.0  # a straight vertex needs no rounding
    tang = r * np.tan(0.5 * phi)
    if np.any(tang + np.roll(tang, -1) > length * (1.0 + 1e-12)):
        i = int(np.argmax(tang + np.roll(tang, -1) - length))
        raise ValueError(f"corner radii of vertices {i} and {(i + 1) % len(p)} overlap on "
                         "their common edge: radii too large")
    a = p - tang[:, None] * u_in
    b = p + tang[:, None] * u_out
    bis = u_out - u_in
    nb = np.linalg.norm(bis, axis=1)
    bis = np.divide(bis, nb[:, None], out=np.zeros_like(bis), where=nb[:, None] > 0)
    c = p + (r / np.cos(0.5 * phi))[:, None] * bis
    s = np.where(cross >= 0.0, 1.0, -1.0)
    chord = np.stack([a, b], axis=1).reshape(-1, 2)
    keep = np.ones(len(chord), dtype=bool)
    keep[1:] = np.linalg.norm(np.diff(chord, axis=0), axis=1) > 1e-12 * np.abs(p).max()
    if not is_simple_polygon(chord[keep]):
        raise ValueError("rounded polygon is not simple")
    return np.column_stack([c, r, s, a, b])


def rounded_sweep(corners, lo, hi, z0, z1, radius=0.0):
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
    return _program(_record(OP_RSWEEP, np.concatenate([[lo, hi, z0, z1, radius, C.shape[0]],
                                                       C.ravel()])))


def extruded_polygon(points2d, z0, z1, corner_radius=0.0, edge_radius=0.0,
                     reflex_radius=0.0):
    """Prism over a simple 2-D polygon between z0 and z1.

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
        p = _ccw(points2d)
        u = np.roll(p, -1, axis=0) - p
        v = p - np.roll(p, 1, axis=0)
        convex = v[:, 0] * u[:, 1] - v[:, 1] * u[:, 0] >= 0.0
        corners = rounded_polygon(p, np.where(convex, corner_radius, reflex_radius))
        return rounded_sweep(corners, -np.inf, 0.0, z0, z1, edge_radius)
    inner = offset_polygon(points2d, -corner_radius) if corner_radius > 0 else _ccw(points2d)
    return sweep(inner, -np.inf, corner_radius, z0, z1, edge_radius)


def star_points(n_points, r_outer, r_inner, phase=0.0):
    """Vertices (2 n_points, 2) of a star, CCW, tips at r_outer, valleys at r_inner."""
    if n_points < 2 or not 0.0 < r_inner < r_outer:
        raise ValueError("star: need n_points >= 2 and 0 < r_inner < r_outer")
    ang = phase + np.pi * np.arange(2 * n_points) / n_points
    r = np.where(np.arange(2 * n_points) % 2 == 0, r_outer, r_inner)
    return np.stack([r * np.cos(ang), r * np.sin(ang)], axis=1)


def star(n_points, r_outer, r_inner, height, corner_radius=0.0, edge_radius=0.0, phase=0.0,
         valley_radius=0.0):
    """Star-shaped prism (punch, or a form block), 0 <= z <= height; tips rounded by
    corner_radius, valleys (reflex corners) by valley_radius (0: sharp)."""
    return extruded_polygon(star_points(n_points, r_outer, r_inner, phase), 0.0, height,
                            corner_radius, edge_radius, valley_radius)


def star_die(n_points, r_outer, r_inner, height, shoulder_radius, corner_radius=0.0,
             width=None, phase=0.0, valley_radius=None):
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


def _combine(op, a, b, blend):
    if blend < 0.0:
        raise ValueError("blend must be >= 0")
    return _program(np.concatenate([_body(a), _body(b), _record(op, [blend])]))


def union(a, b, blend=0.0):
    """a or b: exact min for blend = 0 (C0 crease), cubic smooth min (C2) of width blend."""
    return _combine(OP_UNION, a, b, blend)


def intersect(a, b, blend=0.0):
    """a and b: exact max for blend = 0, smooth max of width blend."""
    return _combine(OP_INTERSECT, a, b, blend)


def subtract(a, b, blend=0.0):
    """a minus b = max(a, -b): exact for blend = 0, smooth (filleted) for blend > 0."""
    return _combine(OP_SUBTRACT, a, b, blend)


def moved(a, R=None, t=None):
    """Place program a with pose (R, t) inside a tool: x_a = R^T (x - t)."""
    R, t = _pose(R, t)
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-12) or np.linalg.det(R) < 0:
        raise ValueError("R must be a proper rotation")
    return _program(np.concatenate([_record(OP_PUSH_FRAME, np.concatenate([R.ravel(), t])),
                                    _body(a), _record(OP_POP_FRAME, [])]))


def parse(prog):
    """Expression tree of a program, for inspection and meshing.

    Nodes: ("plane", p, n), ("box", c, h, r), ("revolve", lo, hi, z0, z1, r),
    ("sweep", lo, hi, z0, z1, r, poly (m, 2)), ("rsweep", lo, hi, z0, z1, r, corners (m, 8)
    as cx cy rc s ax ay bx by), ("union" | "intersect" | "subtract", k, a, b),
    ("frame", R, t, child).
    """
    validate(prog)
    stack = []
    frames = []
    for op, p in _records(np.asarray(prog)):
        if op == OP_PLANE:
            stack.append(("plane", p[:3].copy(), p[3:6].copy()))
        elif op == OP_BOX:
            stack.append(("box", p[:3].copy(), p[3:6].copy(), float(p[6])))
        elif op == OP_REVOLVE:
            stack.append(("revolve", *map(float, p[:5])))
        elif op == OP_SWEEP:
            stack.append(("sweep", *map(float, p[:5]), p[6:].reshape(-1, 2).copy()))
        elif op == OP_RSWEEP:
            stack.append(("rsweep", *map(float, p[:5]), p[6:].reshape(-1, RCORNER).copy()))
        elif op in _BINARY:
            b = stack.pop()
            a = stack.pop()
            name = {OP_UNION: "union", OP_INTERSECT: "intersect", OP_SUBTRACT: "subtract"}[op]
            stack.append((name, float(p[0]), a, b))
        elif op == OP_PUSH_FRAME:
            frames.append((p[:9].reshape(3, 3).copy(), p[9:12].copy()))
        elif op == OP_POP_FRAME:
            R, t = frames.pop()
            stack.append(("frame", R, t, stack.pop()))
    return stack[0]

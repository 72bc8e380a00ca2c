"""SDF programs: rigid forming tools as signed distances with exact gradients and Hessians.

A tool shape is a small program: a float64 1-D array holding a list of primitives and CSG
operations in postfix (reverse Polish) order. One numba kernel, ``sdf_eval(prog, X)``
(sim.tools.evaluate), runs it for every point of ``X`` (n, 3), given in the tool's local frame,
and returns the signed distance d (n,), its gradient g (n, 3) and Hessian H (n, 3, 3). Sign
convention: d > 0 outside the tool (in the air), d < 0 inside the tool material, so g is the
outward normal on the surface. Units: whatever the caller uses, in this project SI (m); d in m,
g dimensionless, H in 1/m.

Program layout
--------------
::

    prog = [MAGIC, n_body, record, record, ...]        MAGIC = 1503.0, n_body = len(prog) - 2
    record = [opcode, n_params, p_0, ..., p_{n_params-1}]

Records are run left to right on a value stack (each value is a triple d, g, H expressed in the
tool frame); primitives push one value, binary operations pop two (a pushed before b) and push
one. A valid program leaves exactly one value; the stack is at most MAX_STACK deep and frames
nest at most MAX_FRAMES deep. Every builder (sim.tools.builders) returns a complete program, and
the combinators (``union`` ...) splice the bodies of their operands, so programs nest freely.

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
6      GRID           ox oy oz h B nx ny nz n_active 0, then its table, corner distances and
                      B-spline coefficients (sim.tools.grid, whose docstring gives the
                      layout): a distance sampled near a surface (a tool made from a triangle
                      mesh, sim.tools.meshtool) and interpolated by tricubic B-splines
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

from collections.abc import Iterator

import numpy as np
import numpy.typing as npt

MAGIC = 1503.0
HEADER = 2
MAX_STACK = 16
MAX_FRAMES = 8

OP_PLANE = 1
OP_BOX = 2
OP_REVOLVE = 3
OP_SWEEP = 4
OP_RSWEEP = 5
OP_GRID = 6
OP_UNION = 10
OP_INTERSECT = 11
OP_SUBTRACT = 12
OP_PUSH_FRAME = 20
OP_POP_FRAME = 21

_NPARAM = {OP_PLANE: 6, OP_BOX: 7, OP_REVOLVE: 5, OP_UNION: 1, OP_INTERSECT: 1,
           OP_SUBTRACT: 1, OP_PUSH_FRAME: 12, OP_POP_FRAME: 0}
_PRIMITIVES = (OP_PLANE, OP_BOX, OP_REVOLVE, OP_SWEEP, OP_RSWEEP, OP_GRID)
_BINARY = (OP_UNION, OP_INTERSECT, OP_SUBTRACT)

RCORNER = 8  # values per corner of a rounded polygon: cx cy rc s ax ay bx by

# a node of a parsed program (``parse``): a tuple whose first item names its kind
Node = tuple


def record(op: int, params: npt.ArrayLike) -> np.ndarray:
    params = np.asarray(params, dtype=np.float64).ravel()
    return np.concatenate([[float(op), float(params.size)], params])


def program(body: npt.ArrayLike) -> np.ndarray:
    body = np.asarray(body, dtype=np.float64)
    prog = np.concatenate([[MAGIC, float(body.size)], body])
    validate(prog)
    return prog


def body(prog: npt.ArrayLike) -> np.ndarray:
    prog = np.asarray(prog, dtype=np.float64)
    validate(prog)
    return prog[HEADER:]


def records(prog: np.ndarray) -> Iterator[tuple[int, np.ndarray]]:
    """Yield (opcode, params) of a validated program."""
    n = HEADER + int(prog[1])
    pc = HEADER
    while pc < n:
        op = int(prog[pc])
        npar = int(prog[pc + 1])
        yield op, prog[pc + 2: pc + 2 + npar]
        pc += 2 + npar


def validate(prog: npt.ArrayLike) -> bool:
    """Check magic, record structure, stack discipline and parameters; raise ValueError."""
    prog = np.asarray(prog)
    if prog.ndim != 1 or prog.dtype != np.float64:
        raise ValueError("SDF program must be a float64 1-D array")
    if prog.size < HEADER + 2 or prog[0] != MAGIC:
        raise ValueError("not an SDF program (bad magic)")
    n = HEADER + int(prog[1])
    if n != prog.size:
        raise ValueError("SDF program length does not match its header")
    sp = 0
    frames = []
    for op in _checked_records(prog, n):
        sp = _stack_step(op, sp, frames)
    if sp != 1 or frames:
        raise ValueError("SDF program: does not leave exactly one value")
    return True


def _checked_records(prog: np.ndarray, n: int) -> Iterator[int]:
    """Yield the opcode of each record of ``prog[:n]``, its structure and parameters checked."""
    pc = HEADER
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
        elif op == OP_GRID:
            _check_grid(p)
        elif op not in _NPARAM or npar != _NPARAM[op]:
            raise ValueError(f"SDF program: unknown opcode {op} or bad parameter count")
        yield op
        pc += 2 + npar


def _check_grid(p: np.ndarray) -> None:
    """A GRID record's sizes agree with its head and its table names only stored bricks."""
    from sim.tools.grid import GRID_HEAD, grid_sizes

    if p.size < GRID_HEAD or not (p[3] > 0 and p[4] >= 1 and np.all(p[5:9] >= 1)):
        raise ValueError("SDF program: bad GRID record")
    n_tab, n_far, n_coef = grid_sizes(p)
    if p.size != GRID_HEAD + n_tab + n_far + n_coef:
        raise ValueError("SDF program: bad GRID record (sizes)")
    table = p[GRID_HEAD:GRID_HEAD + n_tab]
    if table.size and (table.min() < -1 or table.max() >= p[8]):
        raise ValueError("SDF program: bad GRID record (table)")


def _stack_step(op: int, sp: int, frames: list[int]) -> int:
    """The value stack's depth after record ``op``; ``frames`` the depths at the open frames."""
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
    return sp


def parse(prog: npt.ArrayLike) -> Node:
    """Expression tree of a program, for inspection and meshing.

    Nodes: ("plane", p, n), ("box", c, h, r), ("revolve", lo, hi, z0, z1, r),
    ("sweep", lo, hi, z0, z1, r, poly (m, 2)), ("rsweep", lo, hi, z0, z1, r, corners (m, 8)
    as cx cy rc s ax ay bx by), ("grid", lo (3,), hi (3,)) (its box),
    ("union" | "intersect" | "subtract", k, a, b), ("frame", R, t, child).
    """
    validate(prog)
    stack = []
    frames = []
    for op, p in records(np.asarray(prog)):
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
        elif op == OP_GRID:
            side = p[3] * p[4] * p[5:8]
            stack.append(("grid", p[:3].copy(), p[:3] + side))
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

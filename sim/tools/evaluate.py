"""The SDF evaluator: one numba kernel runs a program (sim.tools.program) on a value stack
for every point, in the tool frame or posed in the world (x_world = R x_local + t:
``sdf_world`` returns g = R g_local, H = R H_local R^T)."""

from __future__ import annotations

import numba
import numpy as np

from sim.tools.grid import prim_grid
from sim.tools.primitives import prim_box, prim_plane, prim_revolve, prim_rsweep, prim_sweep
from sim.tools.program import (
    HEADER,
    MAGIC,
    MAX_FRAMES,
    MAX_STACK,
    OP_BOX,
    OP_GRID,
    OP_INTERSECT,
    OP_PLANE,
    OP_POP_FRAME,
    OP_PUSH_FRAME,
    OP_REVOLVE,
    OP_RSWEEP,
    OP_SUBTRACT,
    OP_SWEEP,
    OP_UNION,
)


@numba.njit(cache=True)
def _smin(st_d: np.ndarray, st_g: np.ndarray, st_H: np.ndarray, ia: int, ib: int, k: float,
          derivs: bool) -> None:
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
def _negate(st_d: np.ndarray, st_g: np.ndarray, st_H: np.ndarray, i0: int, derivs: bool) -> None:
    st_d[i0] = -st_d[i0]
    if derivs:
        for i in range(3):
            st_g[i0, i] = -st_g[i0, i]
            for j in range(3):
                st_H[i0, i, j] = -st_H[i0, i, j]


@numba.njit(cache=True)
def _rotate_back(R: np.ndarray, g: np.ndarray, H: np.ndarray, tmp: np.ndarray,
                 derivs: bool) -> None:
    """g := R g, H := R H R^T (R (3, 3): part frame -> tool frame; g (3,), H, tmp (3, 3))."""
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
def _workspace() -> tuple[np.ndarray, ...]:
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


# the stack machine's dispatch: one branch per opcode in the per-point loop of every contact
# evaluation; it stays one kernel so the branches share the point's workspace in registers
@numba.njit(numba.float64(_F1, _F1, _B, _F1, _F2, _F3, _F3, _F2, _F1, _F1, _F2), cache=True)
def _eval_point(prog: np.ndarray, x: np.ndarray, derivs: bool,  # noqa: C901
                st_d: np.ndarray, st_g: np.ndarray, st_H: np.ndarray, fr_R: np.ndarray,
                fr_x: np.ndarray, sc: np.ndarray, sc2: np.ndarray, tmp: np.ndarray) -> float:
    """Run the program at one point x (3,) (tool frame). Result in st_d[0], st_g[0], st_H[0].

    Workspace (``_workspace``): st_d (MAX_STACK,), st_g (MAX_STACK, 3), st_H (MAX_STACK, 3, 3)
    the value stack; fr_R (MAX_FRAMES + 1, 3, 3), fr_x (MAX_FRAMES + 1, 3) each open frame's
    rotation to the tool frame and local point; sc (8,), sc2 (4,), tmp (3, 3) scratch.
    """
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
                d = prim_plane(prog, b, xl, derivs, g, H)
            elif op == OP_BOX:
                d = prim_box(prog, b, xl, derivs, g, H, q, s)
            elif op == OP_REVOLVE:
                d = prim_revolve(prog, b, xl, derivs, g, H, prof, gw, tmp[0:2, 0:2])
            elif op == OP_SWEEP:
                d = prim_sweep(prog, b, xl, derivs, g, H, prof, gw, tmp[0:2, 0:2])
            elif op == OP_RSWEEP:
                d = prim_rsweep(prog, b, xl, derivs, g, H, prof, gw, tmp[0:2, 0:2])
            elif op == OP_GRID:
                d = prim_grid(prog, b, xl, derivs, g, H, q, s)
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
def _run(prog: np.ndarray, R: np.ndarray, t: np.ndarray, X: np.ndarray, posed: bool,
         derivs: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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
def sdf_eval(prog: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """d (n,), g (n, 3), H (n, 3, 3) of the program at points X (n, 3) in the tool frame."""
    return _run(np.ascontiguousarray(prog), np.eye(3), np.zeros(3), np.ascontiguousarray(X),
                False, True)


@numba.njit(cache=True)
def sdf_distance(prog: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Signed distance only (no derivatives, cheaper) at points X (n, 3) in the tool frame."""
    return _run(np.ascontiguousarray(prog), np.eye(3), np.zeros(3), np.ascontiguousarray(X),
                False, False)[0]


@numba.njit(cache=True)
def sdf_world(prog: np.ndarray, R: np.ndarray, t: np.ndarray,
              X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """d, g, H at world points X (n, 3) of a tool with pose (R (3, 3), t (3,)).

    x_local = R^T (x - t); g_world = R g_local, H_world = R H_local R^T.
    """
    return _run(np.ascontiguousarray(prog), np.ascontiguousarray(R), np.ascontiguousarray(t),
                np.ascontiguousarray(X), True, True)


@numba.njit(cache=True)
def sdf_world_distance(prog: np.ndarray, R: np.ndarray, t: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Signed distance only at world points X (n, 3) of a tool with pose (R, t)."""
    return _run(np.ascontiguousarray(prog), np.ascontiguousarray(R), np.ascontiguousarray(t),
                np.ascontiguousarray(X), True, False)[0]


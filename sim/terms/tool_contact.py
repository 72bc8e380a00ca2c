"""Contact of the sheet's skins with one rigid tool: penalty normal force plus lagged smoothed
Coulomb friction (sim.terms.contact_kernels), as one energy term. A scene builds one such term per
tool and none without tools.

Friction lags the normal force (sim.terms.contact_kernels): ``lag_change(x, take=True)``
refreshes it from a state, which Newton does at its iterates near convergence until it no
longer changes (sim.solve.newton), so a converged step slides with |f_t| = mu f_n of its own
normal force.

The normal force is the C2 penalty (sim.terms.contact_kernels, ``c2=True``): its stiffness ramps up
over a contact layer ``delta`` (2 % of the thickness) outside the tool surface instead of jumping by
k where a node enters it. With the jump, a node that ends a Newton step at the layer's edge sees a
Hessian that is wrong by k times its last move, and the residual stalls there at a level set by the
last bits of that move (measured: 1e-5 N against a floor of 1e-7 N, on one CPU code path and not
another). A skin placed exactly on a tool is inside the layer and already held by it (no free rigid
mode at the first step). The tool moves rigidly: a translation (velocity plus keyframed offsets) and
a keyframed rotation about its origin, given as a rotation vector (axis * angle, rad) interpolated
linearly between keyframes (exact for a fixed axis). Its pose (R, t) places the SDF (x_world = R
x_local + t) for contact, friction (the tool's displacement over a step at each node,
sim.terms.contact_kernels.tool_displacement) and display. Both are integrated step by step from
their increments, so a speed changed between steps takes effect from the next step on.

Only the tool's candidate nodes are evaluated (sim.terms.contact_reach): those within half a
sheet thickness of the contact layer when the list was made, the list made again from every
node once one left out may have moved into the layer. Friction's nodes are those of its lagged
normal force, wherever they are now.

Force control (a blank holder): the tool's z offset is an unknown of the system, stored as an
extra "node" row ``x[vdof]`` whose x and y are held. The term then adds the work of the
pressing force, F * x[vdof, 2], and the couplings: with u the tool offset, contact and
friction (slip relative to the tool, which moves by u - u_start over the step besides its
prescribed motion) depend on x_i - u, so dE/du = -sum_i g_i, d2E/du2 = sum_i H_i and
d2E/dx_i du = -H_i, with g, H the sum of both.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import numpy.typing as npt

from sim.solve.assembly import Pattern, scatter_node_blocks
from sim.terms import Term
from sim.terms.contact_kernels import (
    friction,
    normal_forces,
    penalty_contact,
    penalty_energy,
    tool_displacement,
)
from sim.terms.contact_reach import Reach
from sim.tools.evaluate import sdf_world_distance
from sim.tools.pose import rotation

EYE = np.eye(3)
NONE = np.zeros(0, np.int64)
# the nodes with a force from one part of the term: indices into its nodes (a,), gradient
# (a, 3), Hessian (a, 3, 3)
Forces = tuple[np.ndarray, np.ndarray, np.ndarray]
# how far beyond its contact layer a node stays on a tool's candidate list (sim.terms.
# contact_reach), in layers: 25 is half the sheet's thickness at the model's delta = 2 % of
# it, about what the sheet and a moving tool travel in a forming step, so the list is made
# about once per step instead of the distance of every skin node at every evaluation
REACH_LAYERS = 25.0


def rotation_matrix(rv: npt.ArrayLike) -> np.ndarray:
    """Rotation (3, 3) of a rotation vector (axis * angle, rad)."""
    angle = float(np.linalg.norm(rv))
    return rotation(rv, angle) if angle > 0 else EYE.copy()


def quaternion_wxyz(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a rotation matrix (for display poses)."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return np.array([w, x, y, z])


class ToolContact(Term):
    """nodes: candidate sheet nodes (both skins) ``(m,)``; prog: SDF program; position (3,)
    at t = 0; velocity (3,) per unit time; k penalty stiffness (N/m); mu Coulomb coefficient.
    ``vdof``: row of x holding the tool's solved offset (force control) or None; ``force`` (N)
    presses the tool along -z; ``pair_slots (m, 3, 3)`` the CSR slots of the (node, vdof)
    blocks."""

    barrier = True

    def __init__(self, name: str, prog: npt.ArrayLike, nodes: npt.ArrayLike,
                 position: npt.ArrayLike, velocity: npt.ArrayLike, k: float, mu: float,
                 eps_v: float, pattern: Pattern, delta: float = 0.0, vdof: int | None = None,
                 force: float = 0.0, pair_slots: np.ndarray | None = None,
                 stop: float | None = None, keyframes: Sequence[Sequence[float]] = ()):
        self.name = f"contact:{name}"
        self.tool = name
        self.prog = np.ascontiguousarray(prog, float)
        self.nodes = np.asarray(nodes, np.int64)
        self.position = np.asarray(position, float).copy()  # committed
        self.velocity = np.asarray(velocity, float)
        kf = np.asarray(keyframes, float)
        kf = kf.reshape(-1, kf.shape[-1] if kf.size else 4)
        if kf.shape[1] == 4:  # translation only
            kf = np.hstack([kf, np.zeros((len(kf), 3))])
        self._path_t, self._path_u = kf[:, 0], kf[:, 1:]  # (k,), (k, 6): offset, rotation
        start = self.path(0.0)  # where the path begins (held before its first time)
        self.position += start[:3]
        self.rot = start[3:].copy()  # committed rotation vector
        self._origin = self.position.copy(), self.rot.copy()  # where the path starts from
        self.rot_now = self.rot.copy()
        self.R_now = rotation_matrix(self.rot)
        self.force_scale = 1.0
        self.moving = True  # False in the release (springback) stage: the tool stays put
        self.k, self.mu, self.eps_v = float(k), float(mu), float(eps_v)
        self.delta = float(delta)
        self.reach = Reach(self.prog, self.nodes, self.delta, REACH_LAYERS * self.delta)
        self.pattern = pattern
        self.vdof, self.force, self.pair_slots = vdof, float(force), pair_slots
        # the distance-block stop: a spring 100x the contact stiffness of all candidate nodes,
        # so the tool rests on it without measurable give
        self.stop = stop
        self.k_stop = 100.0 * self.k * len(self.nodes)
        # Hessian-only floor on the tool DoF: a tool that loses contact (the flange has left
        # the holder) would make the matrix singular; with it the tool drops in a few Newton
        # steps of at most F / k_floor each, the line search keeping the energy decreasing.
        # It fills in only what contact leaves below it (_add_hessian): added in contact as
        # well, it is a tenth of the holder's stiffness through the sheet, and Newton
        # converged linearly, the residual falling 5-7x per iteration instead of squaring
        self.k_floor = 1e-4 * self.k * len(self.nodes)
        self.t_now = self.position.copy()
        self.lagged = None
        self.settled = False  # a step converged: the state a step starts from is in equilibrium
        # Newton's protocol (as Elasticity): nonzero = PSD-project each node block; the exact
        # block is indefinite next to convex tool edges (e' H with e' < 0)
        self.project = 1

    def translation(self, x: np.ndarray) -> np.ndarray:
        """Where the tool is at state x (its offset is part of x under force control)."""
        return self.t_now + x[self.vdof] if self.vdof is not None else self.t_now

    def path(self, t: float) -> np.ndarray:
        """Keyframed offset and rotation vector (6,) at scene time t (zero without keyframes)."""
        if not len(self._path_t):
            return np.zeros(6)
        return np.array([np.interp(t, self._path_t, self._path_u[:, c]) for c in range(6)])

    def planned(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The pose (R, translation) the tool's velocity and keyframes give it at scene time t
        (a force-controlled tool's solved offset is not in it)."""
        p, (position, rot) = self.path(t) - self.path(0.0), self._origin
        return rotation_matrix(rot + p[3:]), position + t * self.velocity + p[:3]

    @property
    def moves(self) -> bool:
        return bool(np.any(self.velocity) or len(self._path_t))

    def travel(self, t0: float, t1: float, points: np.ndarray) -> float:
        """Largest distance the tool moves from scene time t0 to t1, at any of ``points``
        (n, 3): its translation plus its rotation angle times the farthest point's distance
        from the tool's origin (the rotation centre)."""
        if not self.moving:
            return 0.0
        d = self.path(t1) - self.path(t0)
        d[:3] += (t1 - t0) * self.velocity
        turn = float(np.linalg.norm(d[3:]))
        reach = float(np.linalg.norm(points - self.t_now, axis=1).max()) if turn else 0.0
        return float(np.linalg.norm(d[:3])) + turn * reach

    def begin_step(self, t: float, dt: float, x: np.ndarray) -> None:
        step = self.path(t) - self.path(t - dt)
        step[:3] += dt * self.velocity
        if not self.moving:
            step = 0.0 * step
        self.t_now = self.position + step[:3]
        self.rot_now = self.rot + step[3:]
        self.R_now = rotation_matrix(self.rot_now)
        self._R0 = rotation_matrix(self.rot)
        # slip is measured from the state at the start of the step; friction lags the normal
        # force of that state, refreshed within the step by Newton. From the rest placement
        # before the first converged step the lag is a guess (``guessed_lag``): a skin
        # placed on a tool sits in its contact layer and carries k delta / 2 per node there,
        # which holds a part that only friction holds through Newton's first correction, but
        # is a pressure of hundreds of MPa that no equilibrium holds. Kept until the first
        # refresh near convergence, it dragged the nodes lifting off the punch with it, and the
        # cup's first step took 27 iterations; followed from the first correction on, 19.
        self._start = x[self.nodes].copy()
        self._start_u = x[self.vdof].copy() if self.vdof is not None else 0.0
        self.lagged = None
        self.guessed_lag = not self.settled
        if self.mu > 0:
            here = self.position + (x[self.vdof] if self.vdof is not None else 0.0)
            self._lag(*normal_forces(self._start, self.prog, self._R0, here, self.k,
                                     self.delta, c2=True))

    def seat(self, x: np.ndarray) -> None:
        """A force-controlled tool that the predicted state x leaves without contact is put,
        in place, at the height where its contact with x carries its force (or on its stop
        when nothing carries it above that). Continued from the last increment, a blank
        holder that rose with the flange in the first step started the second one above the
        sheet: its Hessian then held only k_floor, and Newton's first correction sent it far
        into the sheet, which backtracking cut to a 64th over two iterations."""
        if self.vdof is None or not len(self.nodes):
            return
        y = x.copy()
        push = self.force * self.force_scale

        def unbalanced(u: float) -> float:  # the height's residual: > 0 while it should sink
            y[self.vdof, 2] = u
            gp = penalty_contact(y[self.nodes], self.prog, self.R_now, self.translation(y),
                                 self.k, self.delta, c2=True)[1]
            return push - float(gp[:, 2].sum())

        u = float(x[self.vdof, 2])
        if unbalanced(u) < push:  # in contact: the predictor's height stands
            return
        # for a flat face pressing along -z the gap shrinks by what the tool sinks, so the
        # balance lies within the nearest gap plus the layer below; twice that for a face
        # that is not flat
        lo = u - 2.0 * (max(float(self.gap(x).min()), 0.0) + self.delta)
        if self.stop is not None:
            lo = max(lo, self.stop)
        if unbalanced(lo) >= 0.0:  # nothing carries it down to there
            if self.stop is not None and lo == self.stop:
                x[self.vdof, 2] = lo
            return
        hi = u
        for _ in range(64):  # bisection to the spacing of the doubles at the height
            mid = 0.5 * (lo + hi)
            if mid in (lo, hi):
                break
            lo, hi = (mid, hi) if unbalanced(mid) < 0.0 else (lo, mid)
        x[self.vdof, 2] = hi

    def _lag(self, lam: np.ndarray, nrm: np.ndarray) -> None:
        act = lam > 0
        # the prescribed motion over the step of the tool points under the nodes
        disp = tool_displacement(self._start[act], self._R0, self.position, self.R_now,
                                 self.t_now)
        self.lagged = (act, self._start[act], np.ascontiguousarray(disp), lam[act], nrm[act],
                        lam)

    @property
    def lags(self) -> bool:
        return self.mu > 0

    def relag(self, x: np.ndarray) -> float:
        """Take the normal forces of state x as the lagged ones; returns their largest change
        relative to the largest normal force (0 without friction)."""
        return self.lag_change(x, take=True)

    def lag_change(self, x: np.ndarray, take: bool = False) -> float:
        """Largest change of the normal forces at state x from the lagged ones, relative to the
        largest (0 without friction); ``take``: they become the lagged ones."""
        if self.mu == 0:
            return 0.0
        t = self.translation(x)
        near = self.reach.near(x, self.R_now, t)
        lam, nrm = np.zeros(len(self.nodes)), np.zeros((len(self.nodes), 3))
        lam[near], nrm[near] = normal_forces(x[self.nodes[near]], self.prog, self.R_now, t,
                                             self.k, self.delta, c2=True)
        old = self.lagged[5] if self.lagged is not None else np.zeros_like(lam)
        if take:
            self._lag(lam, nrm)
        top = float(lam.max()) if lam.size else 0.0
        return float(np.abs(lam - old).max()) / top if top > 0 else 0.0

    def lag_coupling(self, x: np.ndarray) -> Callable[[np.ndarray], np.ndarray] | None:
        """What the lagged energy's Hessian leaves out of the friction forces' Jacobian at x,
        right after the lag was taken there, as v -> J v: a node's friction force is linear
        in its normal force lam (f = lam w), which the energy holds while lam depends on x
        through the node's gap, so J v = w (grad lam . v) per node in contact (and minus
        their sum on the tool's solved height, as the slip is relative to it). Newton left
        with the lagged Hessian alone converges at the rate of this coupling."""
        if not self.lags or self.lagged is None or not self.lagged[0].any():
            return None
        act, X0, disp, lam, nrm, _ = self.lagged
        nodes = self.nodes[act]
        Xa = x[nodes]
        if self.vdof is not None:
            Xa = Xa - (x[self.vdof] - self._start_u)
        w = friction(Xa, X0, disp, lam, nrm, self.mu, self.eps_v)[1] / lam[:, None]
        dlam = normal_forces(x[nodes], self.prog, self.R_now, self.translation(x), self.k,
                             self.delta, c2=True, gradients=True)[2]
        vdof = self.vdof

        def apply(v: np.ndarray) -> np.ndarray:
            rel = v[nodes] - v[vdof] if vdof is not None else v[nodes]
            f = w * np.einsum("ij,ij->i", dlam, rel)[:, None]
            out = np.zeros_like(v)
            np.add.at(out, nodes, f)
            if vdof is not None:
                out[vdof] -= f.sum(0)
            return out

        return apply

    def commit(self, x: np.ndarray) -> None:
        self.settled = True
        self.position = self.t_now.copy()
        self.rot = self.rot_now.copy()

    def _eval(self, x: np.ndarray) -> tuple[float, Forces, Forces]:
        """The energy and the nodes with a force, as (indices into ``nodes`` (a,), gradient
        (a, 3), Hessian (a, 3, 3)): the penalty's (the candidates in the contact layer) and
        friction's (the nodes of the lagged normal force)."""
        t = self.translation(x)
        near = self.reach.near(x, self.R_now, t)
        E, g, H, active, _ = penalty_contact(x[self.nodes[near]], self.prog, self.R_now, t,
                                             self.k, self.delta, c2=True,
                                             project_psd=bool(self.project))
        pen = (near[active], g[active], H[active])
        fri = (NONE, np.zeros((0, 3)), np.zeros((0, 3, 3)))
        if self.mu > 0 and self.lagged is not None and self.lagged[0].any():
            act, X0, disp, lam, nrm, _ = self.lagged
            idx = np.flatnonzero(act)
            Xa = x[self.nodes[idx]]
            if self.vdof is not None:  # slip relative to the tool, whose height is solved
                Xa = Xa - (x[self.vdof] - self._start_u)
            Ef, gfa, Hfa = friction(Xa, X0, disp, lam, nrm, self.mu, self.eps_v)
            E += Ef
            fri = (idx, gfa, Hfa)
        return E + self._tool_energy(x), pen, fri

    def _tool_energy(self, x: np.ndarray) -> float:
        """The pressing force's work and the stop spring of a force-controlled tool."""
        if self.vdof is None:
            return 0.0
        u = x[self.vdof, 2]
        E = self.force * self.force_scale * u
        if self.stop is not None and u < self.stop:
            E += 0.5 * self.k_stop * (self.stop - u) ** 2
        return E

    def _stop_force(self, x: np.ndarray) -> tuple[float, float]:
        """Derivative and stiffness of the stop spring in the tool's z. A tool resting exactly
        on its stop (where the step's predictor puts a holder that came down on it) is on
        the spring: the force pressing it can only push it in, and without the stiffness
        Newton's first correction sent it F / k_floor into the stop, which backtracking then
        cut down a thousandfold."""
        u = x[self.vdof, 2]
        if self.stop is None or u > self.stop:
            return 0.0, 0.0
        return -self.k_stop * (self.stop - u), self.k_stop

    def step_bound(self, x: np.ndarray, dx: np.ndarray) -> float:
        """A tool above its stop that the correction takes past it stops on it: the Hessian
        above the stop has no stop stiffness, so the correction takes the tool as far as the
        pressing force over the stiffness of its contact (or k_floor) goes, far into the
        stop, and backtracking from there took steps of 1/2 to 1/2048 of it until one
        crossed the stop (the 2 mm cup's holder landing on its stop: 6 iterations). A
        millionth past the stop, so the next iterate is on its spring (``_stop_force``)."""
        if self.vdof is None or self.stop is None:
            return 1.0
        u, du = x[self.vdof, 2], dx[self.vdof, 2]
        if u <= self.stop or u + du >= self.stop:
            return 1.0
        return min(1.0, (u - self.stop) / -du * (1.0 + 1e-6))

    def energy(self, x: np.ndarray) -> float:
        t = self.translation(x)
        near = self.reach.near(x, self.R_now, t)
        E = penalty_energy(x[self.nodes[near]], self.prog, self.R_now, t, self.k, self.delta,
                           c2=True)
        if self.mu > 0 and self.lagged is not None and self.lagged[0].any():
            act, X0, disp, lam, nrm, _ = self.lagged
            Xa = x[self.nodes[act]]
            if self.vdof is not None:
                Xa = Xa - (x[self.vdof] - self._start_u)
            E += friction(Xa, X0, disp, lam, nrm, self.mu, self.eps_v)[0]
        return E + self._tool_energy(x)

    def _add_gradient(self, x: np.ndarray, g: np.ndarray, *parts: Forces) -> None:
        for idx, gi, _ in parts:
            g[self.nodes[idx]] += gi  # a node once per part: no repeated index
            if self.vdof is not None:
                g[self.vdof] -= gi.sum(0)
        if self.vdof is not None:
            g[self.vdof, 2] += self.force * self.force_scale + self._stop_force(x)[0]

    def _add_hessian(self, x: np.ndarray, data: np.ndarray, *parts: Forces) -> None:
        block = np.zeros((3, 3))
        for idx, _, Hi in parts:
            scatter_node_blocks(data, self.pattern.node_slots, self.nodes[idx], Hi)
            if self.vdof is not None:
                block += Hi.sum(0)
                _scatter_pairs(data, self.pair_slots[idx], -Hi)
        if self.vdof is not None:
            block[2, 2] += self._stop_force(x)[1] + max(self.k_floor - block[2, 2], 0.0)
            scatter_node_blocks(data, self.pattern.node_slots, np.array([self.vdof]),
                                block[None])

    def add_gradient(self, x: np.ndarray, g: np.ndarray) -> None:
        _, pen, fri = self._eval(x)
        self._add_gradient(x, g, pen, fri)

    def add_hessian(self, x: np.ndarray, data: np.ndarray) -> None:
        _, pen, fri = self._eval(x)
        self._add_hessian(x, data, pen, fri)

    def add_gradient_hessian(self, x: np.ndarray, g: np.ndarray, data: np.ndarray) -> float:
        E, pen, fri = self._eval(x)
        self._add_gradient(x, g, pen, fri)
        self._add_hessian(x, data, pen, fri)
        return E

    def node_forces(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The penalty's and friction's gradients (m, 3) at each of ``nodes`` (the force on
        a node is minus its row; zero off the tool)."""
        _, pen, fri = self._eval(x)
        out = np.zeros((2, len(self.nodes), 3))
        out[0, pen[0]], out[1, fri[0]] = pen[1], fri[1]
        return out[0], out[1]

    def gap(self, x: np.ndarray) -> np.ndarray:
        """Signed distance (m) of each candidate node to the tool surface, negative inside."""
        return sdf_world_distance(self.prog, self.R_now, self.translation(x), x[self.nodes])

    def report(self, x: np.ndarray) -> dict[str, float]:
        """Force the sheet exerts on the tool (N), nodes in contact, deepest penetration (m),
        the tool's position (x, y, z, m) and rotation vector (rx, ry, rz, rad)."""
        gp, gf = self.node_forces(x)
        gap = self.gap(x)
        f = (gp + gf).sum(0)
        t = self.translation(x)
        return {"fx": float(f[0]), "fy": float(f[1]), "fz": float(f[2]),
                "contact_nodes": int((gap < self.delta).sum()),
                "penetration": float(max(0.0, -gap.min())) if len(gap) else 0.0,
                "x": float(t[0]), "y": float(t[1]), "z": float(t[2]),
                "rx": float(self.rot_now[0]), "ry": float(self.rot_now[1]),
                "rz": float(self.rot_now[2])}


def _scatter_pairs(data: np.ndarray, slots: np.ndarray, blocks: np.ndarray) -> None:
    """data[slots] += blocks for the (node, tool) blocks; every slot is above the diagonal."""
    np.add.at(data, slots.reshape(-1), blocks.reshape(-1))

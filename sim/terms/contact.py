"""Contact of the sheet's skins with one rigid tool: penalty normal force plus lagged smoothed
Coulomb friction (sim.contact), as one energy term. A scene builds one such term per tool and
none without tools.

The contact layer starts ``delta`` (1 % of the thickness) outside the tool surface, so a skin
placed exactly on a tool is already held by it (no free rigid mode at the first step).
The tool moves rigidly (translation); its position is integrated from its velocity, so a speed
changed between steps takes effect from the next step on.
"""

from __future__ import annotations

import numpy as np

from sim.assembly import scatter_node_blocks
from sim.contact import friction, normal_forces, penalty_contact
from sim.terms import Term

EYE = np.eye(3)


class ToolContact(Term):
    """nodes: candidate sheet nodes (both skins) ``(m,)``; prog: SDF program; position (3,)
    at t = 0; velocity (3,) per unit time; k penalty stiffness (N/m); mu Coulomb coefficient."""

    def __init__(self, name, prog, nodes, position, velocity, k, mu, eps_v, pattern,
                 delta=0.0):
        self.name = f"contact:{name}"
        self.tool = name
        self.prog = np.ascontiguousarray(prog, float)
        self.nodes = np.asarray(nodes, np.int64)
        self.position = np.asarray(position, float).copy()  # committed
        self.velocity = np.asarray(velocity, float)
        self.speed_scale = 1.0
        self.k, self.mu, self.eps_v = float(k), float(mu), float(eps_v)
        self.delta = float(delta)
        self.pattern = pattern
        self.t_now = self.position.copy()
        self._lagged = None
        self._settled = False  # normal forces of a converged state are known
        # Newton's protocol (as Elasticity): nonzero = PSD-project each node block; the exact
        # block is indefinite next to convex tool edges (e' H with e' < 0)
        self.project = 1

    def begin_step(self, t, dt, x):
        self.t_now = self.position + self.speed_scale * dt * self.velocity
        # friction lags the normal force of the last converged state; the rest state is not an
        # equilibrium (a skin placed on a tool sits in the contact layer), so the first step
        # is frictionless
        self._lagged = None
        if self.mu > 0 and self._settled:
            X0 = x[self.nodes]
            lam, nrm = normal_forces(X0, self.prog, EYE, self.position, self.k, self.delta)
            act = lam > 0
            disp = np.broadcast_to(self.t_now - self.position, (int(act.sum()), 3))
            self._lagged = (act, X0[act], np.ascontiguousarray(disp), lam[act], nrm[act])

    def commit(self, x):
        self.position = self.t_now.copy()
        self._settled = True

    def _eval(self, x):
        X = x[self.nodes]
        E, g, H, _, _ = penalty_contact(X, self.prog, EYE, self.t_now, self.k, self.delta,
                                        project_psd=bool(self.project))
        if self.mu > 0 and self._lagged is not None and self._lagged[0].any():
            act, X0, disp, lam, nrm = self._lagged
            Ef, gf, Hf = friction(X[act], X0, disp, lam, nrm, self.mu, self.eps_v)
            E += Ef
            g[act] += gf
            H[act] += Hf
        return E, g, H

    def energy(self, x):
        X = x[self.nodes]
        E = penalty_contact(X, self.prog, EYE, self.t_now, self.k, self.delta)[0]
        if self.mu > 0 and self._lagged is not None and self._lagged[0].any():
            act, X0, disp, lam, nrm = self._lagged
            E += friction(X[act], X0, disp, lam, nrm, self.mu, self.eps_v)[0]
        return E

    def add_gradient(self, x, g):
        _, gn, _ = self._eval(x)
        np.add.at(g, self.nodes, gn)

    def add_hessian(self, x, data):
        _, _, H = self._eval(x)
        scatter_node_blocks(data, self.pattern.node_slots, self.nodes, H)

    def add_gradient_hessian(self, x, g, data):
        _, gn, H = self._eval(x)
        np.add.at(g, self.nodes, gn)
        scatter_node_blocks(data, self.pattern.node_slots, self.nodes, H)

    def report(self, x) -> dict[str, float]:
        """Force the sheet exerts on the tool (N), nodes in contact, deepest penetration (m)."""
        _, gn, _ = self._eval(x)
        gap = penalty_contact(x[self.nodes], self.prog, EYE, self.t_now, self.k,
                              self.delta)[4]
        f = gn.sum(0)
        return {"fx": float(f[0]), "fy": float(f[1]), "fz": float(f[2]),
                "contact_nodes": int((gap < self.delta).sum()),
                "penetration": float(max(0.0, -gap.min())) if len(gap) else 0.0}

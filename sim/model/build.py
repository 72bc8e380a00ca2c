"""Discretisation: a validated Scene becomes a Model (shell, energy terms, Dirichlet data).

Only what the scene asks for is built: no inertia for statics, no load term without loads, no
plastic state for an elastic material, no contact without tools. ``Model.built`` (``describe``)
reports what was built, read off the model itself: energy terms, state arrays with their shapes,
the linear solver, and the outputs of a run (probes, sections, frame fields, tools shown).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sim.elements import get_element
from sim.geometry.shell import Shell, extrude
from sim.model import terms as parts
from sim.model.curves import motion_factor
from sim.model.dirichlet import arc_positions, column_nodes, dirichlet, region_mask
from sim.model.sheet import mesh_and_thickness, rule_of
from sim.scene.load import Scene
from sim.solve.assembly import Pattern, build_pattern
from sim.solve.linsolve import make_solver
from sim.solve.newton import NewtonSettings
from sim.solve.problem import Problem
from sim.terms import Term
from sim.terms.elasticity import Elasticity
from sim.terms.inertia import Inertia
from sim.terms.loads import ExternalForce
from sim.terms.tool_contact import ToolContact


@dataclass
class Model:
    scene: Scene
    shell: Shell
    pattern: Pattern
    problem: Problem
    terms: list[Term]
    elasticity: Elasticity
    external: ExternalForce | None
    inertia: Inertia | None
    x0: np.ndarray  # (n_nodes + n_tool_dofs, 3): rest positions, then force-controlled tools
    fixed: np.ndarray  # (n_nodes + n_tool_dofs, 3) bool
    prescribed: np.ndarray  # (n_nodes, 3) displacement at the end of the ramp on fixed DoFs
    bends: list  # (node ids, BendSpec) moved along arcs
    regions: dict[str, np.ndarray]  # name -> in-plane node mask
    settings: NewtonSettings
    quadrature: dict  # the rule and why it was chosen (sim.model.sheet.quadrature_rule)
    mesh_report: dict  # sim.model.sheet.mesh_and_thickness
    released: np.ndarray | None  # (n_nodes, 3) bool: DoFs freed for springback
    release_support: np.ndarray | None  # (n_nodes, 3) bool: held only for springback
    # keyframed BCs: (node ids (m,), component ids (c,), times (k,), displacements (k, c)),
    # times starting at 0 with zero displacement
    motions: list
    built: dict = field(init=False)  # describe(self)

    def __post_init__(self) -> None:
        self.built = describe(self)

    @property
    def driven(self) -> bool:
        """A prescribed motion drives the run (displacements, bends, keyframes): its
        reactions are its forces. Read from the arrays each time, so a caller that sets
        ``prescribed`` after the build is seen."""
        return bool(self.motions or self.bends or np.any(self.prescribed != 0.0))

    def dirichlet_positions(self, t: float) -> np.ndarray:
        """Positions ``(n_nodes + n_tool_dofs, 3)`` with every prescribed DoF at scene time t."""
        f = motion_factor(self.scene.stepping, t)
        x = self.x0 + f * self.prescribed
        for nodes, bend in self.bends:
            x[nodes] = arc_positions(self.shell.rest[nodes], bend.angle * f, bend.length)
        for nodes, comps, times, values in self.motions:
            for j, c in enumerate(comps):
                x[nodes, c] = self.x0[nodes, c] + np.interp(t, times, values[:, j])
        return x

    def column_nodes(self, plane_mask: np.ndarray, layers: str = "all") -> np.ndarray:
        return column_nodes(self.shell, plane_mask, layers)


def build_model(scene: Scene) -> Model:
    elem = get_element(scene.shell.element)
    mesh, h, mesh_report = mesh_and_thickness(scene)
    shell = extrude(mesh, h, elem)
    rule_spec, why = rule_of(scene, elem, mesh)
    rule = elem.quadrature(rule_spec)
    n_tool_dofs = sum(t.force is not None for t in scene.tools)
    n_total = shell.n_nodes + n_tool_dofs
    x0 = np.vstack([shell.rest, np.zeros((n_tool_dofs, 3))])
    candidates = parts.contact_nodes(shell)
    pattern = build_pattern(shell.conn, n_total,
                            parts.tool_pairs(shell, candidates, n_tool_dofs))
    elastic = parts.elasticity(scene, shell, rule, pattern)
    regions = {r.name: region_mask(shell, r) for r in scene.regions}
    external = parts.external_force(scene, shell, rule, elastic, regions, x0)
    inertia = parts.inertia(scene, shell, rule, elastic, pattern, x0, n_tool_dofs)
    tools = parts.tools(scene, shell, pattern, candidates)
    parts.check_start(scene, shell, tools, x0)
    parts.check_paths(scene, shell, tools)
    stored = parts.stored_energy(scene, elastic, x0)
    terms = [t for t in (stored, external, inertia) if t is not None] + tools
    bcs = dirichlet(scene, shell, regions, tools, n_total)
    problem = Problem(terms, pattern, make_solver(pattern, scene.solver.linear_solver),
                      bcs.fixed)
    return Model(scene, shell, pattern, problem, terms, elastic, external, inertia, x0,
                 bcs.fixed, bcs.prescribed, bcs.bends, regions, newton_settings(scene, shell),
                 {"rule": list(rule_spec), "why": why}, mesh_report, bcs.released,
                 bcs.release_support, bcs.motions)


def newton_settings(scene: Scene, shell: Shell) -> NewtonSettings:
    """The scene's solver settings, ``xtol`` relative to the mean thickness. The residual's
    round-off floor is measured by Newton where it matters (sim.solve.problem.Floor)."""
    h = float(np.mean(shell.thickness))
    proj = scene.solver.hessian_projection
    return NewtonSettings(rtol=scene.solver.rtol, xtol=scene.solver.xtol * h,
                          try_exact=proj in ("auto", "exact_near"),
                          exact_below=0.1 if proj == "exact_near" else 0.0,
                          max_iterations=scene.solver.max_iterations)


def frame_fields(model: Model) -> list[str]:
    """Per-vertex fields of every frame (``Simulation.frame``): plastic strain, and the major
    and minor strain of the forming limits, only where there is a plastic state; the FLD zone
    only with a forming limit curve (sim.frames.forming_limits)."""
    plastic = model.elasticity.plastic
    return ["thickness_mm", "thinning_pct", "von_mises_MPa",
            *(["eq_plastic_strain_pct", "major_strain_pct", "minor_strain_pct"] if plastic
              else []),
            *(["fld_zone"] if model.scene.material.flc is not None else [])]


def describe(model: Model) -> dict:
    """What ``model`` holds: ``mesh`` (what was read or generated, and for a file what was
    merged: :func:`mesh_and_thickness`), ``terms`` (names), ``plastic_state``, ``state`` (array
    name -> shape: what a step carries over besides the positions), ``linear_solver``,
    ``quadrature`` (the rule and why: :func:`quadrature_rule`), ``outputs``."""
    el, inertia = model.elasticity, model.inertia
    tools = [t for t in model.terms if isinstance(t, ToolContact)]
    state: dict[str, list[int]] = {"positions": list(model.x0.shape)}
    if el.plastic:
        state |= {"plastic.fp_inv": list(el.fp_inv.shape), "plastic.ep": list(el.ep.shape)}
    if inertia is not None:
        state |= {"inertia.x_n": list(inertia.x_n.shape), "inertia.v": list(inertia.v.shape)}
    for t in tools:  # committed tool position; contact is tested on these skin nodes
        state |= {f"{t.name}.position": [3], f"{t.name}.candidates": [len(t.nodes)]}
    sc = model.scene
    return {"mesh": model.mesh_report, "terms": [t.name for t in model.terms],
            "plastic_state": el.plastic,
            "state": state, "linear_solver": model.problem.solver.name,
            "quadrature": model.quadrature,
            "outputs": {"probes": [p.name for p in sc.probes],
                        "sections": [s.name for s in sc.sections],
                        "frame_fields": frame_fields(model),
                        "tools": [t.tool for t in tools]}}



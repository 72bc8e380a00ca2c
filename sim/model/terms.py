"""The energy terms a scene needs, and only those: elasticity (plastic state only for a
plastic material), the external loads, inertia in dynamic stepping, one contact term per tool."""

from __future__ import annotations

import numpy as np

from sim.geometry.quadrature import Rule
from sim.geometry.shell import Shell
from sim.materials.hill import HILL48, hill_matrix, hill_params, sheet_frames
from sim.materials.plasticity import LAWS
from sim.scene.load import Scene, SceneError
from sim.scene.sheet import MaterialSpec
from sim.solve.assembly import Pattern, pair_slots
from sim.terms import PROJECT_ELEMENT, PROJECT_NONE, PROJECT_QP, Term, loads
from sim.terms.contact_kernels import auto_stiffness
from sim.terms.elasticity import Elasticity
from sim.terms.inertia import Inertia, lumped_mass
from sim.terms.small_strain import SmallStrain
from sim.terms.tool_contact import ToolContact
from sim.tools.evaluate import sdf_world_distance
from sim.tools.shapes import tool_program
from sim.tools.surface import tool_mesh

# linear_elastic is the elastic term linearised at rest, where every law is Hooke's
MODEL_IDS = {"neo_hookean": 0, "hencky": 1, "plastic": 2, "linear_elastic": 0}
PROJECTIONS = {"auto": PROJECT_QP, "exact_near": PROJECT_QP, "qp": PROJECT_QP,
               "element": PROJECT_ELEMENT, "none": PROJECT_NONE}



def lame(E: float, nu: float) -> tuple[float, float]:
    return E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))


def material_params(m: MaterialSpec) -> np.ndarray:
    """[mu, lam, law, hp...] as the numba kernels expect (sim.materials.isotropic)."""
    mu, lam = lame(m.E, m.nu)
    if m.model != "plastic":
        return np.array([mu, lam, 0.0, 0.0])
    law, hp = LAWS[m.hardening.law], m.hardening_params()
    if m.hill48 is not None:
        h = m.hill48
        return hill_params(mu, lam, law, hp, hill_matrix(*h.coefficients(), L=h.L, M=h.M))
    return np.array([mu, lam, float(law), *hp])


def material_frames(m: MaterialSpec, shell: Shell) -> np.ndarray | None:
    """Per element, the material axes (rolling, transverse, normal) ``(n_elem, 3, 3)`` of an
    anisotropic sheet, from its rest mid-surface; None for an isotropic one."""
    if m.hill48 is None:
        return None
    V, F = shell.mesh.vertices, shell.mesh.faces
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    n /= np.linalg.norm(n, axis=1)[:, None]
    try:
        return sheet_frames(n, np.array(m.hill48.rolling_vector(), float))
    except ValueError as exc:
        raise ValueError(f"material.hill48.rolling_direction: {exc}") from None


def elasticity(scene: Scene, shell: Shell, rule: Rule, pattern: Pattern) -> Elasticity:
    m = scene.material
    # the small-strain stiffness is the exact Hessian at rest (positive definite there)
    project = PROJECT_NONE if m.model == "linear_elastic" else \
        PROJECTIONS[scene.solver.hessian_projection]
    model = HILL48 if m.hill48 is not None else MODEL_IDS[m.model]
    return Elasticity(shell, rule, model, material_params(m), pattern, project,
                      plastic=m.model == "plastic", frames=material_frames(m, shell))


def stored_energy(scene: Scene, elastic: Elasticity, x0: np.ndarray) -> Term:
    """The elastic term, or for a linear_elastic material its small-strain version."""
    if scene.material.model == "linear_elastic":
        return SmallStrain(elastic, x0)
    return elastic


def inertia(scene: Scene, shell: Shell, rule: Rule, elastic: Elasticity, pattern: Pattern,
            x0: np.ndarray, n_tool_dofs: int) -> Inertia | None:
    """Dynamic stepping's inertia (lumped mass; the force-controlled tools' rows massless)."""
    if scene.stepping.kind != "dynamic":
        return None
    mass = np.concatenate([lumped_mass(shell, rule, elastic.wdetJ, scene.material.density),
                           np.zeros(n_tool_dofs)])
    return Inertia(mass, pattern, x0)


def contact_nodes(shell: Shell) -> np.ndarray:
    """Both skins, every in-plane node (so the edge nodes of quadratic elements too)."""
    return np.concatenate([shell.layer_nodes(0), shell.layer_nodes(shell.element.q)])


def tool_pairs(shell: Shell, candidates: np.ndarray, n_tool_dofs: int) -> np.ndarray | None:
    """The (node, tool row) pairs of the force-controlled tools, for the sparsity pattern."""
    if not n_tool_dofs:
        return None
    return np.concatenate([np.column_stack([candidates, np.full_like(candidates, row)])
                           for row in range(shell.n_nodes, shell.n_nodes + n_tool_dofs)])


def tools(scene: Scene, shell: Shell, pattern: Pattern, nodes: np.ndarray) -> list[ToolContact]:
    """One contact term per tool over the candidate skin nodes; force-controlled tools get the
    next extra row of x for their z offset."""
    if not scene.tools:
        return []
    vdof = shell.n_nodes
    h = float(np.mean(shell.thickness))
    # the largest tributary area of a skin node: its share of a unit pressure on the skin
    unit = loads.pressure(shell, np.ones(len(shell.conn), bool), 1.0, False)
    area = float(np.linalg.norm(unit, axis=1).max())
    out = []
    for i, t in enumerate(scene.tools):
        try:
            prog = tool_program(t.shape)
        except ValueError as exc:
            raise ValueError(f"tools.{i}.shape: tool {t.name!r}: {exc}") from None
        # auto_stiffness: at its design pressure (4e-3 E, about the tensile strength) the
        # spring is compressed by 1 % of t; the C2 law's layer delta is twice that, so the
        # tool surface is reached at the design pressure (sim.terms.contact_kernels.auto_stiffness)
        k = t.stiffness or auto_stiffness(scene.material.E, h, area)
        # slip below 1 % of the thickness counts as sticking (IPC's eps_v)
        kw = {}
        if t.force is not None:
            pairs = np.column_stack([nodes, np.full_like(nodes, vdof)])
            kw = {"vdof": vdof, "force": t.force, "pair_slots": pair_slots(pattern, pairs),
                  "stop": t.stop}
            vdof += 1
        out.append(ToolContact(t.name, prog, nodes, t.position, t.velocity, k, t.friction,
                               1e-2 * h, pattern, delta=2e-2 * h, keyframes=t.keyframes, **kw))
    return out



# a blank that starts deeper inside a tool than this share of its thickness is a scene's error
# (a thickness or a tool's position mistyped: a 5 m sheet swallowed the cup's tools and its run
# "converged" with no force), not contact to resolve; the shipped scenes start clear or
# touching, and a tessellated tool's facets sag by micrometres
START_OVERLAP = 0.1
FIBRE_POINTS = 9  # along each fibre, skin to skin: a tool inside the sheet is found too


def check_start(scene: Scene, shell: Shell, tools: list[ToolContact], x0: np.ndarray) -> None:
    """SceneError naming the first tool the blank starts inside, deeper than START_OVERLAP of
    its thickness: where, how deep, and what to check."""
    bottom, top = shell.rest[shell.skin_nodes(False)], shell.rest[shell.skin_nodes(True)]
    f = np.linspace(0.0, 1.0, FIBRE_POINTS)[:, None, None]
    points = (bottom + f * (top - bottom)).reshape(-1, 3)
    for i, term in enumerate(tools):
        d = sdf_world_distance(term.prog, term.R_now, term.translation(x0), points)
        depth = -d.reshape(FIBRE_POINTS, -1).min(axis=0)
        share = depth / shell.thickness
        v = int(np.argmax(share))
        if share[v] > START_OVERLAP:
            x, y, _ = shell.mesh.vertices[v]
            raise SceneError(
                f"tools.{i}: tool {scene.tools[i].name!r}: the blank starts inside it, "
                f"{1e3 * depth[v]:.3g} mm deep at (x, y) = ({1e3 * x:.3g} mm, {1e3 * y:.3g} mm), "
                f"{share[v]:.0%} of the sheet's thickness there ({1e3 * shell.thickness[v]:.3g} "
                "mm): place the tool "
                "clear of the sheet (its shape's position) or check shell.thickness")


# the tools' paths are checked at this many points of the run at most (every step up to it):
# two tools that run into each other do so over many steps, closer at each
PATH_SAMPLES = 200
# two tools that come closer than this share of the blank's thickness leave it no room: a
# sheet ironed to a tenth of its thickness has torn long before
PINCH = 0.1


def check_paths(scene: Scene, shell: Shell, tools: list[ToolContact]) -> None:
    """SceneError naming two tools whose prescribed paths bring them closer than PINCH of the
    blank's thickness at a step of the run: a punch wider than the die's opening, a stroke into
    the die's floor. The solver found it out only after steps of a stalled line search that
    named no tool. Force-controlled tools (a blank holder) are placed by the solve, not by a
    path, and two tools that keep their places relative to each other are one rigid tool."""
    st = scene.stepping
    end = st.steps * (st.dt if st.kind == "dynamic" else 1.0 / st.steps)
    led = [i for i, t in enumerate(tools) if t.vdof is None]
    pairs = [(a, b) for a in led for b in led if a != b and (tools[a].moves or tools[b].moves)]
    if not pairs:
        return
    size = 4.0 * float(np.ptp(shell.mesh.vertices, axis=0).max())  # a plane's square
    surface = {i: tool_mesh(tools[i].prog, plane_size=size)[0] for i in led}
    # a lower bound of each surface point's distance to the other tool: its last distance less
    # twice the tools' travel since (a distance field changes by at most the travel; the
    # factor covers smoothed and sampled fields), so a point is evaluated again only where
    # it may have come close, and most of a tool's surface never is
    bound = {pair: np.full(len(surface[pair[0]]), -np.inf) for pair in pairs}
    h = float(np.min(shell.thickness))
    before = 0.0
    for k in np.unique(np.linspace(0, st.steps, min(st.steps, PATH_SAMPLES) + 1).round()):
        now = end * k / st.steps
        pose = {i: tools[i].planned(now) for i in led}
        for a, b in pairs:
            points = surface[a] @ pose[a][0].T + pose[a][1]
            bound[a, b] -= 2.0 * (tools[a].travel(before, now, points)
                                  + tools[b].travel(before, now, points))
            near = bound[a, b] < PINCH * h
            d = sdf_world_distance(tools[b].prog, *pose[b], points[near])
            bound[a, b][near] = d
            if not len(d) or d.min() >= PINCH * h:
                continue
            ta, tb, v = scene.tools[a], scene.tools[b], int(np.argmin(d))
            x, y, z = 1e3 * points[near][v]
            how = (f"overlap by {-1e3 * d[v]:.3g} mm" if d[v] < 0 else
                   f"come within {1e3 * d[v]:.3g} mm of each other")
            raise SceneError(
                f"tools.{a}: tool {ta.name!r} runs into tool {tb.name!r} (tools.{b}) at "
                f"step {int(k)} of {st.steps}: they {how} at (x, y, z) = ({x:.3g}, {y:.3g}, "
                f"{z:.3g}) mm, where the blank needs its {1e3 * h:.3g} mm between them. "
                "Check the tools' shapes, positions and velocities: a punch passes the "
                "die's opening with the sheet around it")
        before = now


def external_force(scene: Scene, shell: Shell, rule: Rule, elastic: Elasticity,
                   regions: dict[str, np.ndarray], x0: np.ndarray) -> loads.ExternalForce | None:
    if not scene.loads:
        return None
    f = np.zeros((len(x0), 3))
    n = shell.n_nodes
    for i, ld in enumerate(scene.loads):
        try:
            if ld.kind == "gravity":
                f[:n] += loads.body_force(shell, elastic.wdetJ, rule,
                                          scene.material.density * np.array(ld.vector))
            elif ld.kind == "traction":
                f[:n] += loads.traction(shell, regions[ld.region], np.array(ld.vector))
            elif ld.kind == "pressure":
                f[:n] += loads.pressure(shell, _elements(shell, regions, ld.region), ld.value,
                                        ld.skin == "top")
            elif ld.kind == "surface":
                f[:n] += loads.surface_force(shell, _elements(shell, regions, ld.region),
                                             np.array(ld.vector))
            else:
                v = int(np.argmin(np.linalg.norm(shell.mesh.vertices - ld.point, axis=1)))
                f[:n] += loads.point_force(shell, v, np.array(ld.vector))
        except ValueError as exc:
            raise ValueError(f"loads.{i}: {exc}") from None
    return loads.ExternalForce(f, x0)


def _elements(shell: Shell, regions: dict[str, np.ndarray], region: str | None) -> np.ndarray:
    """The elements ``(n_elem,)`` bool whose corners all lie in ``region`` (None: all)."""
    if region is None:
        return np.ones(len(shell.conn), bool)
    return regions[region][: shell.n_vertices][shell.mesh.faces].all(1)

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
from sim.geometry import trimesh as meshes
from sim.geometry.shell import Shell, extrude
from sim.materials.plasticity import LINEAR, PERFECT, SWIFT, VOCE
from sim.scene.boundary import RegionSpec
from sim.scene.fields import MAX_LENGTH
from sim.scene.load import Scene
from sim.scene.sheet import MaterialSpec, MeshSpec
from sim.solve.assembly import Pattern, build_pattern
from sim.solve.linsolve import make_solver
from sim.solve.newton import NewtonSettings
from sim.solve.problem import Problem
from sim.terms import Term
from sim.terms import loads as L
from sim.terms.elasticity import (
    PROJECT_ELEMENT,
    PROJECT_NONE,
    PROJECT_QP,
    Elasticity,
)
from sim.terms.inertia import Inertia, lumped_mass
from sim.terms.tool_contact import ToolContact
from sim.tools.shapes import tool_program

MODEL_IDS = {"neo_hookean": 0, "hencky": 1, "plastic": 2}
LAWS = {"perfect": PERFECT, "linear": LINEAR, "swift": SWIFT, "voce": VOCE}
PROJECTIONS = {"auto": PROJECT_QP, "qp": PROJECT_QP, "element": PROJECT_ELEMENT,
               "none": PROJECT_NONE}


def build_mesh(spec: MeshSpec) -> meshes.TriMesh:
    if spec.kind == "rectangle":
        return meshes.rectangle(spec.size, spec.edge_length, spec.origin)
    if spec.kind in ("annulus", "disk"):
        r0 = 0.0 if spec.kind == "disk" else spec.r_inner
        return meshes.annulus(r0, spec.r_outer, spec.edge_length)
    if spec.kind == "cylinder_band":
        return meshes.cylinder_band(spec.radius, spec.height, spec.edge_length)
    return meshes.load(spec.path, spec.scale, spec.merge_vertices)


def imperfect(mesh: meshes.TriMesh, amplitude: float) -> meshes.TriMesh:
    """``MeshSpec.imperfection``: one smooth out-of-plane bump over a flat mesh's extent."""
    if amplitude == 0.0:
        return mesh
    V = mesh.vertices
    if np.ptp(V[:, 2]) > 1e-12 * np.ptp(V, axis=0).max():
        raise ValueError("mesh.imperfection: needs a flat mesh (z = const)")
    lo, span = V.min(0), np.ptp(V, axis=0)
    s, t = (V[:, 0] - lo[0]) / span[0], (V[:, 1] - lo[1]) / span[1]
    out = V.copy()
    out[:, 2] += amplitude * np.sin(np.pi * s) * np.sin(np.pi * t)
    return meshes.TriMesh(out, mesh.faces)


def _read_values(path: str) -> np.ndarray:
    """A .npy array or a text file of numbers (whitespace or comma separated)."""
    from pathlib import Path

    p = Path(path)
    if not p.is_file():
        raise ValueError(f"no file {path!r}")
    try:
        if p.suffix == ".npy":
            return np.asarray(np.load(p, allow_pickle=False), float).ravel()
        return np.loadtxt(p, delimiter="," if p.suffix == ".csv" else None, ndmin=1).ravel()
    except ValueError as exc:
        raise ValueError(f"{p.name} is not an array of numbers ({exc})") from None


def mesh_and_thickness(scene: Scene) -> tuple[meshes.TriMesh, np.ndarray, dict]:
    """The mid-surface, the thickness at each of its vertices ``(n_v,)`` (m) and a report of the
    mesh (a file's: what was read, merged and dropped, sim.geometry.trimesh.load_with_values);
    errors name the field they come from."""
    sh, spec = scene.shell, scene.mesh
    field_name = "shell.thickness_file" if sh.thickness_file else "shell.thickness_attribute"
    try:
        values = _read_values(sh.thickness_file) if sh.thickness_file else None
        if spec.kind == "file":
            mesh, h, report = meshes.load_with_values(spec.path, spec.scale, values,
                                                      sh.thickness_attribute,
                                                      spec.merge_vertices)
        else:
            mesh, h = build_mesh(spec), values
            report = {"vertices": len(mesh.vertices), "triangles": len(mesh.faces)}
            if h is not None and len(h) != len(mesh.vertices):
                raise ValueError(f"{len(h)} values for the {len(mesh.vertices)} vertices of "
                                 f"the {spec.kind} mesh")
    except meshes.MeshFileError as exc:
        raise ValueError(f"mesh.path: {exc}") from None
    except ValueError as exc:
        raise ValueError(f"{field_name}: {exc}") from None
    mesh = imperfect(mesh, spec.imperfection)
    if h is None:
        h = sh.thickness + mesh.vertices @ np.asarray(sh.thickness_gradient)
        field_name = "shell.thickness_gradient"
    bad = ~np.isfinite(h) | (h <= 0) | (h > MAX_LENGTH)
    if bad.any():
        v = int(np.flatnonzero(bad)[0])
        raise ValueError(f"{field_name}: thickness must be positive (and at most "
                         f"{MAX_LENGTH:.0e} m) at every vertex ({int(bad.sum())} are not; "
                         f"vertex {v}: {h[v]:.3g} m)")
    return mesh, np.asarray(h, float), {"kind": spec.kind, **report}


def lame(E: float, nu: float) -> tuple[float, float]:
    return E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))


def material_params(m: MaterialSpec) -> np.ndarray:
    """[mu, lam, law, hp...] as the numba kernels expect (sim.materials.isotropic)."""
    mu, lam = lame(m.E, m.nu)
    if m.model != "plastic":
        return np.array([mu, lam, 0.0, 0.0])
    return np.array([mu, lam, float(LAWS[m.hardening.law]), *m.hardening_params()])


def region_mask(shell: Shell, r: RegionSpec) -> np.ndarray:
    """Selected in-plane nodes ``(n_plane,)`` by their rest mid-surface position."""
    X = shell.plane_mid
    scale = np.ptp(shell.mesh.vertices, axis=0).max()
    tol = 1e-9 * scale
    if r.box is not None:
        mask = np.all((X >= np.array(r.box.min) - tol) & (X <= np.array(r.box.max) + tol), 1)
    elif r.ring is not None:
        rho = np.hypot(X[:, 0], X[:, 1])
        mask = (rho >= r.ring.r_min - tol) & (rho <= r.ring.r_max + tol)
    else:
        n = np.asarray(r.plane.normal, float)
        n = n / np.linalg.norm(n)
        mask = np.abs((X - np.asarray(r.plane.point)) @ n) <= r.plane.tolerance
    if r.boundary:
        bnd = np.zeros(shell.n_plane, bool)
        bnd[np.unique(meshes.boundary_edges(shell.mesh.faces))] = True
        if shell.element.p > 1:  # edge nodes between two boundary vertices
            mask_v = bnd[: shell.n_vertices]
            for_e = _edge_node_owner(shell)
            bnd[shell.n_vertices: shell.n_vertices + len(for_e)] = mask_v[for_e].all(1)
        mask &= bnd
    if not mask.any():
        raise ValueError(f"regions.{r.name}: selects no node")
    return mask


def _edge_node_owner(shell: Shell) -> np.ndarray:
    uniq, _ = meshes.edges(shell.mesh.faces)
    return np.repeat(uniq, shell.element.p - 1, axis=0)


def arc_positions(X: np.ndarray, phi: float, a: float) -> np.ndarray:
    """End section at x = a of a strip bent about y into an arc of curvature phi / a (its
    symmetry plane x = 0 fixed): a point at height Z sits at radius 1/k - Z from the centre
    (0, ., 1/k). Series for small phi so the straight state is exact. X shape (n, 3)."""
    if abs(phi) < 1e-8:
        sinc, cosc = 1.0 - phi**2 / 6, phi / 2 - phi**3 / 24
    else:
        sinc, cosc = np.sin(phi) / phi, (1 - np.cos(phi)) / phi
    Z = X[:, 2]
    out = X.copy()
    out[:, 0] = a * sinc - Z * np.sin(phi)
    out[:, 2] = a * cosc + Z * np.cos(phi)
    return out


LAYERS = {"all": None, "bottom": 0, "top": -1, "mid": "mid"}


@dataclass
class Model:
    scene: Scene
    shell: Shell
    pattern: Pattern
    problem: Problem
    terms: list[Term]
    elasticity: Elasticity
    external: L.ExternalForce | None
    inertia: Inertia | None
    x0: np.ndarray  # (n_nodes + n_tool_dofs, 3): rest positions, then force-controlled tools
    fixed: np.ndarray  # (n_nodes + n_tool_dofs, 3) bool
    prescribed: np.ndarray  # (n_nodes, 3) displacement at the end of the ramp on fixed DoFs
    bends: list  # (node ids, BendSpec) moved along arcs
    regions: dict[str, np.ndarray]  # name -> in-plane node mask
    settings: NewtonSettings
    built: dict = field(default_factory=dict)
    quadrature: dict = field(default_factory=dict)  # the rule and why it was chosen
    mesh_report: dict = field(default_factory=dict)  # sim.model.build.mesh_and_thickness

    released: np.ndarray | None = None  # (n_nodes, 3) bool: DoFs freed for springback
    release_support: np.ndarray | None = None  # (n_nodes, 3) bool: held only for springback

    # keyframed BCs: (node ids (m,), component ids (c,), times (k,), displacements (k, c)),
    # times starting at 0 with zero displacement
    motions: list = field(default_factory=list)

    @property
    def driven(self) -> bool:
        """A prescribed motion drives the run (displacements, bends, keyframes): its
        reactions are its forces. Read from the arrays each time, so a caller that sets
        ``prescribed`` after the build is seen."""
        return bool(self.motions or self.bends or np.any(self.prescribed != 0.0))

    def ramp(self, t: float) -> float:
        """Default time curve of prescribed displacements and bends (sim.scene.boundary.BCSpec):
        linear
        from 0 to 1 over the run (static) or over stepping.load_ramp, else 1 s (dynamic)."""
        st = self.scene.stepping
        length = 1.0 if st.kind == "static" or st.load_ramp == 0 else st.load_ramp
        return min(1.0, t / length)

    def dirichlet_positions(self, t: float) -> np.ndarray:
        """Positions ``(n_nodes + n_tool_dofs, 3)`` with every prescribed DoF at scene time t."""
        f = self.ramp(t)
        x = self.x0 + f * self.prescribed
        for nodes, bend in self.bends:
            x[nodes] = arc_positions(self.shell.rest[nodes], bend.angle * f, bend.length)
        for nodes, comps, times, values in self.motions:
            for j, c in enumerate(comps):
                x[nodes, c] = self.x0[nodes, c] + np.interp(t, times, values[:, j])
        return x

    def column_nodes(self, plane_mask: np.ndarray, layers: str = "all") -> np.ndarray:
        q, n = self.shell.element.q, self.shell.n_plane
        idx = np.flatnonzero(plane_mask)
        if layers == "all":
            ks = range(q + 1)
        elif layers == "bottom":
            ks = [0]
        elif layers == "top":
            ks = [q]
        else:
            if q % 2:
                raise ValueError("layers = 'mid' needs an element with a mid-surface layer")
            ks = [q // 2]
        return np.concatenate([k * n + idx for k in ks])


def quadrature_rule(scene: Scene, elem, mesh) -> tuple[tuple[int, int], str]:
    """The scene's rule, else the element's default, unless the default has spurious
    zero-energy modes on this mesh: on edge-connected patches of one or two triangles (a lone
    element, a pair, or a patch hanging by a vertex) the paper's one-point in-plane rules
    leave some, and the mode-free rule (stiffer: it locks in transverse shear) is taken for
    the whole sheet. Every other mesh keeps the paper's rule, which has none there."""
    if scene.shell.quadrature:
        return tuple(scene.shell.quadrature), "scene"
    if elem.small_mesh_quadrature is not None:
        small = meshes.small_patches(mesh.faces)
        if len(small):
            return elem.small_mesh_quadrature, (
                f"{len(small)} triangle(s) in edge-connected patches of 1-2 triangles (first: "
                f"{small[:5].tolist()}), where the default {list(elem.default_quadrature)} "
                "admits spurious zero-energy modes")
    return elem.default_quadrature, "default"


def build_model(scene: Scene) -> Model:
    elem = get_element(scene.shell.element)
    mesh, h, mesh_report = mesh_and_thickness(scene)
    shell = extrude(mesh, h, elem)
    rule_spec, why = quadrature_rule(scene, elem, mesh)
    if scene.shell.thickness_points:
        rule_spec = (rule_spec[0], scene.shell.thickness_points)
    rule = elem.quadrature(rule_spec)
    forced = [i for i, t in enumerate(scene.tools) if t.force is not None]
    n_total = shell.n_nodes + len(forced)
    x0 = np.vstack([shell.rest, np.zeros((len(forced), 3))])
    candidates = _contact_nodes(shell)
    pairs = np.concatenate([np.column_stack([candidates, np.full_like(candidates, shell.n_nodes
                                                                       + j)])
                            for j in range(len(forced))]) if forced else None
    pattern = build_pattern(shell.conn, n_total, pairs)
    m = scene.material
    plastic = m.model == "plastic"
    elastic = Elasticity(shell, rule, MODEL_IDS[m.model], material_params(m), pattern,
                         PROJECTIONS[scene.solver.hessian_projection], plastic=plastic)
    terms: list[Term] = [elastic]
    regions = {r.name: region_mask(shell, r) for r in scene.regions}
    ext = _external_force(scene, shell, rule, elastic, regions, x0)
    dynamic = scene.stepping.kind == "dynamic"
    if ext is not None:
        ramp = scene.stepping.load_ramp
        if dynamic:
            ext.scale = (lambda t: min(1.0, t / ramp)) if ramp > 0 else (lambda t: 1.0)
        terms.append(ext)
    inertia = None
    if dynamic:
        mass = np.concatenate([lumped_mass(shell, rule, elastic.wdetJ, m.density),
                               np.zeros(len(forced))])
        inertia = Inertia(mass, pattern, x0)
        terms.append(inertia)
    tools = _tools(scene, shell, pattern, candidates)
    terms += tools
    fixed = np.zeros((n_total, 3), bool)
    fixed[shell.n_nodes:, :2] = True  # force-controlled tools move in z only
    prescribed = np.zeros((n_total, 3))
    model = Model(scene, shell, pattern, None, terms, elastic, ext, inertia, x0, fixed,
                  prescribed, [],
                  regions, NewtonSettings())
    release_support = np.zeros((n_total, 3), bool)
    for i, bc in enumerate(scene.bcs):
        try:
            nodes = model.column_nodes(regions[bc.region], bc.layers)
        except ValueError as exc:
            raise ValueError(f"bcs.{i}.layers: {exc}") from None
        comps = ["xyz".index(c) for c in bc.components]
        if bc.release_only:
            release_support[np.ix_(nodes, comps)] = True
            continue
        if bc.bend is not None:
            # 'x' alone: the end section is turned like a rotated wall but free to move
            # across the strip, so it carries a pure moment (no shear force)
            if "x" not in bc.components:
                raise ValueError(f"bcs.{i}.bend: a bent end prescribes x (its rotation): "
                                 "components must include 'x'")
            model.bends.append((nodes, bc.bend))
        if bc.keyframes:
            kf = np.asarray(bc.keyframes, float)
            if kf[0, 0] > 0:  # from rest at t = 0
                kf = np.vstack([np.zeros(kf.shape[1]), kf])
            model.motions.append((nodes, comps, kf[:, 0], kf[:, 1:]))
        for k in comps:
            fixed[nodes, k] = True
            prescribed[nodes, k] = bc.displacement[k]
    if scene.stepping.release:
        released = np.zeros_like(fixed)
        for bc in scene.bcs:
            if bc.release:
                nodes = model.column_nodes(regions[bc.region], bc.layers)
                released[np.ix_(nodes, ["xyz".index(c) for c in bc.components])] = True
        for t in tools:  # a retracted force-controlled tool's offset is held
            if t.vdof is not None and t.tool in {s.name for s in scene.tools if s.release}:
                release_support[t.vdof] = True
        model.released = released
        model.release_support = release_support
    # the residual's round-off floor is measured by Newton where it matters (sim.solve.problem.Floor)
    h = float(np.mean(shell.thickness))
    model.settings = NewtonSettings(rtol=scene.solver.rtol, xtol=scene.solver.xtol * h,
                                    try_exact=scene.solver.hessian_projection == "auto",
                                    max_iterations=scene.solver.max_iterations)
    solver = make_solver(pattern, scene.solver.linear_solver)
    model.problem = Problem(terms, pattern, solver, fixed)
    model.quadrature = {"rule": list(rule_spec), "why": why}
    model.mesh_report = mesh_report
    model.built = describe(model)
    return model


def frame_fields(model: Model) -> list[str]:
    """Per-vertex fields of every frame (``Simulation.frame``): plastic strain only where there
    is a plastic state."""
    return ["thickness_mm", "thinning_pct", "von_mises_MPa",
            *(["eq_plastic_strain"] if model.elasticity.plastic else [])]


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


def _contact_nodes(shell) -> np.ndarray:
    """Both skins, every in-plane node (so the edge nodes of quadratic elements too)."""
    return np.concatenate([shell.layer_nodes(0), shell.layer_nodes(shell.element.q)])


def _tools(scene, shell, pattern, nodes) -> list[ToolContact]:
    """One contact term per tool over the candidate skin nodes; force-controlled tools get the
    next extra row of x for their z offset."""
    if not scene.tools:
        return []
    from sim.solve.assembly import pair_slots
    from sim.terms.contact_kernels import auto_stiffness

    vdof = shell.n_nodes
    h = float(np.mean(shell.thickness))
    # the largest tributary area of a skin node: its share of a unit pressure on the skin
    area = float(np.linalg.norm(L.pressure(shell, np.ones(len(shell.conn), bool), 1.0, False),
                                axis=1).max())
    out = []
    for i, t in enumerate(scene.tools):
        try:
            prog = tool_program(t.shape)
        except ValueError as exc:
            raise ValueError(f"tools.{i}.shape: {exc}") from None
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


def _external_force(scene, shell, rule, elastic, regions, x0) -> L.ExternalForce | None:
    if not scene.loads:
        return None
    f = np.zeros((len(x0), 3))
    n = shell.n_nodes
    for i, ld in enumerate(scene.loads):
        try:
            if ld.kind == "gravity":
                f[:n] += L.body_force(shell, elastic.wdetJ, rule,
                                  scene.material.density * np.array(ld.vector))
            elif ld.kind == "traction":
                f[:n] += L.traction(shell, regions[ld.region], np.array(ld.vector))
            elif ld.kind == "pressure":
                sel = np.ones(len(shell.conn), bool)
                if ld.region:
                    v_mask = regions[ld.region][: shell.n_vertices]
                    sel = v_mask[shell.mesh.faces].all(1)
                f[:n] += L.pressure(shell, sel, ld.value, ld.skin == "top")
            else:
                v = int(np.argmin(np.linalg.norm(shell.mesh.vertices - ld.point, axis=1)))
                f[:n] += L.point_force(shell, v, np.array(ld.vector))
        except ValueError as exc:
            raise ValueError(f"loads.{i}: {exc}") from None
    return L.ExternalForce(f, x0)

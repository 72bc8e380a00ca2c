"""Closed-form references for ``q3t study`` (``[study] analytic = ...``), each with the checks
that the scene meets the formula's assumptions; a scene that does not is rejected with the
field and the reason, never compared against a formula that does not hold for it.

- ``euler_bernoulli``: tip deflection of a cantilever under its own weight,
  w = q L^4 / (8 E I) with q = rho g b h and I = b h^3 / 12, i.e. w = 3 rho g L^4 / (2 E h^2).
  Beam theory has no Poisson effect across the width: it holds at nu = 0. Shear deformation
  adds about (h / L)^2; geometric nonlinearity about (w / L)^2 (said in the notes).
- ``springback``: residual curvature of an elastic-perfectly-plastic strip bent to radius R
  and released, k_after = k (4 X^3 - 3 X + 1), X = sigma_y R / (E t), in plane strain
  (E -> E / (1 - nu^2), sigma_y -> 2 sigma_y / sqrt(3)); valid for 0 < X < 1 (the strip
  yielded).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, NoReturn, Protocol

if TYPE_CHECKING:
    from sim.scene.boundary import BCSpec, LoadSpec, RegionSpec
    from sim.scene.run import ProbeSpec, SteppingSpec
    from sim.scene.shapes import ToolSpec
    from sim.scene.sheet import MaterialSpec, MeshSpec, ShellSpec


class Tables(Protocol):
    """The tables of a scene the formulas check: sim.scene.load.Scene, which checks its study
    against them (``reference``) and so cannot be imported here."""

    material: MaterialSpec
    mesh: MeshSpec
    shell: ShellSpec
    regions: list[RegionSpec]
    bcs: list[BCSpec]
    loads: list[LoadSpec]
    stepping: SteppingSpec
    tools: list[ToolSpec]
    probes: list[ProbeSpec]


def _fail(name: str, why: str) -> NoReturn:
    raise ValueError(f"study.analytic: {name} needs {why}")


def _probe(scene: Tables, name: str) -> ProbeSpec:
    return next(p for p in scene.probes if p.name == name)


def euler_bernoulli(scene: Tables, probe: str) -> dict:
    n = "euler_bernoulli"
    m, mesh, sh = scene.material, scene.mesh, scene.shell
    if m.model == "plastic":
        _fail(n, "an elastic material (material.model is 'plastic')")
    if m.nu != 0:
        _fail(n, f"material.nu = 0 (beam theory has no Poisson effect; the scene has {m.nu})")
    if mesh.kind != "rectangle":
        _fail(n, f"a rectangle mesh (mesh.kind is {mesh.kind!r})")
    if any(sh.thickness_gradient) or scene.tools or scene.stepping.kind != "static":
        _fail(n, "a uniform static plate without tools (shell.thickness_gradient, tools, "
                 "stepping.kind)")
    if (len(scene.loads) != 1 or scene.loads[0].kind != "gravity"
            or any(scene.loads[0].vector[:2]) or not scene.loads[0].vector[2]):
        _fail(n, "one load: gravity along z (loads)")
    x0, L = mesh.origin[0], mesh.size[0]
    regions = {r.name: r for r in scene.regions}
    clamps = [bc for bc in scene.bcs if bc.components == "xyz" and bc.layers == "all"
              and not any(bc.displacement) and bc.bend is None
              and (pl := regions[bc.region].plane) is not None
              and tuple(pl.normal) == (1.0, 0.0, 0.0) and pl.point[0] == x0]
    if len(scene.bcs) != 1 or not clamps:
        _fail(n, f"one BC clamping (components 'xyz') the plane x = {x0} (bcs)")
    p = _probe(scene, probe)
    if p.kind != "displacement" or p.component != "z" or abs(p.point[0] - (x0 + L)) > 1e-9 * L:
        _fail(n, f"a z displacement probe at the tip x = {x0 + L} (study.probe {probe!r})")
    g = scene.loads[0].vector[2]
    w = 1.5 * m.density * g * L**4 / (m.E * sh.thickness**2)
    return {"name": n, "value": w,
            "about": f"Euler-Bernoulli tip deflection 3 rho g L^4 / (2 E h^2) = {w:.6g} m; "
                     f"linear theory: w/L = {abs(w) / L:.2g} (nonlinearity ~(w/L)^2 = "
                     f"{(w / L) ** 2:.1g}), shear ~(h/L)^2 = {(sh.thickness / L) ** 2:.1g}"}


def springback(scene: Tables, probe: str) -> dict:
    n = "springback"
    m = scene.material
    if m.model != "plastic" or m.hardening.law != "perfect":
        _fail(n, "an elastic-perfectly-plastic material (material.model 'plastic', "
                 "hardening.law 'perfect')")
    bends = [bc.bend for bc in scene.bcs if bc.bend is not None]
    if len(bends) != 1 or not scene.stepping.release or scene.tools or scene.loads:
        _fail(n, "one bent end (bcs.*.bend), stepping.release = true, no tools or loads")
    if not any("y" in bc.components and bc.layers == "all" for bc in scene.bcs):
        _fail(n, "plane strain: a BC holding y (bcs)")
    if _probe(scene, probe).kind != "curvature":
        _fail(n, f"a curvature probe (study.probe {probe!r})")
    b = bends[0]
    k = b.angle / b.length
    Ep, Yp = m.E / (1 - m.nu**2), 2 * m.yield_stress / math.sqrt(3)
    X = Yp / (abs(k) * Ep * scene.shell.thickness) if k else math.inf
    if not 0 < X < 1:
        _fail(n, f"a strip that yields: X = sigma_y R / (E t) = {X:.3g} must lie in (0, 1)")
    value = k * (4 * X**3 - 3 * X + 1)
    return {"name": n, "value": value,
            "about": f"residual curvature k (4 X^3 - 3 X + 1) = {value:.6g} 1/m after bending "
                     f"to k = {k:.6g} 1/m, X = {X:.4g} (plane strain, perfect plasticity)"}


FORMULAS = {"euler_bernoulli": euler_bernoulli, "springback": springback}


def reference(scene: Tables, name: str, probe: str) -> dict:
    """``{"name", "value", "about"}`` of formula ``name`` for ``probe`` of ``scene``; raises
    ValueError naming the field when the scene does not meet the formula's assumptions."""
    if name not in FORMULAS:
        raise ValueError(f"study.analytic: unknown {name!r}; known: {sorted(FORMULAS)}")
    return FORMULAS[name](scene, probe)

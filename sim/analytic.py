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
- ``fibre``: residual curvature of the scene's bent strip from a fibre model of its section
  (:func:`fibre_section`): any hardening law, in plane strain when a BC holds the width (y),
  else in plane stress.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, NoReturn, Protocol

import numpy as np

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


def _bent_strip(scene: Tables, probe: str, n: str) -> tuple[float, bool]:
    """The imposed curvature of a strip bent by one end and released, and whether a BC holds
    its width (plane strain); ValueError naming the field when the scene is not such a strip."""
    if scene.material.model != "plastic" or scene.material.hill48 is not None:
        _fail(n, "a von Mises plastic material (material.model 'plastic', no material.hill48)")
    bends = [bc.bend for bc in scene.bcs if bc.bend is not None]
    if len(bends) != 1 or not scene.stepping.release or scene.tools or scene.loads:
        _fail(n, "one bent end (bcs.*.bend), stepping.release = true, no tools or loads")
    if _probe(scene, probe).kind != "curvature":
        _fail(n, f"a curvature probe (study.probe {probe!r})")
    plane_strain = any("y" in bc.components and bc.layers == "all" for bc in scene.bcs)
    return bends[0].angle / bends[0].length, plane_strain


def springback(scene: Tables, probe: str) -> dict:
    n = "springback"
    m = scene.material
    k, plane_strain = _bent_strip(scene, probe, n)
    if m.hardening.law != "perfect":
        _fail(n, "an elastic-perfectly-plastic material (hardening.law 'perfect')")
    if not plane_strain:
        _fail(n, "plane strain: a BC holding y (bcs)")
    Ep, Yp = m.E / (1 - m.nu**2), 2 * m.yield_stress / math.sqrt(3)
    X = Yp / (abs(k) * Ep * scene.shell.thickness) if k else math.inf
    if not 0 < X < 1:
        _fail(n, f"a strip that yields: X = sigma_y R / (E t) = {X:.3g} must lie in (0, 1)")
    value = k * (4 * X**3 - 3 * X + 1)
    return {"name": n, "value": value,
            "about": f"residual curvature k (4 X^3 - 3 X + 1) = {value:.6g} 1/m after bending "
                     f"to k = {k:.6g} 1/m, X = {X:.4g} (plane strain, perfect plasticity)"}


def fibre_section(E: float, nu: float, law: int, hp: Sequence[float], thickness: float,
                  kappa: float, plane_strain: bool, points: int | str = 400,
                  steps: int = 40) -> dict:
    """A section of unit width, of the von Mises plasticity of ``sim.materials.plasticity``
    (``law``, ``hp``), bent to curvature ``kappa`` and released: ``{"moment", "springback",
    "released"}`` (N m / m, 1/m, 1/m); ValueError when the release yields again.

    Each fibre at distance z from the mid-surface takes the log strain kappa z along the strip
    in ``steps`` equal increments (monotone loading: the stress path follows the ratio of its
    components as it moves from elastic to plastic), the width's strain held at zero
    (``plane_strain``) or its stress free (plane stress), the thickness stress free; its
    stress is the material's return map, the free strains solved with its exact tangent. The
    neutral axis stays at mid-thickness (the material is odd in the strain: no axial force).
    Release is elastic: the springback is M over the elastic bending stiffness E' t^3 / 12
    (E' = E / (1 - nu^2) in plane strain, E in plane stress). For a stress profile sigma(z)
    that rises with z no faster than in proportion (a concave hardening curve: every law of
    sim.materials.plasticity), the unloading stress M z / I is at most 1.5 sigma(z), short of
    the 2 sigma(z) that would yield the fibre again; each fibre is still checked at the
    released curvature.

    ``points``: the section's fibres, an integer n for n equal layers (midpoint rule; the
    stress profile's kink at the elastic core makes its error O(1/n^2)), or ``"gauss:n"``
    for the n-point Gauss rule an element integrates the thickness with."""
    from sim.materials.plasticity import plastic_flow, return_map

    c = thickness / 2
    if isinstance(points, str):
        xg, wg = np.polynomial.legendre.leggauss(int(points.split(":")[1]))
        z, w = c * xg, c * wg
    else:
        z = c * ((2 * np.arange(points) + 1) / points - 1)
        w = np.full(points, thickness / points)
    mu, lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
    hp = np.asarray(hp, float)
    free = [2] if plane_strain else [1, 2]
    eps, eps_p, ep = np.zeros((len(z), 3)), np.zeros((len(z), 3)), np.zeros(len(z))
    tol = 1e-12 * hp[0]

    def fibre(i: int, k: float) -> tuple[np.ndarray, float]:
        """The fibre's strain and its stress along the strip at curvature k."""
        e = eps[i].copy()
        e[0] = k * z[i]
        for _ in range(50):
            _, tau, D, _, _ = return_map(e - eps_p[i], ep[i], mu, lam, law, hp)
            if np.abs(tau[free]).max() <= tol:
                return e, tau[0]
            e[free] -= np.linalg.solve(D[np.ix_(free, free)], tau[free])
        raise ArithmeticError(f"fibre at z = {z[i]:.4g} m: its free stresses do not vanish")

    tau_x = np.zeros(len(z))
    for k in np.linspace(0.0, kappa, steps + 1)[1:]:
        for i in range(len(z)):
            eps[i], tau_x[i] = fibre(i, k)
            dep, dg = plastic_flow(eps[i] - eps_p[i], ep[i], mu, law, hp)
            eps_p[i] += dep
            ep[i] += dg
    M = float(np.sum(w * tau_x * z))
    Ep = E / (1 - nu**2) if plane_strain else E
    ks = M / (Ep * thickness**3 / 12)
    for i in range(len(z)):
        e, _ = fibre(i, kappa - ks)
        if plastic_flow(e - eps_p[i], ep[i], mu, law, hp)[1] > 0:
            raise ValueError(f"fibre_section: the release yields again at z = {z[i]:.4g} m; "
                             "the springback is not the elastic M / (E' I)")
    return {"moment": M, "springback": ks, "released": kappa - ks}


def fibre(scene: Tables, probe: str) -> dict:
    from sim.materials.plasticity import LAWS

    n = "fibre"
    m = scene.material
    k, plane_strain = _bent_strip(scene, probe, n)
    fibres = 400  # midpoint layers: the kink at the elastic core leaves an O(1/n^2) error
    r = fibre_section(m.E, m.nu, LAWS[m.hardening.law], m.hardening_params(),
                      scene.shell.thickness, k, plane_strain, points=fibres)
    section = "plane strain" if plane_strain else "plane stress"
    return {"name": n, "value": r["released"],
            "about": f"residual curvature {r['released']:.6g} 1/m after bending to k = "
                     f"{k:.6g} 1/m: springback {r['springback']:.6g} 1/m = M / (E' I), "
                     f"M = {r['moment']:.6g} N m/m from {fibres} fibres ({section}, "
                     f"{m.hardening.law} hardening)"}


FORMULAS = {"euler_bernoulli": euler_bernoulli, "springback": springback, "fibre": fibre}


def reference(scene: Tables, name: str, probe: str) -> dict:
    """``{"name", "value", "about"}`` of formula ``name`` for ``probe`` of ``scene``; raises
    ValueError naming the field when the scene does not meet the formula's assumptions."""
    if name not in FORMULAS:
        raise ValueError(f"study.analytic: unknown {name!r}; known: {sorted(FORMULAS)}")
    return FORMULAS[name](scene, probe)

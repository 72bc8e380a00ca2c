"""q3t_ans against shear and Poisson locking: a thin strip in bending at coarse meshes
(Euler-Bernoulli), the paper's cantilever at nu = 0.49 (the quadratic reference), and plastic
bending without the one-point rule's zigzag of curvature."""

import functools

import numpy as np
import pytest

from sim.scene.load import load_scene
from sim.stepping.simulation import Simulation

# a strip of slenderness L/h = 100 clamped at x = 0 under its own weight, nu = 0 (beam and plate
# strip then agree: no anticlastic coupling). Self-weight tip deflection q L^4 / (8 E I),
# q = rho g b h, I = b h^3 / 12; E makes it 3e-4 of L, where geometric nonlinearity is below 1e-6
# and Timoshenko's shear term adds (h/L)^2 = 1e-4.
L, B, H, E, RHO = 0.2, 0.02, 0.002, 1e11, 1000.0
W_EB = 1.5 * RHO * 9.81 * L**4 / (E * H * H)


def _tip(element: str, overrides: dict) -> float:
    o = {"shell.element": element, "stepping.steps": 1, **overrides}
    sim = Simulation.from_scene(load_scene("scenes/cantilever.toml", o))
    assert sim.run(), sim.failure
    return -sim.records[-1].probes["tip_deflection"]


def strip(element: str, edge: float) -> float:
    return _tip(element, {"material.E": E, "material.nu": 0.0, "material.density": RHO,
                          "mesh.edge_length": edge, "mesh.size": [L, B],
                          "shell.thickness": H, "probes.0.point": [L, B / 2, 0.0]}) / W_EB


@pytest.mark.parametrize("edge", [0.02, 0.01])
def test_thin_strip_bends_without_shear_locking(edge):
    """10 x 1 and 20 x 2 cells, h / cell 0.1-0.2: Q3T locks (measured 0.69, 0.65 of
    Euler-Bernoulli), q3t_ans is within 1 % (measured 1.0001 on both)."""
    assert abs(strip("q3t_ans", edge) - 1) < 0.01
    assert strip("q3t", edge) < 0.8


@functools.cache
def cantilever(element: str) -> float:
    """The paper's beam (scenes/cantilever.toml, 150 x 15 cells) at nu = 0.49, linear range."""
    return _tip(element, {"material.E": 1e11, "material.nu": 0.49, "material.density": RHO})


@pytest.mark.slow  # the quadratic reference: 84k DoFs, about 20 s
def test_cantilever_at_nu_049_stays_free_of_poisson_locking():
    # issue bound 5 %; measured q3t_ans / quadratic 0.985 (Q3T 0.951)
    assert abs(cantilever("q3t_ans") / cantilever("quadratic") - 1) < 0.05


def _local_curvature(element: str) -> np.ndarray:
    """plastic_bending loaded to radius 1 m (no release): the curvature of the circle through
    each three consecutive mid-surface vertices along the strip's edge y = 0."""
    sim = Simulation.from_scene(load_scene("scenes/plastic_bending.toml", {
        "shell.element": element, "stepping.release": False}))
    assert sim.run(), sim.failure
    sh, x = sim.model.shell, sim.x
    n, q = sh.n_plane, sh.element.q
    mid = (x[:n] + x[q * n:(q + 1) * n]) / 2
    V = sh.mesh.vertices
    line = np.flatnonzero(np.isclose(V[:, 1], 0.0))
    P = mid[line[np.argsort(V[line, 0])]][:, [0, 2]]
    a, b, c = P[:-2], P[1:-1], P[2:]
    cross = (b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0]
    sides = (np.linalg.norm(b - a, axis=1) * np.linalg.norm(c - b, axis=1)
             * np.linalg.norm(a - c, axis=1))
    return 2 * cross / sides


def test_plastic_bending_curvature_has_no_zigzag():
    """Issue 17: Q3T's one-point rule leaves a zigzag of the local curvature (measured 0.77 to
    1.25 of the imposed 1 / m from one vertex to the next); q3t_ans is within 2 % everywhere
    (measured 0.996-1.002)."""
    kappa = _local_curvature("q3t_ans")
    assert np.abs(kappa - 1.0).max() < 0.02  # the end rotation imposes radius 1 m
    q3t = _local_curvature("q3t")
    assert q3t.max() - q3t.min() > 0.2  # the zigzag this element removes


def _springback(tp: int | None, hardening: dict) -> tuple[float, float, object]:
    """plastic_bending with q3t_ans at 10 x 1 cells and ``tp`` section points (None: the
    scene's own), bent to radius 1 m and released: (loaded curvature, its springback
    k_load - k_after, the scene)."""
    o = {"shell.element": "q3t_ans", "mesh.edge_length": 0.01, "material.hardening": hardening}
    if tp is not None:
        o["shell.thickness_points"] = tp
    scene = load_scene("scenes/plastic_bending.toml", o)
    sim = Simulation.from_scene(scene)
    for _ in range(scene.stepping.steps):
        sim.step()
    k_load = sim.records[-1].probes["curvature"]
    assert sim.run(), sim.failure  # the release stage
    return k_load, k_load - sim.records[-1].probes["curvature"], scene


@pytest.mark.parametrize("hardening", [{"law": "perfect"}, {"law": "linear", "modulus": 2e9}])
def test_springback_matches_the_fibre_model(hardening):
    """Issue 17: springback within 1 % of a fibre model of the section (sim.analytic.
    fibre_section, 400 fibres, plane strain as the scene's BC makes it), with perfect and
    linear hardening, at the loaded curvature the element reached.

    Measured (q3t_ans, perfect / linear): +0.27 / +0.21 % at 20 section points; the in-plane
    mesh moves it by under 0.1 % (edge 10, 5, 2.5 mm), the section rule by 0.15 % from 20 to
    40 points (+0.10 % there), the fibre model itself by 2e-6 from 400 fibres and 40 increments
    to 800 and 80: the 1 % holds with the result converged. Against the fibre model integrated
    on the element's own Gauss rule the element is within 0.04 % at 9 and 20 points (bound
    0.1 %): the element's own error, apart from the section rule's. At 9 points (the scene's
    until 2026-12-03) the springback is 1.8 / 1.4 % short of the converged fibre model, and so
    is the fibre model on those 9 points: nine Gauss points integrate the nearly rigid-plastic
    stress block, a step at the thin elastic core, that coarsely. The scene's own rule (19
    points, measured -0.37 / -0.30 %) is what is held to the 1 %."""
    from sim.analytic import fibre_section
    from sim.materials.plasticity import LAWS

    for tp in (9, None):
        k_load, springback, scene = _springback(tp, hardening)
        m = scene.material
        section = (m.E, m.nu, LAWS[m.hardening.law], m.hardening_params(),
                   scene.shell.thickness, k_load, True)
        rule = scene.shell.thickness_points
        same_rule = fibre_section(*section, points=f"gauss:{rule}")["springback"]
        assert abs(springback / same_rule - 1) < 1e-3, (rule, springback, same_rule)
        if tp is None:
            converged = fibre_section(*section)["springback"]
            assert abs(springback / converged - 1) < 0.01, (springback, converged)

"""Scenes made small for tests: the shipped ones coarsened (two ways, named for what a test
keeps of the scene), and the tiny scenes the service tests run."""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from sim.model.sheet import build_mesh
from sim.scene.load import Scene, load_scene, scene_from_toml
from tests.support import ROOT

SCENES = sorted((ROOT / "scenes").glob("*.toml"))


def coarse(scene_path: str | Path, element: str | None = None) -> Scene:
    """A run's first steps: the mesh at about 200 triangles, the steps capped at 2, tools at
    the stroke per step of the real path; ``element`` overrides the scene's."""
    sc = load_scene(scene_path)
    if sc.mesh.kind == "rectangle":
        e = max(sc.mesh.size) / 14
    elif sc.mesh.kind in ("annulus", "disk"):
        e = sc.mesh.r_outer / 6
    else:
        e = getattr(sc.mesh, "edge_length", None)
        e = e * 3 if e else None
    o = {"stepping.steps": min(sc.stepping.steps, 2)}
    if hasattr(sc.mesh, "cells"):  # a patch (8 x 8 x 2 triangles) or a strip (8 along)
        o["mesh.cells"] = 8
    # the first two steps of the real path: tools keep their stroke per step
    for i, t in enumerate(sc.tools):
        o[f"tools.{i}.velocity"] = [v * o["stepping.steps"] / sc.stepping.steps
                                    for v in t.velocity]
    if element:
        o["shell.element"] = element
    if e:
        o["mesh.edge_length"] = e
    return load_scene(scene_path, o)


@functools.cache
def shipped_cup() -> tuple:
    """The shipped cup (2 mm mesh, 50 steps) run to its end once per test process, and how
    many factorisations it had taken at the end of each step: several tests check its answers
    and only read it. A failed run is kept too (its ``failure`` says why: each test asserts
    it has none), not run again by every test that asks."""
    from sim.stepping.simulation import Simulation

    sim = Simulation.from_scene(load_scene(ROOT / "scenes" / "cup_drawing.toml"))
    count, counts = factor_counted(sim), []
    sim.run(progress=lambda *_: counts.append(count[0]))
    return sim, counts


def factor_counted(sim) -> list[int]:  # noqa: ANN001
    """A one-item list that counts ``sim``'s factorisations from now on."""
    solver, count = sim.model.problem.solver, [0]

    def factor(data, f=solver.factor):  # noqa: ANN001, ANN202
        count[0] += 1
        return f(data)

    solver.factor = factor
    return count


def coarsest_mesh(sc: Scene) -> dict:
    """Overrides that leave about 20-60 triangles, for a model that is built and not run: what
    it builds and records depends on the scene, not on the mesh. A mesh file stays as it is."""
    m = sc.mesh
    edge = {"rectangle": lambda: max(m.size or (0,)) / 8, "disk": lambda: m.r_outer / 4,
            "annulus": lambda: m.r_outer / 4, "cylinder_band": lambda: m.height / 2,
            "outline": lambda: m.edge_length * 4}
    if hasattr(m, "cells"):
        return {"mesh.cells": 4}
    return {"mesh.edge_length": edge[m.kind]()} if m.kind in edge else {}


def tiny_toml(steps: int = 4) -> str:
    """The cantilever at a coarse mesh and stiff material: a step takes well under a second."""
    text = (ROOT / "scenes/cantilever.toml").read_text()
    text = text.replace("edge_length = 0.0046667", "edge_length = 0.035")
    text = text.replace("steps = 4", f"steps = {steps}")
    return text.replace('name = "cantilever"', 'name = "tiny"')


# A 20 x 20 mm, 0.5 mm plastic plate on a ground plane, pressed 0.2 mm by a punch in 3 steps
PRESS_TOML = """
name = "press"
description = "A small plastic plate on a plane, pressed by a punch (service tests)"

[mesh]
kind = "rectangle"
size = [0.02, 0.02]
origin = [-0.01, -0.01]
edge_length = 0.005

[shell]
thickness = 0.0005
element = "q3t"

[material]
model = "plastic"
E = 70.0e9
nu = 0.33
yield_stress = 100.0e6
hardening = { law = "perfect" }

[[regions]]
name = "centre"
box = { min = [-0.001, -0.001, -1.0], max = [0.001, 0.001, 1.0] }

[[bcs]]
region = "centre"
components = "xy"

[[tools]]
name = "ground"
shape = { kind = "plane", point = [0.0, 0.0, 0.0], normal = [0.0, 0.0, 1.0] }
position = [0.0, 0.0, -0.00025]

[[tools]]
name = "punch"
shape = { kind = "punch", radius = 0.004, height = 0.01, edge_radius = 0.001 }
position = [0.0, 0.0, 0.00025]
velocity = [0.0, 0.0, -0.0002]

[stepping]
steps = 3

[[probes]]
name = "punch_force"
kind = "tool_force"
tool = "punch"
component = "z"

[[probes]]
name = "max_plastic_strain"
kind = "plastic_strain"
stat = "max"
"""


EDITED_EDGE = 0.0175  # half tiny's saved 35 mm edge: about three times the vertices


def vertices(text: str) -> int:
    """How many mid-surface vertices the scene ``text`` meshes into."""
    return len(build_mesh(scene_from_toml(text).mesh).vertices)


def tiny_cup_toml(steps: int = 4) -> str:
    """A 24 mm plastic disk drawn 2 mm into a die ring by a punch, with a forming limit
    curve and a radial section: every plot of the page in about a second of solving."""
    return TINY_CUP_TOML.replace("steps = 4\n", f"steps = {steps}\n", 1)


def ring_cup_toml() -> str:
    """The tiny cup drawn 8 mm through on a 1.5 mm mesh: the coarsest with a steep wall tall
    enough for a split ring (sim.stepping.split_ring). Its wall's rows of elements lie about
    1.6, 3, 5 and 6.2 mm above the bottom (the steep wall's extent, sim.frames.rings.wall, is
    1.62 to 6.16 mm), the top 8.8 mm: RING_BAND, that extent rounded out, is a closed ring
    that opens (0.53 mm); 3-5 mm catches no closed ring, 0-1 mm is the bottom, the command
    line's 8-13 mm reaches above the part. About 4 s of solving."""
    return (tiny_cup_toml(16).replace('name = "tiny_cup"', 'name = "ring_cup"')
            .replace("edge_length = 0.003", "edge_length = 0.0015")
            .replace("velocity = [0.0, 0.0, -0.002]", "velocity = [0.0, 0.0, -0.008]"))


RING_BAND = [1.6, 6.2]  # mm above the ring cup's bottom


TINY_CUP_TOML = """
name = "tiny_cup"
description = "A small cup drawn a few millimetres (page tests)"

[mesh]
kind = "disk"
r_outer = 0.012
edge_length = 0.003

[shell]
thickness = 0.0005
element = "q3t"

[material]
model = "plastic"
E = 70.0e9
nu = 0.33
yield_stress = 100.0e6
hardening = { law = "voce", saturation = 250.0e6, rate = 13.5 }
flc = { kind = "keeler_brazier", n = 0.2 }

[[tools]]
name = "punch"
shape = { kind = "punch", radius = 0.005, height = 0.02, edge_radius = 0.0015 }
position = [0.0, 0.0, 0.00025]
velocity = [0.0, 0.0, -0.002]
friction = 0.1

[[tools]]
name = "die"
position = [0.0, 0.0, -0.00025]
friction = 0.1
[tools.shape]
kind = "die_ring"
inner_radius = 0.0062
outer_radius = 0.02
height = 0.01
edge_radius = 0.0015

[stepping]
steps = 4

[[sections]]
name = "radial"
direction = [1.0, 0.0]
width = 0.0001
steps = [0, 2, 4]

[[probes]]
name = "punch_force"
kind = "tool_force"
tool = "punch"
component = "z"

[[probes]]
name = "min_thickness"
kind = "thickness"
stat = "min"

[[probes]]
name = "centre_dz"
kind = "displacement"
point = [0.0, 0.0, 0.0]
component = "z"
"""


def probe_series(sim) -> dict[str, np.ndarray]:  # noqa: ANN001
    """Each probe of a run (a sim.stepping.simulation.Simulation) over its steps."""
    return {k: np.array([r.probes[k] for r in sim.records]) for k in sim.records[0].probes}

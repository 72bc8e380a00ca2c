"""The summary's deviation from the tool surface after release (sim.frames.summary) is the
change of each contact node's distance from the tool, loaded to released: an elastic plate
held between its tools through the release (no springback) reads 0, though penalty contact
left its skin inside the contact layer; one whose punch is released springs back and reads
the motion away from the tools, exactly for the flat ground and no more than the nodes moved."""

from __future__ import annotations

import tomllib

import numpy as np

from sim.frames import blank
from sim.frames.fields import mid_surface
from sim.scene.load import scene_from_dict
from sim.stepping.simulation import Simulation
from tests.support.scenes import PRESS_TOML


def elastic_press(release_punch: bool) -> Simulation:
    """The press (a 0.5 mm plate on a ground plane, pushed 0.2 mm by a punch), elastic, with
    a release stage; the punch lifted at the release when ``release_punch``."""
    raw = tomllib.loads(PRESS_TOML)
    raw["material"] = {"model": "hencky", "E": 70e9, "nu": 0.33}
    raw["stepping"]["release"] = True
    raw["probes"] = raw["probes"][:1]
    raw["tools"][1]["release"] = release_punch
    sim = Simulation.from_scene(scene_from_dict(raw))
    assert sim.run(), sim.failure
    return sim


def summary(sim: Simulation) -> dict[str, float]:
    return {e["name"]: e["value"] for e in sim.result()["summary"]}


def tool(sim: Simulation, name: str):
    return next(t for t in sim.tools if t.tool == name)


def test_a_part_held_through_the_release_does_not_deviate_from_its_tools():
    sim = elastic_press(release_punch=False)
    s = summary(sim)
    # nothing is released: the state does not change (round-off of the release's solve)
    assert s["springback_max"] < 1e-12
    # skin nodes micrometres from the tools, inside their contact layers: the distance from
    # the tools (the old reading) is not 0, its change is
    gaps = [t.gap(sim.loaded) for t in sim.tools]
    layer = np.concatenate([g[g < t.delta] for g, t in zip(gaps, sim.tools, strict=True)])
    assert np.abs(layer).max() > 1e-6
    assert s["tool_deviation_max"] < 1e-12 and s["tool_deviation_mean"] < 1e-12


def test_a_part_that_springs_back_reads_its_motion_from_the_tools():
    sim = elastic_press(release_punch=True)
    s = summary(sim)
    m = sim.model
    R, c = blank.best_fit(mid_surface(m, sim.x), mid_surface(m, sim.loaded))
    assert s["springback_max"] > 1e-5
    moved = {}
    for t in sim.tools:
        inside = t.gap(sim.loaded) < t.delta
        nodes = t.nodes[inside]
        moved[t.tool] = np.linalg.norm(sim.x[nodes] @ R.T + c - sim.loaded[nodes], axis=1)
    # a distance changes by no more than the point moved (a signed distance is 1-Lipschitz)
    assert s["tool_deviation_max"] <= max(v.max() for v in moved.values()) * (1 + 1e-12)
    # the ground is the plane z = -0.25 mm: a node's distance from it changes by its height's
    # change, the largest of which the summary's largest is at least
    ground = tool(sim, "ground")
    nodes = ground.nodes[ground.gap(sim.loaded) < ground.delta]
    dz = np.abs((sim.x[nodes] @ R.T + c)[:, 2] - sim.loaded[nodes, 2])
    assert dz.max() > 1e-5
    assert s["tool_deviation_max"] >= dz.max() * (1 - 1e-12)

"""The cup (scenes/cup_drawing.toml) with its punch, die and blank holder read from triangle
meshes, tessellated from the analytic tools, against the analytic tools themselves.

The tessellation's chords lie inside each convex rounding by up to the chordal error, but its
vertices lie on the tools: the mesh tool's distance is that to the surface through them (the
facets' sag put back, sim.tools.meshtool.facet_sag), within 0.2 um of the analytic tools' at
their surfaces, so the forces differ by what is left of that and of the spline's smoothing
(docs/mesh-tools.md has the full stroke at two chordal errors)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from sim.scene.load import load_scene
from sim.stamp import ROOT
from sim.stepping.simulation import Simulation
from sim.tools.builders import punch
from sim.tools.shapes import tool_program
from sim.tools.surface import chordal_mesh

CUP = ROOT / "scenes" / "cup_drawing.toml"


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("Q3T_CACHE", str(tmp_path / "cache"))


def mesh_overrides(tmp_path, chord: float, spacing: dict[int, float]) -> dict:
    """The cup's tools as STL files tessellated within ``chord`` (m), read back as mesh
    shapes with ``spacing`` (m) per tool index."""
    scene = load_scene(CUP)
    out = {}
    for i, tool in enumerate(scene.tools):
        path = tmp_path / f"{tool.name}.stl"
        trimesh.Trimesh(*chordal_mesh(tool_program(tool.shape), chord)).export(path)
        out[f"tools.{i}.shape"] = {"kind": "mesh", "path": str(path), "spacing": spacing[i]}
    return out


def run(overrides: dict) -> tuple[np.ndarray, list]:
    return run_scene(load_scene(CUP, overrides), sections=True)


def run_scene(scene, sections: bool = False):
    sim = Simulation.from_scene(scene)
    force = []
    while not sim.done:
        force.append(sim.step().probes["punch_force"])
    if not sections:
        return np.array(force)
    return np.array(force), [np.asarray(s["thickness"]) for s in sim.sections["radial"]]


def test_a_few_steps_of_a_press_with_a_mesh_punch(tmp_path):
    """The service tests' press (a plate pressed 0.2 mm by a punch in 3 steps) with its punch
    read from an STL tessellated within 10 um: the plate's coarse nodes touch only the flat
    nose, which the mesh has exactly, so the force is the analytic tools' to round-off (and to
    within the spline's error near the nose, far below 1e-6 relative)."""
    from sim.scene.load import scene_from_toml
    from tests.support.scenes import PRESS_TOML

    path = tmp_path / "punch.stl"
    trimesh.Trimesh(*chordal_mesh(punch(0.004, 0.01, 0.001), 1e-5)).export(path)
    analytic = scene_from_toml(PRESS_TOML)
    meshed = scene_from_toml(PRESS_TOML, {"tools.1.shape": {"kind": "mesh", "path": str(path),
                                                             "spacing": 2.5e-4}})
    fa, fm = (run_scene(s) for s in (analytic, meshed))
    np.testing.assert_allclose(fm, fa, rtol=1e-6)
    assert fa[-1] > 100.0  # N: it pressed


@pytest.mark.slow
def test_the_first_10_mm_of_the_cup_with_mesh_tools(tmp_path):
    """The stroke's first 10 mm at the scene's own step (20 of its 50 steps, up to the force
    peak), tools tessellated at chordal error 0.01 mm and sampled at 0.5 mm, against the
    shipped cup's first 20 steps (the analytic tools' run the other tests read: the same
    0.5 mm steps, so the same states to Newton's tolerance, 1e-4 of the force level).
    Punch force within 1 % of each step's own analytic force at every step (the issue's bar;
    with q3t_ans, the scene's element since 2026-12-07, 0.64 % at most in these 20 steps; with
    Q3T the full stroke measured 0.80 % at most, at step 50, and 0.32 % in these 20 steps, 1.12 %
    when the facets were sampled instead of the surface through their vertices); the radial
    thickness section within 1 % at every recorded step (q3t_ans 0.004 %; Q3T's full stroke
    0.11 %). The difference is deterministic (micrometres of geometry and the spline's
    smoothing), not round-off."""
    from tests.support.scenes import shipped_cup

    part = {"stepping.steps": 20, "tools.0.velocity": [0.0, 0.0, -0.01],
            "sections.0.steps": [0, 10, 20]}
    mesh = mesh_overrides(tmp_path, 1e-5, {0: 5e-4, 1: 5e-4, 2: 5e-4})
    shipped = shipped_cup()[0]
    assert shipped.failure is None, shipped.failure
    fa = np.array([r.probes["punch_force"] for r in shipped.records[:20]])
    sa = [np.asarray(s["thickness"]) for s in shipped.sections["radial"] if s["step"] <= 20]
    fm, sm = run({**part, **mesh})
    assert len(sa) == len(sm) == 3
    assert np.all(np.abs(fm - fa) <= 0.01 * np.abs(fa)), (fm, fa)
    for a, m in zip(sa, sm, strict=True):
        assert np.all(np.abs(m - a) <= 0.01 * a)


def test_a_coarse_tiny_cup_keeps_its_mesh_punch(tmp_path):
    """The page tests' tiny cup (3 mm edges, no blank holder, 0.5 mm steps) with its punch
    from an STL: at step 1's end every contact node sits 8.7 um from its tool (a 10 um layer),
    and continuing the last increment carried them all out of their layers, the sheet free at
    step 2's start; Newton's first correction was then a rigid motion that round-off decided,
    back onto the tools with the analytic punch, 0.12 m off them with the mesh one (punch
    force 0 from step 2 on). The step now starts from the last state there: the mesh punch's
    forces are the analytic punch's at every step (their fields agree to 0.01 um where the
    sheet touches; 1e-4 is the Newton tolerance on the force level)."""
    from sim.scene.load import scene_from_toml
    from tests.support.scenes import tiny_cup_toml

    text = tiny_cup_toml(4)
    path = tmp_path / "punch.stl"
    shape = tool_program(scene_from_toml(text).tools[0].shape)
    trimesh.Trimesh(*chordal_mesh(shape, 1e-5)).export(path)
    analytic = scene_from_toml(text)
    meshed = scene_from_toml(text, {"tools.0.shape": {"kind": "mesh", "path": str(path),
                                                      "spacing": 2.5e-4}})
    fa, fm = (run_scene(s) for s in (analytic, meshed))
    assert np.all(fa > 150.0), fa  # N: the punch draws the cup at every step
    np.testing.assert_allclose(fm, fa, rtol=1e-4)

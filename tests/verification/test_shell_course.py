"""The shell obstacle course's inputs against closed forms and its scenes against their
published values: a small-strain bar in tension (exact for every element), the quadratic prism
on the Scordelis-Lo roof, the clamped plate and MacNeal and Harder's cantilevers at coarse
meshes, q3t_ans where Q3T locks, and the in-plane bending no three-node triangle gets."""

import numpy as np
import pytest

from sim.elements import ROUTINE
from sim.scene.load import load_scene
from sim.stepping.simulation import Simulation

pytestmark = pytest.mark.fast  # in-process, a few seconds in all

SIGMA = 3.0e8  # 30 % strain at E = 1e9: far from linear for a finite-strain law


def _bar(element: str, model: str) -> float:
    """A 0.7 m bar (nu = 0), clamped at x = 0, pulled at x = 0.7 by the traction SIGMA."""
    sc = load_scene("scenes/cantilever.toml", {
        "mesh.edge_length": 0.035, "shell.element": element, "material.model": model,
        "material.nu": 0.0, "stepping.steps": 1,
        "regions": [{"name": "clamp", "plane": {"point": [0.0, 0, 0], "normal": [1.0, 0, 0]}},
                    {"name": "end", "plane": {"point": [0.7, 0, 0], "normal": [1.0, 0, 0]}}],
        "loads": [{"kind": "traction", "vector": [SIGMA, 0.0, 0.0], "region": "end"}],
        "probes": [{"name": "end_x", "kind": "displacement", "point": [0.7, 0.035, 0.0],
                    "component": "x"}]})
    sim = Simulation.from_scene(sc)
    assert sim.run(), sim.failure
    return sim.records[-1].probes["end_x"]


def _ratio(scene: str, element: str, cells: int) -> float:
    sc = load_scene(f"scenes/{scene}.toml", {"shell.element": element, "mesh.cells": cells})
    sim = Simulation.from_scene(sc)
    assert sim.run(), sim.failure
    return sim.records[-1].probes[sc.study.probe] / sc.study.published.value


@pytest.mark.parametrize("element", ROUTINE)
def test_small_strain_bar_is_exact(element):
    """u = sigma L / E at any load: constant strain, which every element represents exactly;
    Newton stops at rtol 1e-8 of the load, so 1e-7 relative is generous. A finite-strain law
    under the same traction stretches measurably less (Neo-Hookean stiffens in tension)."""
    exact = SIGMA * 0.7 / 1.0e9
    assert np.isclose(_bar(element, "linear_elastic"), exact, rtol=1e-7)
    if element == "linear":
        assert abs(_bar(element, "neo_hookean") / exact - 1) > 0.05


def test_quadratic_prism_on_the_roof_at_a_coarse_mesh():
    """Scordelis-Lo, 8 cells per side: the curved quadratic prism is within 5 % of the
    published deflection, stiffer (its six-node triangles lock somewhat in membrane at this
    size, and converge from below: 0.99 at 16 cells, docs/shells.md); the linear-in-plane
    Q3T locks in transverse shear (a quarter of the deflection)."""
    assert 0.95 < _ratio("scordelis_lo", "quadratic", 8) < 1.0
    assert _ratio("scordelis_lo", "q3t", 8) < 0.25


@pytest.mark.parametrize("scene,cells,measured", [
    ("clamped_plate", 8, 0.968), ("clamped_plate", 16, 0.993),
    ("twisted_beam_inplane", 12, 0.991), ("twisted_beam_outofplane", 12, 0.995),
    ("straight_beam_outofplane", 6, 0.972), ("straight_beam_inplane", 6, 0.969)])
def test_quadratic_prism_meets_the_flat_and_twisted_references(scene, cells, measured):
    """The scenes and their published values checked through the element that needs no
    remedy: the quadratic prism from below, within a point of what it measured at the
    coarsest levels (a regression guard: an error in a scene's load, supports or reference
    moves these by far more), and closer at 16 cells of the plate (thin-plate theory, the
    reference, is exceeded by a plate of a / t = 100 by under 0.3 %)."""
    assert measured - 0.01 < _ratio(scene, "quadratic", cells) < 1.0


def test_q3t_ans_bends_plates_and_twisted_beams_at_coarse_meshes():
    """q3t_ans where Q3T locks in transverse shear: the clamped plate at 8 cells per side of
    the quarter (measured 0.935; Q3T 0.161) and 16 (0.980), the twisted beam under its
    in-plane load at MacNeal and Harder's 12 x 2 cells (0.973; Q3T 0.489). The bounds sit
    1.5 points under the measured values: a regression guard, not the issue's target."""
    assert _ratio("clamped_plate", "q3t_ans", 8) > 0.92
    assert _ratio("clamped_plate", "q3t_ans", 16) > 0.965
    assert _ratio("twisted_beam_inplane", "q3t_ans", 12) > 0.955
    assert _ratio("clamped_plate", "q3t", 8) < 0.2


def test_q3t_ans_on_the_curved_shells_at_coarse_meshes():
    """The curved shells at 16 cells per side: Scordelis-Lo at least 0.95 and the pinched
    hemisphere above 0.95 (issue 17's bound on the roof and its aim for all three; measured
    0.958 and 0.964), and as regression guards, about 2.5 points under the measured values,
    the hemisphere at 8 cells (0.906) and the pinched cylinder at 16 (0.816, short of the aim:
    membrane locking, docs/elements-ans.md). Without the thickness strain tied at the corners
    the hemisphere gave 0.091 and 0.587 (curvature thickness locking: the field's e_ww
    between two corners' directors mixes one's direction with the other's rotation), the
    roof 0.957 and the cylinder 0.801 (their directors turn about one axis only). Linear
    analyses: one solve each, far from round-off."""
    assert _ratio("scordelis_lo", "q3t_ans", 16) >= 0.95
    assert _ratio("pinched_hemisphere", "q3t_ans", 16) > 0.95
    assert _ratio("pinched_hemisphere", "q3t_ans", 8) > 0.88
    assert _ratio("pinched_cylinder", "q3t_ans", 16) > 0.79


@pytest.mark.parametrize("mesher,measured", [("frontal_delaunay", 0.948), ("meshadapt", 0.945)])
def test_q3t_ans_bends_the_plate_on_unstructured_meshes(mesher, measured):
    """The clamped plate's quarter meshed by gmsh (edges of 1 / 16, about 160 triangles of
    no one diagonal direction) instead of the strip's grid: q3t_ans as close as on the grid
    of 8 cells (0.935), no worse for the triangles' directions (a regression guard 1.5
    points under the measured value)."""
    sc = load_scene("scenes/clamped_plate.toml", {
        "shell.element": "q3t_ans", "study": None,
        "mesh": {"kind": "outline", "points": [[0, -0.25], [0.5, -0.25], [0.5, 0.25],
                                               [0, 0.25]],
                 "edge_length": 0.0625, "mesher": mesher}})
    sim = Simulation.from_scene(sc)
    assert sim.run(), sim.failure
    published = load_scene("scenes/clamped_plate.toml").study.published.value
    assert sim.records[-1].probes["centre_deflection"] / published > measured - 0.015


def test_in_plane_bending_is_the_three_node_triangles_limit():
    """The straight cantilever under in-plane shear bends across its width, in the sheet's
    plane, where a three-node triangle's membrane strain is constant: linear, Q3T and q3t_ans
    share that membrane, so at MacNeal and Harder's 6 x 1 cells they give the same 3 % of the
    deflection (measured 0.033 each, within 0.3 % of one another; 1 % allowed, far below the
    factor 29 to the quadratic prism's 0.969, tested above). The assumed strains do not
    reach it (docs/shells.md)."""
    r = {el: _ratio("straight_beam_inplane", el, 6) for el in ("linear", "q3t", "q3t_ans")}
    assert all(0.02 < v < 0.05 for v in r.values()), r
    assert max(r.values()) / min(r.values()) < 1.01, r

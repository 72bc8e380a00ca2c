"""A ring region that misses the blank is refused when the scene is read (sim.scene.footprint),
naming the region's ring, and never one that the build would accept: checked against the
build's own selection (sim.model.dirichlet.region_mask) on rings across the blanks' edges."""

import numpy as np
import pytest
from pydantic import TypeAdapter

from sim.elements import get_element
from sim.geometry.shell import extrude
from sim.model.dirichlet import region_mask
from sim.model.sheet import build_mesh
from sim.scene.boundary import RegionSpec
from sim.scene.footprint import ring_problem
from sim.scene.load import SceneError, load_scene
from sim.scene.sheet import MeshSpec
from tests.support import ROOT

CUP = ROOT / "scenes/cup_drawing_outline.toml"
H = 0.004
MESHES = {
    "circle": {"kind": "outline", "edge_length": H, "circle": {"radius": 0.03}},
    "square with a hole": {
        "kind": "outline", "edge_length": H,
        "points": [[-0.02, -0.02], [0.03, -0.02], [0.03, 0.03], [-0.02, 0.03]],
        "holes": [[[-0.005, -0.005], [0.005, -0.005], [0.005, 0.005], [-0.005, 0.005]]]},
    "disk": {"kind": "disk", "edge_length": H, "r_outer": 0.03},
    "annulus": {"kind": "annulus", "edge_length": H, "r_inner": 0.01, "r_outer": 0.03},
    "rectangle": {"kind": "rectangle", "edge_length": H, "size": [0.04, 0.02],
                  "origin": [0.005, -0.01]},
}


@pytest.mark.parametrize("radius, words", [
    (0.025, "regions.1.ring: selects no node: no boundary node of the blank lies 0.0295-0.031 m"),
    (0.0294, "they lie within 0.02938-0.0294 m of it"),
])
def test_the_rim_ring_off_the_edited_blank_is_named(radius, words):
    """cup_drawing_outline's rim ring, 29.5-31 mm, once its blank's radius leaves it."""
    with pytest.raises(SceneError, match=words):
        load_scene(CUP, {"mesh.circle.radius": radius})
    load_scene(CUP, {"mesh.circle.radius": 0.0296})  # still on the ring


def rings() -> list[tuple[float, float]]:
    """Narrow rings across every radius the blanks above reach, at their edges and between
    their nodes."""
    lo = np.linspace(0.0, 0.0365, 99)
    return [(a, a + w) for a in lo for w in (1e-4, 2e-3)]


@pytest.mark.parametrize("name", sorted(MESHES))
@pytest.mark.parametrize("element", ["linear", "quadratic"])
def test_a_refused_ring_selects_nothing_in_the_build(name, element):
    """Sound: every ring refused selects no node of the built mesh (vertices and edge nodes,
    all nodes or the boundary's). And useful: the rings that lie clear of the blank are
    refused."""
    mesh_spec = TypeAdapter(MeshSpec).validate_python(MESHES[name])
    shell = extrude(build_mesh(mesh_spec), 0.001, get_element(element))
    radius = np.hypot(shell.plane_mid[:, 0], shell.plane_mid[:, 1])
    refused = 0
    for boundary in (False, True):
        for r_min, r_max in rings():
            region = RegionSpec(name="r", ring={"r_min": r_min, "r_max": r_max},
                                boundary=boundary)
            if ring_problem(mesh_spec, region) is None:
                continue
            refused += 1
            with pytest.raises(ValueError, match="selects no node"):
                region_mask(shell, region)
    assert refused >= sum(r_min > radius.max() for r_min, _ in rings())


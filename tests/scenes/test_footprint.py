"""A ring region that misses the blank is refused when the scene is read (sim.scene.footprint),
naming the region's ring, and never one that the build would accept: checked against the
build's own selection (sim.model.dirichlet.region_mask) and the built mesh's own radii, for
all nodes and the boundary's apart, on rings across the blanks' edges."""

import functools
import math
import os

import numpy as np
import pytest
import shapely
from pydantic import TypeAdapter

from sim.elements import get_element
from sim.geometry import trimesh as meshes
from sim.geometry.shell import Shell, extrude
from sim.model.dirichlet import region_mask
from sim.model.sheet import build_mesh, imperfect
from sim.scene.boundary import REGION_TOLERANCE, RegionSpec
from sim.scene.footprint import ring_problem
from sim.scene.load import SceneError, load_scene
from sim.scene.sheet import MeshSpec
from tests.support import ROOT

CUP = ROOT / "scenes/cup_drawing_outline.toml"
H = 0.004
MESHES = {
    "circle": {"kind": "outline", "edge_length": H, "circle": {"radius": 0.03}},
    "circle with a band": {
        "kind": "outline", "edge_length": H, "circle": {"radius": 0.03},
        "refine": [{"ring": {"r_min": 0.02, "r_max": 0.025}, "edge_length": 0.002}]},
    "off-centre 15-gon": {  # its chords cut well inside the circle
        "kind": "outline", "edge_length": H,
        "circle": {"radius": 0.025, "center": [0.006, -0.004], "segments": 15}},
    "square with a hole": {
        "kind": "outline", "edge_length": H,
        "points": [[-0.02, -0.02], [0.03, -0.02], [0.03, 0.03], [-0.02, 0.03]],
        "holes": [[[-0.005, -0.005], [0.005, -0.005], [0.005, 0.005], [-0.005, 0.005]]]},
    # a drawing (read when the scene is, as the build reads it): an off-centre circle with a
    # square hole around the axis
    "drawing": {"kind": "outline", "edge_length": H, "scale": 1e-3,
                "path": str(ROOT / "tests/data/drawings/holed_blank.svg")},
    # a mesh file (read once per version of it): a dished annulus off the axis, in mm
    "file": {"kind": "file", "scale": 1e-3,
             "path": str(ROOT / "tests/data/blanks/dished_annulus.obj")},
    "disk": {"kind": "disk", "edge_length": H, "r_outer": 0.03},
    # a bump as tall as the build takes (half the disk's width: a taller one is refused), its
    # nodes out of the plane by up to 25 mm
    "imperfect disk": {"kind": "disk", "edge_length": H, "r_outer": 0.03, "imperfection": -0.025},
    "annulus": {"kind": "annulus", "edge_length": H, "r_inner": 0.01, "r_outer": 0.03},
    "rectangle": {"kind": "rectangle", "edge_length": H, "size": [0.04, 0.02],
                  "origin": [0.005, -0.01]},
    "flat strip": {"kind": "strip", "length": 0.04, "width": 0.02, "cells": 10},
    # a tube's triangles stand on the plane: seen from above, each is a chord of the circle
    "tube": {"kind": "cylinder_band", "edge_length": H, "radius": 0.02, "height": 0.01},
    # taller than it is wide: its height, not its radius, sets region_mask's tolerance
    "tall tube": {"kind": "cylinder_band", "edge_length": 0.02, "radius": 0.01,
                  "height": 0.5},
    # curved patches: the quadratic and quartic elements' edge nodes on the exact surface, or
    # (faceted) on the triangles
    "roof": {"kind": "cylinder_patch", "radius": 0.025, "length": 0.03, "angle": 0.698,
             "cells": 5},
    "faceted octant of a tube": {"kind": "cylinder_patch", "radius": 0.02, "length": 0.015,
                                 "angle": math.pi / 2, "cells": 4, "curved": False},
    "hemisphere with a hole": {"kind": "sphere_patch", "radius": 0.02, "hole": 0.314,
                               "cells": 5},
    # three steps around half a turn: the hole's rim chords cut well inside its circle
    "half of it": {"kind": "sphere_patch", "radius": 0.02, "hole": 0.6, "azimuth": math.pi,
                   "cells": 3},
}
ELEMENTS = ["linear", "quadratic", "quartic"]
# a ring this far off the built mesh's radii is refused: far above the tolerances (about
# 1e-10 m here) and the round-off of the radii, far below the rings' spacing
CLEAR = 1e-6


@pytest.mark.parametrize("radius, words", [
    (0.018, "regions.0.ring: region 'flange' selects no node: no node of the blank lies "
            "24 mm or more from the z axis"),
    (0.0239, "they lie 0 to 23.9 mm from it"),
])
def test_a_ring_off_the_edited_blank_is_named(radius, words):
    """cup_drawing_outline's flange (24 mm out to the edge) once its blank is smaller than
    that; a blank larger than the shipped one keeps its flange and rim (they reach its edge)."""
    with pytest.raises(SceneError, match=words):
        load_scene(CUP, {"mesh.circle.radius": radius})
    for fits in (0.0241, 0.035):
        load_scene(CUP, {"mesh.circle.radius": fits})


@pytest.mark.parametrize("name, ring, boundary, where", [
    ("disk", (0.031, 0.032), False, "0 to 30 mm"),
    # between the rims: a boundary ring of an annulus lies on one of them
    ("annulus", (0.015, 0.02), True, "9.808 to 10 mm or 29.93 to 30 mm"),
])
def test_the_message_says_where_the_nodes_lie(name, ring, boundary, where):
    spec = TypeAdapter(MeshSpec).validate_python(MESHES[name])
    region = RegionSpec(name="rim", ring={"r_min": ring[0], "r_max": ring[1]},
                        boundary=boundary)
    said = ring_problem(spec, [RegionSpec(name="all", box={"min": [-1] * 3, "max": [1] * 3}),
                               region])
    assert said.startswith("regions.1.ring: region 'rim' selects no "), said
    assert said.endswith(f"(they lie {where} from it)"), said
    with pytest.raises(ValueError, match="selects no node"):
        region_mask(built(name, "quadratic"), region)


@functools.cache
def built(name: str, element: str) -> Shell:
    spec = TypeAdapter(MeshSpec).validate_python(MESHES[name])
    return extrude(imperfect(build_mesh(spec), spec.imperfection), 0.001, get_element(element))


def covered(shell: Shell, boundary: bool) -> list[tuple[float, float]]:
    """The radii the built mesh covers, where its nodes lie: those of its triangles (or of its
    boundary edges), merged into intervals."""
    V, F = shell.mesh.vertices[:, :2], shell.mesh.faces
    cells = meshes.boundary_edges(F) if boundary else F
    parts = shapely.linestrings(V[cells]) if boundary else shapely.polygons(V[cells])
    near = shapely.distance(parts, shapely.Point(0.0, 0.0))
    far = np.hypot(V[:, 0], V[:, 1])[cells].max(1)
    spans: list[list[float]] = []
    for a, b in sorted(zip(near, far, strict=True)):
        if spans and a <= spans[-1][1]:
            spans[-1][1] = max(spans[-1][1], b)
        else:
            spans.append([a, b])
    return [(a, b) for a, b in spans]


def rings(shell: Shell) -> list[tuple[float, float]]:
    """Narrow and wide rings from the axis to past the blank, at its edges and between its
    nodes."""
    r_max = np.hypot(shell.plane_mid[:, 0], shell.plane_mid[:, 1]).max()
    return [(a, a + w) for a in np.linspace(0.0, r_max + 0.005, 151) for w in (1e-4, 2e-3)]


@pytest.mark.parametrize("name", sorted(MESHES))
@pytest.mark.parametrize("element", ELEMENTS)
@pytest.mark.parametrize("boundary", [False, True], ids=["all", "boundary"])
def test_a_ring_is_refused_when_it_misses_the_built_blank(name, element, boundary):
    """Sound: every ring refused selects no node of the built mesh (vertices and edge nodes,
    all nodes or the boundary's). And useful: every ring clear of the radii the built mesh
    covers is refused, so the check's ranges are those radii (between nodes a ring may still
    select none: the build names it)."""
    spec = TypeAdapter(MeshSpec).validate_python(MESHES[name])
    shell = built(name, element)
    spans = covered(shell, boundary)
    missed = 0
    for r_min, r_max in rings(shell):
        region = RegionSpec(name="r", ring={"r_min": r_min, "r_max": r_max}, boundary=boundary)
        clear = all(r_max < a - CLEAR or r_min > b + CLEAR for a, b in spans)
        missed += clear
        if ring_problem(spec, [region]) is None:
            assert not clear, (r_min, r_max, spans)
            continue
        with pytest.raises(ValueError, match="selects no node"):
            region_mask(shell, region)
    assert missed >= 20  # the rings past the blank, at least


@pytest.mark.parametrize("name", sorted(MESHES))
@pytest.mark.parametrize("boundary", [False, True], ids=["all", "boundary"])
def test_a_ring_within_the_builds_tolerance_of_a_node_is_accepted(name, boundary):
    """A ring that begins half region_mask's tolerance past the outermost node (or ends half
    of it short of the innermost, off the axis) selects that node in the build, and is
    accepted."""
    spec = TypeAdapter(MeshSpec).validate_python(MESHES[name])
    shell = built(name, "quadratic")
    tol = REGION_TOLERANCE * np.ptp(shell.mesh.vertices, axis=0).max()
    everywhere = RegionSpec(name="r", ring={"r_max": 1.0}, boundary=boundary)
    radius = np.hypot(shell.plane_mid[:, 0], shell.plane_mid[:, 1])[
        region_mask(shell, everywhere)]
    near = [(radius.max() + 0.5 * tol, radius.max() + 0.001)]
    if radius.min() > 0.001:
        near.append((radius.min() - 0.001, radius.min() - 0.5 * tol))
    for r_min, r_max in near:
        region = RegionSpec(name="r", ring={"r_min": r_min, "r_max": r_max}, boundary=boundary)
        assert region_mask(shell, region).sum() >= 1
        assert ring_problem(spec, [region]) is None, (r_min, r_max)


def test_a_mesh_file_is_read_again_when_it_changes_and_left_to_the_build_when_unreadable(
        tmp_path):
    """The ranges of a mesh file follow the file (its ranges are kept per version of it: a
    file written anew is read anew); one the check cannot read (missing, not a mesh) gives no
    ranges, and the build names its problem at mesh.path."""
    path = tmp_path / "blank.obj"
    region = RegionSpec(name="r", ring={"r_min": 0.05, "r_max": 0.06})
    spec = TypeAdapter(MeshSpec).validate_python({"kind": "file", "path": str(path)})
    for size, refused in ((0.04, True), (0.07, False)):
        path.write_text(f"v 0 0 0\nv {size} 0 0\nv 0 {size} 0\nf 1 2 3\n")
        os.utime(path, ns=(int(size * 1e12), int(size * 1e12)))  # a new version, whatever the clock
        assert (ring_problem(spec, [region]) is not None) == refused, size
    for text, why in (("", "no triangles"), ("v 0 0 0\nf 1 2 9\n", "not a readable mesh")):
        path.write_text(text)
        os.utime(path, ns=(len(text) + 1, len(text) + 1))
        assert spec.radial_ranges() is None and ring_problem(spec, [region]) is None
        with pytest.raises(ValueError, match=why):
            build_mesh(spec)
    missing = TypeAdapter(MeshSpec).validate_python(
        {"kind": "file", "path": str(tmp_path / "none.obj")})
    assert missing.radial_ranges() is None


def test_an_unreadable_drawing_is_left_to_the_build(tmp_path):
    """A drawing the check cannot read gives it no ranges (no ring refused, nothing raised
    when the scene is read); the build names the file's problem at mesh.path."""
    spec = TypeAdapter(MeshSpec).validate_python(
        {"kind": "outline", "edge_length": H, "path": str(tmp_path / "none.svg")})
    region = RegionSpec(name="r", ring={"r_min": 1.0, "r_max": 2.0})
    assert spec.radial_ranges() is None and ring_problem(spec, [region]) is None
    with pytest.raises(ValueError, match="no drawing"):
        build_mesh(spec)


@pytest.mark.parametrize("thickness, refused", [(0.1, True), (0.061, True), (0.059, False)])
def test_a_sheet_thicker_than_its_blank_is_across_is_refused_when_read(thickness, refused):
    """100 mm on the 60 mm cup blank read 'valid' in the form and failed after Start (the
    build's 'not a sheet'): refused when the scene is read, naming shell.thickness, once it
    is more than the blank is across at all (twice its radius); nearer the build decides."""
    cup = ROOT / "scenes/cup_drawing.toml"
    if not refused:
        load_scene(cup, {"shell.thickness": thickness})
        return
    with pytest.raises(SceneError, match=r"shell.thickness: .* mm thick, more than the blank "
                                         r"is across \(60 mm at most\): not a sheet"):
        load_scene(cup, {"shell.thickness": thickness})

"""The ``outline`` mesh kind in scenes: points, a circle or a drawing next to the scene file,
checked when the scene is read (points, circle) or built (a drawing), errors naming the field;
its size known before the build."""

import math
import tomllib

import numpy as np
import pytest

from server.store import SceneStore
from sim.geometry.trimesh import boundary_edges
from sim.model import size
from sim.model.sheet import build_mesh, mesh_and_thickness
from sim.scene.load import SceneError, load_scene, scene_from_toml
from tests.support import ROOT

SCENE = """
name = "blank"
[mesh]
{mesh}
[shell]
thickness = 0.001
[material]
E = 2e11
nu = 0.3
"""
SQUARE = "[[0.0, 0.0], [0.1, 0.0], [0.1, 0.1], [0.0, 0.1]]"
HOLE = "[[0.04, 0.04], [0.06, 0.04], [0.06, 0.06], [0.04, 0.06]]"
# SQUARE with HOLE in mm; SVG's y axis points down
SVG = ('<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 -100 100 100">'
       '<path d="M 0 0 H 100 V -100 H 0 Z M 40 -40 V -60 H 60 V -40 Z"/></svg>')


def outline_toml(**fields) -> str:
    body = {"kind": '"outline"', "edge_length": "0.005", **fields}
    return SCENE.format(mesh="\n".join(f"{k} = {v}" for k, v in body.items()))


@pytest.mark.parametrize("fields, words", [
    ({"points": "[[0.0, 0.0], [0.1, 0.0]]"}, "mesh: points: a closed outline needs at least 3"),
    ({"points": "[[0.0, 0.0], [0.1, 0.1], [0.1, 0.0], [0.0, 0.1]]"},
     "mesh: points: the outline is not a simple closed curve: Self-intersection[0.05 0.05]"),
    ({"points": SQUARE, "holes": "[[[0.2, 0.2], [0.3, 0.2], [0.3, 0.3]]]"},
     "mesh: holes.0: hole 0 does not lie inside the outline"),
    ({"points": SQUARE, "edge_length": "0.08"}, "mesh: edge_length: 80 mm is too coarse"),
    ({"points": SQUARE, "edge_length": "1e-6"}, "mesh: edge_length: 0.001 mm would give"),
    ({}, "mesh: give exactly one of points, path, circle (got none)"),
    # the form's file field before a file is chosen: said at the field (it read as a path
    # leading out of the scenes folder, at Save)
    ({"path": '""'}, "mesh.path: no file chosen: choose or upload one (or leave the field "
                     "unset)"),
    ({"points": SQUARE, "centre": "true"}, "mesh: centre: for a drawing (path); points and a "
                                           "circle are placed by their coordinates"),
    ({"points": SQUARE, "path": '"b.svg"'},
     "mesh: give exactly one of points, path, circle (got points, path)"),
    ({"path": '"b.svg"', "holes": f"[{HOLE}]"}, "mesh: holes: a drawing's holes are its"),
    ({"points": SQUARE, "circle": "{ radius = 0.05 }"},
     "mesh: give exactly one of points, path, circle (got points, circle)"),
    ({"circle": "{ radius = 0.05 }", "path": '"b.svg"'},
     "mesh: give exactly one of points, path, circle (got path, circle)"),
    ({"circle": "{ radius = 0.0 }"}, "mesh.circle.radius: Input should be greater than"),
    ({"circle": "{ radius = -0.05 }"}, "mesh.circle.radius: Input should be greater than"),
    ({"circle": "{ radius = 0.05, segments = 14 }"},
     "mesh.circle.segments: Input should be greater than or equal to 15"),
    ({"circle": "{ radius = 0.05, segments = 100001 }"},
     "mesh.circle.segments: Input should be less than or equal to 100000"),
    ({"circle": "{ radius = 0.05, segments = 36.5 }"}, "mesh.circle.segments"),
    ({"circle": "{ radius = 0.05, center = [0.0] }"}, "mesh.circle.center"),
    ({"circle": "{ radius = 0.05, centre = [0.0, 0.0] }"}, "mesh.circle.centre: Extra inputs"),
    ({"circle": "{ center = [0.0, 0.0] }"}, "mesh.circle.radius: Field required"),
    ({"circle": "{ radius = 0.05 }", "holes": "[[[0.06, 0.0], [0.08, 0.0], [0.07, 0.01]]]"},
     "mesh: holes.0: hole 0 does not lie inside the outline"),
    ({"circle": "{ radius = 0.05 }", "edge_length": "0.05"},
     "mesh: edge_length: 50 mm is too coarse"),
])
def test_bad_outline_is_refused_naming_the_field(fields, words):
    with pytest.raises(SceneError) as err:
        scene_from_toml(outline_toml(**fields))
    assert words in str(err.value)


def test_a_circle_takes_holes():
    """A circle of 40 mm about the square hole's centre (50, 50) mm, with the hole: its
    boundary on the circle's 360-gon and on the hole's sides, nothing meshed in the hole."""
    scene = scene_from_toml(outline_toml(circle="{ radius = 0.04, center = [0.05, 0.05] }",
                                         holes=f"[{HOLE}]"))
    m = mesh_and_thickness(scene)[0]
    xy = m.vertices[:, :2]
    square = np.abs(xy - 0.05).max(1)  # the hole is square <= 0.01
    edge = np.unique(boundary_edges(m.faces))
    on_hole = square[edge] <= 0.01 + 1e-12
    r = np.hypot(*(xy[edge[~on_hole]] - 0.05).T)
    sag = 0.04 * (1 - math.cos(math.pi / 360))  # the 360-gon's sides lie this far inside
    assert on_hole.sum() >= 4 and len(r) == round(2 * math.pi * 0.04 / 0.005)  # resampled
    assert (r > 0.04 - sag - 1e-9).all() and (r < 0.04 + 1e-9).all()
    assert (square > 0.01 - 1e-12).all()


def listed(radius: float, segments: int) -> str:
    """A circle's points as a scene lists them: nine decimals of a metre."""
    t = [2 * math.pi * k / segments for k in range(segments)]
    return "[" + ", ".join(f"[{radius * math.cos(a):.9f}, {radius * math.sin(a):.9f}]"
                           for a in t) + "]"


def test_the_shipped_circle_meshes_as_its_listed_points():
    """cup_drawing_outline's circle gives the very mesh of the 360 points it listed before
    (nine decimals, as written by hand): gmsh's Frontal-Delaunay mesh changes when its input
    moves in the last bits, which the circle's rounding to a nanometre keeps out."""
    text = (ROOT / "scenes/cup_drawing_outline.toml").read_text()
    spec = scene_from_toml(text).mesh
    circle = spec.circle
    points = scene_from_toml(outline_toml(
        points=listed(circle.radius, circle.segments),
        edge_length=repr(spec.edge_length))).mesh
    assert circle.center == (0.0, 0.0)
    np.testing.assert_array_equal(spec.shape().outer, points.shape().outer)
    a, b = build_mesh(spec), build_mesh(points)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)
    assert tomllib.loads(text)["mesh"]["circle"] == {"radius": 0.03, "segments": 360}


def test_the_mesher_is_the_scenes_choice():
    """mesh.mesher reaches the build: the shipped cup's blank with MeshAdapt is another mesh
    on the same boundary (the outline resampled at the edge length, whichever mesher)."""
    text = (ROOT / "scenes/cup_drawing_outline.toml").read_text()
    frontal = scene_from_toml(text).mesh
    adapt = frontal.model_copy(update={"mesher": "meshadapt"})
    a, b = build_mesh(frontal), build_mesh(adapt)
    assert len(a.faces) != len(b.faces)
    rim = [np.sort(np.linalg.norm(m.vertices[np.unique(boundary_edges(m.faces))][:, :2], axis=1))
           for m in (a, b)]
    np.testing.assert_array_equal(rim[0], rim[1])
    with pytest.raises(SceneError, match="mesh.mesher"):
        scene_from_toml(text.replace("[mesh]\n", '[mesh]\nmesher = "delaunay"\n', 1))


def test_points_and_drawing_give_the_same_blank(tmp_path):
    """A square with a square hole, as points and as an SVG in mm next to the scene: the same
    boundary vertices (the interior follows the order gmsh meets them in); its size estimated
    before the build within 10 % (equilateral triangles of the edge length against a real
    mesh's mix)."""
    (tmp_path / "blank.svg").write_text(SVG)
    (tmp_path / "a.toml").write_text(outline_toml(points=SQUARE, holes=f"[{HOLE}]"))
    (tmp_path / "b.toml").write_text(outline_toml(path='"blank.svg"', scale="0.001"))
    a, b = (load_scene(tmp_path / f"{n}.toml") for n in "ab")
    (ma, ha, ra), (mb, _, _) = mesh_and_thickness(a), mesh_and_thickness(b)
    assert ra == {"kind": "outline", "vertices": len(ma.vertices), "triangles": len(ma.faces)}
    boundary = [np.unique(np.round(m.vertices[boundary_edges(m.faces).ravel()], 12), axis=0)
                for m in (ma, mb)]
    np.testing.assert_allclose(boundary[0], boundary[1], atol=1e-12)
    assert (ha == 0.001).all()
    for m, sc in ((ma, a), (mb, b)):
        n_v, n_f = size.mesh_counts(sc.mesh)
        assert n_v == pytest.approx(len(m.vertices), rel=0.1)
        assert n_f == pytest.approx(len(m.faces), rel=0.1)


def test_a_bad_drawing_is_refused_naming_the_field(tmp_path):
    """By the model's size check, before a run starts (a 422 from the service), and by the
    build: a drawing that is missing, has an open path or only an empty rect (svgelements
    read it as the whole page), is read in other units than its scale says, or says no units
    where the scene gives no scale."""
    svg = '<svg xmlns="http://www.w3.org/2000/svg" width="60mm" height="40mm" ' \
          'viewBox="0 0 60 40">{}</svg>'
    (tmp_path / "open.svg").write_text(svg.format('<path d="M 0 0 L 100 0 L 100 100"/>'))
    (tmp_path / "empty.svg").write_text(svg.format("<rect/>"))
    (tmp_path / "mm.svg").write_text(svg.format('<rect width="60" height="40"/>'))
    (tmp_path / "px.svg").write_text(svg.replace("mm", "px").format('<rect width="60" '
                                                                    'height="40"/>'))
    for name, scale, words in (
            ("none.svg", "0.001", "mesh.path: no drawing"),
            ("open.svg", "0.001", "mesh.path: open.svg: an open path"),
            ("empty.svg", "0.001", "mesh.path: empty.svg: no closed path"),
            ("mm.svg", "1", "mesh.scale: absurd size: the drawing is 60000 mm across with "
                            "scale = 1 .a blank is 0.1-5000 mm across; a drawing in mm needs "
                            "scale = 0.001."),
            ("px.svg", None, "mesh.scale: px.svg does not say its units .an SVG's width in "
                             "mm, cm, in, pt or pc over its viewBox; a DXF's .INSUNITS.: give "
                             "scale, 0.001 for a drawing in mm")):
        given = {"scale": scale} if scale else {}
        (tmp_path / "s.toml").write_text(outline_toml(path=f'"{name}"', **given))
        sc = load_scene(tmp_path / "s.toml")
        with pytest.raises(SceneError, match=words):
            size.mesh_counts(sc.mesh)
        with pytest.raises(ValueError, match=words):
            mesh_and_thickness(sc)
    for given in ({"scale": "0.001"}, {}):  # in mm, as given or as the drawing says
        (tmp_path / "s.toml").write_text(outline_toml(path='"mm.svg"', **given))
        assert size.mesh_counts(load_scene(tmp_path / "s.toml").mesh)[1] > 0


def test_the_service_reads_drawings_from_its_scenes_folder_only(tmp_path):
    """A drawing is a file the scene reads: inside the scenes folder, of a drawing's suffix;
    points read no file."""
    store = SceneStore(tmp_path)
    (tmp_path / "blank.svg").write_text(SVG)
    ok = store.validate(outline_toml(path='"blank.svg"', scale="0.001"))
    assert store.scene_files(ok) == {"mesh.path": tmp_path / "blank.svg"}
    assert store.scene_files(store.validate(outline_toml(points=SQUARE))) == {}
    for path, words in (("/etc/passwd", "must be a relative path"),
                        ("../x.svg", "must be a relative path"),
                        ("blank.obj", "not a file of the kind")):
        with pytest.raises(SceneError, match=f"mesh.path: .*{words}"):
            store.validate(outline_toml(path=f'"{path}"'))


REFINE = "[{ ring = { r_min = 0.02, r_max = 0.04 }, edge_length = 0.0025 }]"


def test_refined_outline_builds_finer_where_asked():
    """``refine`` reaches the mesher: the refined blank has more triangles than the plain
    one, fewer than the size estimate (an upper bound), and the ring's triangles are the
    band's size."""
    plain = mesh_and_thickness(scene_from_toml(outline_toml(points=SQUARE)))[0]
    scene = scene_from_toml(outline_toml(points=SQUARE, refine=REFINE))
    m = mesh_and_thickness(scene)[0]
    assert len(plain.faces) < len(m.faces) <= size.estimate(scene).elements
    c = m.vertices[m.faces].mean(1)
    r = np.linalg.norm(c[:, :2], axis=1)
    e = np.linalg.norm(m.vertices[m.faces[:, 1]] - m.vertices[m.faces[:, 0]], axis=1)
    assert abs(e[(r > 0.022) & (r < 0.038)].mean() / 0.0025 - 1) < 0.15


@pytest.mark.parametrize("refine, words", [
    ("[{ ring = { r_min = 0.04, r_max = 0.02 }, edge_length = 0.001 }]",
     "mesh.refine.0: ring: r_min must be smaller than r_max"),
    ("[{ ring = { r_max = 0.02 }, edge_length = 0.01 }]",
     "mesh: refine.0.edge_length: 10 mm is not finer"),
    ("[{ ring = { r_max = 0.02 }, edge_length = -0.001 }]", "mesh.refine.0.edge_length"),
    ("[{ ring = { r_max = 0.02 }, edge_length = 0.001, growth = 0.0 }]",
     "mesh.refine.0.growth"),
    ("[{ ring = { r_max = 0.2 }, edge_length = 1e-6 }]",
     "mesh: refine: the refined rings would give"),
    ("[{ edge_length = 0.001 }]", "mesh.refine.0.ring"),
])
def test_bad_refinement_is_refused_naming_the_field(refine, words):
    with pytest.raises(SceneError) as err:
        scene_from_toml(outline_toml(points=SQUARE, refine=refine))
    assert words in str(err.value)

"""Mesh files (OBJ, PLY, STL) and per-vertex thickness (an array file next to the scene, or a
PLY vertex property): read, validated with errors naming the field, extruded exactly."""

import numpy as np
import pytest
import trimesh

from sim.elements import ROUTINE
from sim.geometry import trimesh as mesh
from sim.scene.load import SceneError, load_scene
from sim.stepping.simulation import Simulation

SCENE = """
name = "plate"
[mesh]
{mesh}
[shell]
{shell}
element = "{element}"
[material]
E = 1e6
nu = 0.3
[[regions]]
name = "clamp"
plane = {{ point = [0.0, 0.0, 0.0], normal = [1.0, 0.0, 0.0] }}
[[bcs]]
region = "clamp"
[[loads]]
kind = "gravity"
vector = [0.0, 0.0, -9.81]
[[probes]]
name = "volume"
kind = "volume"
"""
RECT = 'kind = "rectangle"\nsize = [0.1, 0.06]\nedge_length = 0.02'


def write_scene(tmp_path, mesh_toml=RECT, shell='thickness = 0.004', element="q3t"):
    p = tmp_path / "scene.toml"
    p.write_text(SCENE.format(mesh=mesh_toml, shell=shell, element=element))
    return p


def exact_volume(m: mesh.TriMesh, h: np.ndarray) -> float:
    """int h dA of the piecewise-linear thickness over a flat mid-surface: area x mean h."""
    V = m.vertices[m.faces]
    area = 0.5 * np.linalg.norm(np.cross(V[:, 1] - V[:, 0], V[:, 2] - V[:, 0]), axis=1)
    return float(np.sum(area * h[m.faces].mean(1)))


@pytest.mark.parametrize("element", ROUTINE)
@pytest.mark.parametrize("fmt", ["npy", "txt"])
def test_thickness_file_extrudes_to_its_integral(tmp_path, element, fmt):
    """Over a flat mid-surface detJ = h(u, v) |a_u x a_v| / 2 is linear in-plane and constant
    through the thickness, so every rule integrates it exactly: the extruded volume is
    int h dA to round-off."""
    m = mesh.rectangle((0.1, 0.06), 0.02)
    h = 0.003 + 0.002 * np.random.default_rng(1).random(len(m.vertices))
    if fmt == "npy":
        np.save(tmp_path / "h.npy", h)
    else:
        np.savetxt(tmp_path / "h.txt", h)
    path = write_scene(tmp_path, shell=f'thickness_file = "h.{fmt}"', element=element)
    sim = Simulation.from_scene(load_scene(path))
    assert np.allclose(sim.model.shell.thickness, h, rtol=1e-15 if fmt == "npy" else 1e-12)
    fibre = sim.model.shell.rest[sim.model.shell.skin_nodes(True)] - \
        sim.model.shell.rest[sim.model.shell.skin_nodes(False)]
    assert np.allclose(fibre[:, 2], sim.model.shell.thickness, rtol=1e-14)
    vol = sim.model.elasticity.wdetJ.sum()
    assert vol == pytest.approx(exact_volume(m, h), rel=1e-12)
    assert sim.run(), sim.failure  # and it runs
    assert sim.records[-1].probes["volume"] == pytest.approx(vol, rel=1e-2)


def _ply_with_thickness(path, m: mesh.TriMesh, h: np.ndarray) -> None:
    head = ("ply\nformat ascii 1.0\n"
            f"element vertex {len(m.vertices)}\nproperty double x\nproperty double y\n"
            "property double z\nproperty double thickness\n"
            f"element face {len(m.faces)}\nproperty list uchar int vertex_indices\nend_header\n")
    rows = [f"{x:.17g} {y:.17g} {z:.17g} {t:.17g}"
            for (x, y, z), t in zip(m.vertices, h, strict=True)]
    rows += [f"3 {a} {b} {c}" for a, b, c in m.faces]
    path.write_text(head + "\n".join(rows) + "\n")


def test_thickness_from_a_ply_vertex_property(tmp_path):
    m = mesh.rectangle((0.1, 0.06), 0.02)
    h = 0.004 + 0.01 * m.vertices[:, 0] * m.vertices[:, 1]
    _ply_with_thickness(tmp_path / "sheet.ply", m, h)
    path = write_scene(tmp_path, 'kind = "file"\npath = "sheet.ply"',
                       'thickness_attribute = "thickness"')
    sim = Simulation.from_scene(load_scene(path))
    sh = sim.model.shell
    # trimesh may reorder nothing here, but match by position to be independent of it
    order = [int(np.argmin(np.linalg.norm(m.vertices - v, axis=1))) for v in sh.mesh.vertices]
    assert np.allclose(sh.thickness, h[order], rtol=1e-15)
    assert sim.model.elasticity.wdetJ.sum() == pytest.approx(exact_volume(sh.mesh, sh.thickness),
                                                             rel=1e-12)
    with pytest.raises(ValueError, match=r"shell.thickness_attribute: .*no vertex property 'h'"):
        Simulation.from_scene(load_scene(path, {"shell.thickness_attribute": "h"}))


@pytest.mark.parametrize("values,message", [
    (np.full(5, 0.004), "5 values for the 24 vertices"),
    (np.r_[np.full(23, 0.004), -1e-3], "vertex 23: -0.001 m"),
    (np.r_[np.full(23, 0.004), np.nan], "must be positive"),
])
def test_bad_thickness_arrays_name_the_field(tmp_path, values, message):
    np.save(tmp_path / "h.npy", values)
    path = write_scene(tmp_path, shell='thickness_file = "h.npy"')
    with pytest.raises(ValueError, match="shell.thickness_file") as err:
        Simulation.from_scene(load_scene(path))
    assert message in str(err.value)


def test_a_thickness_file_that_is_no_list_of_values_says_what_it_is(tmp_path):
    """A table (2 rows of 3, a 3-D array) was read across its rows as 6 values; a .npy of
    text or cut short was read as a text file ('line 1, value 1: "\\x93NUMPY..."'); a fuzz of
    the uploads."""
    from sim.model.sheet import read_values

    (tmp_path / "t.csv").write_text("1e-3,1e-3,1e-3\n1e-3,1e-3,1e-3\n")
    np.save(tmp_path / "cube.npy", np.full((2, 2, 2), 1e-3))
    np.save(tmp_path / "words.npy", np.array(["a", "b"]))
    (tmp_path / "cut.npy").write_bytes((tmp_path / "cube.npy").read_bytes()[:90])
    for name, words in (("t.csv", "t.csv holds an array of shape 2x3: a value per vertex is "
                                  "one column or one row"),
                        ("cube.npy", "cube.npy holds an array of shape 2x2x2"),
                        ("words.npy", "words.npy holds text, not numbers"),
                        ("cut.npy", "cut.npy is not an array of numbers (")):
        with pytest.raises(ValueError) as err:
            read_values(str(tmp_path / name))
        assert str(err.value).startswith(words), str(err.value)
    (tmp_path / "row.csv").write_text("1e-3,2e-3,3e-3\n")
    (tmp_path / "column.txt").write_text("1e-3\n2e-3\n3e-3\n")
    np.save(tmp_path / "column.npy", np.array([[1e-3], [2e-3], [3e-3]]))
    for name in ("row.csv", "column.txt", "column.npy"):  # one row or one column: the values
        assert read_values(str(tmp_path / name)).tolist() == [1e-3, 2e-3, 3e-3]


def test_thickness_sources_are_exclusive(tmp_path):
    with pytest.raises(SceneError, match="exactly one of thickness"):
        load_scene(write_scene(tmp_path, shell='thickness = 0.004\nthickness_file = "h.npy"'))
    with pytest.raises(SceneError, match="exactly one of thickness"):
        load_scene(write_scene(tmp_path, shell=""))
    with pytest.raises(SceneError, match="needs a PLY mesh file"):
        load_scene(write_scene(tmp_path, shell='thickness_attribute = "t"'))
    with pytest.raises(ValueError, match="shell.thickness_file: no file"):
        Simulation.from_scene(load_scene(write_scene(tmp_path,
                                                     shell='thickness_file = "none.npy"')))


@pytest.mark.parametrize("fmt", ["obj", "ply", "stl"])
def test_mesh_files_load_the_same_sheet(tmp_path, fmt):
    """The same disk written as OBJ, PLY and STL reads back as the same sheet (STL stores
    every triangle's corners apart: merging restores the shared vertices) and runs."""
    m = mesh.annulus(0.0, 0.05, 0.02)
    trimesh.Trimesh(m.vertices * 1e3, m.faces, process=False).export(tmp_path / f"d.{fmt}")
    path = write_scene(tmp_path, f'kind = "file"\npath = "d.{fmt}"\nscale = 1e-3')
    sim = Simulation.from_scene(load_scene(path))
    got = sim.model.shell.mesh
    assert len(got.vertices) == len(m.vertices) and len(got.faces) == len(m.faces)
    # mm -> m through scale; PLY and STL store float32: 6e-8 of 50 mm is 3e-9 m
    d = np.linalg.norm(got.vertices[:, None] - m.vertices[None], axis=2)
    assert d.min(1).max() < 1e-8 and len(set(d.argmin(1))) == len(m.vertices)
    assert sim.model.elasticity.wdetJ.sum() == pytest.approx(
        exact_volume(m, np.full(len(m.vertices), 0.004)), rel=1e-6)
    assert sim.run(), sim.failure


def test_missing_or_broken_mesh_file_names_the_field(tmp_path):
    path = write_scene(tmp_path, 'kind = "file"\npath = "nothing.obj"')
    with pytest.raises(ValueError, match="mesh.path: no mesh file"):
        Simulation.from_scene(load_scene(path))
    (tmp_path / "bad.ply").write_text("ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2\n")
    path = write_scene(tmp_path, 'kind = "file"\npath = "bad.ply"')
    with pytest.raises(ValueError, match="mesh.path: bad.ply"):
        Simulation.from_scene(load_scene(path))


def test_a_mesh_file_in_mm_read_as_metres_is_refused_naming_the_scale(tmp_path):
    """A 100 mm disk written in mm and read at scale 1 was a blank 100 m across, built and
    previewed without a word (a browser review); refused as a drawing of that size is."""
    m = mesh.annulus(0.0, 0.05, 0.02)
    trimesh.Trimesh(m.vertices * 1e3, m.faces, process=False).export(tmp_path / "d.obj")
    path = write_scene(tmp_path, 'kind = "file"\npath = "d.obj"\nscale = 1')
    with pytest.raises(ValueError, match=r"^mesh.scale: absurd size: the mesh is 100000 mm "
                       r"across with scale = 1 \(a blank is 0.1-5000 mm across; a mesh in mm "
                       r"needs scale = 0.001\)$"):
        Simulation.from_scene(load_scene(path))


def test_imperfection_seeds_one_smooth_bump(tmp_path):
    path = write_scene(tmp_path)
    sim = Simulation.from_scene(load_scene(path, {"mesh.imperfection": 1e-5}))
    V = sim.model.shell.mesh.vertices
    s, t = V[:, 0] / 0.1, V[:, 1] / 0.06
    assert np.allclose(V[:, 2], 1e-5 * np.sin(np.pi * s) * np.sin(np.pi * t), atol=1e-20)
    assert V[:, 2].max() > 0.5e-5
    band = write_scene(tmp_path, 'kind = "cylinder_band"\nradius = 0.05\nheight = 0.02\n'
                                 'edge_length = 0.02')
    with pytest.raises(ValueError, match="mesh.imperfection: needs a flat mesh"):
        Simulation.from_scene(load_scene(band, {"mesh.imperfection": 1e-5}))


SLIT = """
name = "slit"
[mesh]
kind = "file"
path = "slit.obj"
{merge}
[shell]
thickness = 0.002
element = "linear"
[material]
E = 1e6
nu = 0.3
[[regions]]
name = "bottom"
plane = {{ point = [0.0, 0.0, 0.0], normal = [0.0, 1.0, 0.0], tolerance = 1e-6 }}
[[regions]]
name = "top"
plane = {{ point = [0.0, 0.1, 0.0], normal = [0.0, 1.0, 0.0], tolerance = 1e-6 }}
[[bcs]]
region = "bottom"
[[bcs]]
region = "top"
displacement = [0.0, 1e-4, 0.0]
"""


def _slit_plate_obj(path) -> None:
    """A 10 x 10 cm plate, a 6 x 6 vertex grid (vertex (i, j) is number 6 j + i), with a slit
    from the left edge along y = 4 cm to x = 6 cm: the cells above the slit use copies of its
    vertices at x = 0, 2 and 4 cm (numbers 36-38), the tip at 6 cm is shared. 39 vertices,
    two rows of them coincident."""
    xs = np.linspace(0.0, 0.1, 6)
    V = [(x, y, 0.0) for y in xs for x in xs] + [(xs[i], xs[2], 0.0) for i in range(3)]

    def vid(i, j, above_slit):
        return 36 + i if above_slit and j == 2 and i <= 2 else 6 * j + i

    F = []
    for j in range(5):
        for i in range(5):
            a, b, c, d = (vid(i, j, j == 2), vid(i + 1, j, j == 2),
                          vid(i + 1, j + 1, j == 2), vid(i, j + 1, j == 2))
            F += [(a, b, c), (a, c, d)]
    path.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in V)
                    + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F))


def test_a_mesh_file_keeps_its_topology_and_merges_only_on_request(tmp_path):
    """The slit plate pulled apart: read as the file has it, the slit opens (its two sides
    are different vertices); merged on request, it is a closed plate, and built.mesh says
    which vertices were merged."""
    _slit_plate_obj(tmp_path / "slit.obj")
    gaps, built = {}, {}
    for merge in (None, True):
        path = tmp_path / "scene.toml"
        path.write_text(SLIT.format(merge="" if merge is None else "merge_vertices = true"))
        sim = Simulation.from_scene(load_scene(path))
        assert sim.run(), sim.failure
        built[merge] = sim.result()["built"]["mesh"]
        sheet = sim.model.shell.mesh
        x = sim.x[: len(sheet.vertices)]  # the bottom skin nodes of the mid-surface vertices
        at = np.flatnonzero(np.isclose(sheet.vertices[:, 0], 0.0)
                            & np.isclose(sheet.vertices[:, 1], 0.04))
        gaps[merge] = np.ptp(x[at, 1]) if len(at) > 1 else 0.0
        assert len(mesh.boundary_edges(sheet.faces)) == (26 if merge is None else 20)
    assert built[None] == {"kind": "file", "file": "slit.obj", "file_vertices": 39,
                           "vertices": 39, "triangles": 50, "merged": 0, "merged_groups": [],
                           "unused": 0}
    assert built[True] == {**built[None], "vertices": 36, "merged": 3,
                           "merged_groups": [[12, 36], [13, 37], [14, 38]]}
    # the mouth of the slit opens by a good part of the 0.1 mm the plate is stretched by
    assert gaps[None] > 2e-5 and gaps[True] == 0.0


def test_merging_that_collapses_a_triangle_names_the_file(tmp_path):
    (tmp_path / "sliver.obj").write_text("v 0 0 0\nv 1 0 0\nv 1 1e-12 0\nv 0 1 0\n"
                                         "f 1 2 4\nf 2 3 4\n")
    path = write_scene(tmp_path, 'kind = "file"\npath = "sliver.obj"\nmerge_vertices = true')
    with pytest.raises(ValueError, match=r"mesh.path: sliver.obj: 1 triangles have a repeated "
                                         r"vertex \(first: \[1\]\) once coincident"):
        Simulation.from_scene(load_scene(path))
    with pytest.raises(SceneError, match=r"^mesh\.merge_vertices: not a field of "
                                         r"kind 'rectangle'"):
        load_scene(write_scene(tmp_path, RECT + "\nmerge_vertices = true"))

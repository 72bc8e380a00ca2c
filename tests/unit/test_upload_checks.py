"""The checks an uploaded file passes before the scenes folder keeps it (server.files): a blank
mid-surface as the solver reads it, without zero-area triangles, non-manifold or flipped edges;
a thickness file of positive numbers; a plain file name whose extension says its kind."""

from __future__ import annotations

import numpy as np
import pytest

from server.files import (
    check_blank,
    check_file_name,
    inspect_blank,
    inspect_thickness,
    kind_of,
)
from server.problems import Invalid
from sim.geometry.trimesh import boundary_edges, rectangle


def plate():
    m = rectangle((0.7, 0.07), 0.035)
    return m.vertices.copy(), m.faces.copy()


def inner_edges(V, F, f):
    """Triangle ``f``'s edges that another triangle shares, as sorted vertex pairs."""
    outer = {tuple(e) for e in boundary_edges(F).tolist()}
    return [e for e in (sorted(F[f, [0, 1]]), sorted(F[f, [1, 2]]), sorted(F[f, [2, 0]]))
            if tuple(int(v) for v in e) not in outer]


def write_obj(path, V, F):
    lines = [f"v {x:.17g} {y:.17g} {z:.17g}" for x, y, z in V]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in F]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_a_plate_is_a_blank():
    assert check_blank(*plate()) is None


def test_a_zero_area_triangle_is_refused():
    V, F = plate()
    a, b, c = F[7]
    V[c] = (V[a] + V[b]) / 2  # onto the opposite edge's midpoint: area zero to round-off
    problem = check_blank(V, F)  # (and a neighbour of c's, along the same grid line)
    assert problem and problem.startswith("2 zero-area (degenerate) triangles"), problem
    assert "first: [7, 9]" in problem


def test_an_edge_of_three_triangles_is_refused():
    V, F = plate()
    a, b = inner_edges(V, F, 10)[0]
    fin = np.vstack([V, (V[a] + V[b]) / 2 + [0, 0, 0.02]])  # a fin standing on an inner edge
    problem = check_blank(fin, np.vstack([F, [a, b, len(V)]]))
    assert problem and problem.startswith("1 non-manifold edges, each shared by more than two"), \
        problem
    assert str(sorted([int(a), int(b)])) in problem


def test_a_flipped_triangle_is_refused():
    V, F = plate()
    shared = len(inner_edges(V, F, 12))
    F[12] = F[12, ::-1]  # each edge it shares now meets its neighbour walked the same way
    problem = check_blank(V, F)
    assert problem and problem.startswith(f"{shared} edges between triangles wound opposite "
                                          "ways"), problem


def test_a_blank_file_is_read_as_the_solver_reads_it(tmp_path):
    V, F = plate()
    # its extent in the file's own units (the scene's scale makes them metres)
    extent = np.ptp(V, axis=0).tolist()
    assert inspect_blank(write_obj(tmp_path / "p.obj", V, F)) == {
        "vertices": len(V), "triangles": len(F), "extent": pytest.approx(extent, rel=1e-9)}
    F[3] = F[3, ::-1]
    with pytest.raises(Invalid, match=r"^f\.obj: \d edges between triangles wound opposite"):
        inspect_blank(write_obj(tmp_path / "f.obj", V, F))


@pytest.mark.parametrize("name,content,reason", [
    ("text.obj", b"this is not a mesh\n", "text.obj: no triangles"),
    ("empty.stl", b"", "empty.stl: "),
    # a binary STL of 12 triangles (84 + 600 bytes) cut after 584: trimesh read it as an
    # empty text STL, and the reason said "not a .stl mesh file"
    ("cut.stl", bytes(80) + (12).to_bytes(4, "little") + bytes(500),
     "cut.stl: a binary STL of 12 triangles cut short: 584 bytes of the 684 they take"),
    ("text.stl", b"solid x\n" + b"  facet normal 0 0 1\n" * 5 + b"endsolid\n",
     "text.stl: no triangles: not a .stl mesh file"),
    ("noise.ply", bytes(range(256)) * 4, "noise.ply: not a readable mesh"),
    ("points.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\n", "points.obj: no triangles"),
    ("nan.obj", b"v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n", "nan.obj: vertex 1"),
    ("repeat.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 2\n", "repeat.obj: 1 triangles have a "
                                                           "repeated vertex"),
])
def test_what_is_not_a_mesh_is_refused_naming_the_file(tmp_path, name, content, reason):
    (tmp_path / name).write_bytes(content)
    with pytest.raises(Invalid) as err:
        inspect_blank(tmp_path / name)
    assert str(err.value).startswith(reason), str(err.value)


def test_a_thickness_file_is_positive_numbers(tmp_path):
    (tmp_path / "t.txt").write_text("0.001\n0.002\n0.003\n")
    assert inspect_thickness(tmp_path / "t.txt") == {"values": 3}
    np.save(tmp_path / "t.npy", np.full(5, 7e-3))
    assert inspect_thickness(tmp_path / "t.npy") == {"values": 5}
    (tmp_path / "t.csv").write_text("0.001,0.002,0.003\n")
    assert inspect_thickness(tmp_path / "t.csv") == {"values": 3}


@pytest.mark.parametrize("name,content,reason", [
    ("neg.txt", b"0.001\n-0.002\n", "neg.txt: 1 values are no thickness"),
    ("zero.csv", b"0.001,0,0.002\n", "zero.csv: 1 values are no thickness"),
    ("nan.txt", b"0.001 nan\n", "nan.txt: 1 values are no thickness"),
    ("words.txt", b"seven millimetres\n", "words.txt is not an array of numbers"),
    # where, as an editor counts lines (numpy said "row 2, column 1": rows from 0, data only)
    ("line.csv", b"# mm\n0.001\n\n0.002\nabc\n",
     "line.csv is not an array of numbers (line 5, value 1: 'abc' is not a number)"),
    ("ragged.txt", b"0.001 0.002\n0.003\n", "ragged.txt is not an array of numbers"),
    ("empty.txt", b"", "empty.txt: no values"),
    ("empty.npy", b"", "empty.npy is not an array of numbers"),
    ("noise.npy", bytes(range(256)), "noise.npy is not an array of numbers"),
])
def test_what_is_no_thickness_is_refused_naming_the_file(tmp_path, name, content, reason):
    (tmp_path / name).write_bytes(content)
    with pytest.raises(Invalid) as err:
        inspect_thickness(tmp_path / name)
    assert str(err.value).startswith(reason), str(err.value)


def test_a_pickled_npy_is_refused_unread(tmp_path):
    np.save(tmp_path / "obj.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(Invalid, match="obj.npy is not an array of numbers"):
        inspect_thickness(tmp_path / "obj.npy")


@pytest.mark.parametrize("name", ["blank.obj", "Blank-2.stl", "cup.v2.ply", "t.npy", "t_1.txt",
                                  "x.csv"])
def test_plain_names_of_a_known_kind_are_taken(name):
    assert check_file_name(name) == name


@pytest.mark.parametrize("name,reason", [
    ("../blank.obj", "no paths"), ("sub/blank.obj", "no paths"), ("..\\blank.obj", "no paths"),
    (".hidden.obj", "no paths"), ("/etc/x.obj", "no paths"), ("a..obj", "no paths"),
    ("", "no paths"), ("x" * 78 + ".obj", "1 to 80"),
    ("cup_drawing.toml", "unknown extension '.toml'"), ("blank.STL", "unknown extension '.STL'"),
    ("blank", "unknown extension '(none)'"), ("blank.step", "unknown extension '.step'"),
])
def test_other_names_are_refused(name, reason):
    with pytest.raises(Invalid) as err:
        check_file_name(name)
    assert reason in str(err.value), str(err.value)


def test_a_kind_given_must_be_the_extension_s():
    assert kind_of("b.stl") == "blank" and kind_of("t.csv", "thickness") == "thickness"
    with pytest.raises(Invalid, match=r"kind 'thickness': 'b.stl' is a blank file"):
        kind_of("b.stl", "thickness")


def test_of_two_uploads_of_one_new_name_one_is_kept(tmp_path):
    """A new name is linked into place, never renamed over: the second of two uploads that
    both found the name free is a Conflict, and the first one's file stays."""
    from server.files import FileStore
    from server.problems import Conflict
    from server.store import SceneStore

    files = FileStore(SceneStore(tmp_path / "scenes"))
    V, F = plate()
    want = write_obj(tmp_path / "want.obj", V, F).read_text()
    with files.incoming("p.obj") as first, files.incoming("p.obj") as second:
        write_obj(first, V, F)
        write_obj(second, V[:, [1, 0, 2]], F[:, ::-1])
        assert files.keep(first, "blank", replace=False)["triangles"] == len(F)
        with pytest.raises(Conflict, match="'p.obj' exists"):
            files.keep(second, "blank", replace=False)
    assert (tmp_path / "scenes" / "p.obj").read_text() == want
    assert sorted(p.name for p in (tmp_path / "scenes").iterdir()) == ["p.obj"]


def test_the_form_s_schema_names_the_kind_of_file_a_field_takes():
    from server.sceneform import schema

    defs = schema()["$defs"]
    assert defs["FileMesh"]["properties"]["path"]["x-file"] == "blank"
    assert defs["ShellSpec"]["properties"]["thickness_file"]["x-file"] == "thickness"


def test_upload_folders_left_by_a_dead_server_are_swept(tmp_path):
    """An upload folder untouched for an hour goes at the next upload; a live one stays."""
    import os
    import time

    from server.files import STALE, FileStore
    from server.store import SceneStore

    files = FileStore(SceneStore(tmp_path / "scenes"))
    now = time.time()
    with files.incoming("old.obj") as old, files.incoming("live.obj") as live:
        old.write_text("v 0 0 0\n")
        live.write_text("v 0 0 0\n")
        for p in (old, old.parent):
            os.utime(p, (now - STALE - 1, now - STALE - 1))
        assert files.sweep(now) == [old.parent.name]
        assert not old.parent.exists() and live.is_file()
    assert list((tmp_path / "scenes").iterdir()) == []

"""Tool surfaces uploaded into the scenes folder (/api/files with kind=tool): checked as a
tool's surface (422 naming the problem), used by a scene's mesh tool that runs, guarded from
deletion while a scene names it; the form's schema marks the field."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("fastapi")
import trimesh  # noqa: E402
from fastapi.testclient import TestClient  # noqa: E402

from server.app import create_app  # noqa: E402
from server.sceneform import schema  # noqa: E402
from server.settings import Settings  # noqa: E402
from tests.support.scenes import PRESS_TOML  # noqa: E402
from tests.support.service import HANG, wait_ready, wait_state  # noqa: E402

PUNCH = 'shape = { kind = "punch", radius = 0.004, height = 0.01, edge_radius = 0.001 }'


def stl(mesh: trimesh.Trimesh) -> bytes:
    return mesh.export(file_type="stl")


def punch_mesh() -> trimesh.Trimesh:
    """The press scene's punch as a closed surface (a cylinder, nose at z = 0)."""
    return trimesh.creation.cylinder(radius=0.004, height=0.01, sections=48).apply_translation(
        [0.0, 0.0, 0.005])


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("toolfiles")
    scenes = tmp / "scenes"
    scenes.mkdir()
    settings = Settings(scenes_dir=scenes, runs_dir=tmp / "runs", viewer=False,
                        max_upload=1_000_000, ack_timeout=HANG)
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("Q3T_CACHE", str(tmp / "cache"))  # the solver process inherits it
        with TestClient(create_app(settings)) as client:
            wait_ready(client)
            yield client, scenes


def upload(client, name, content, **params):
    return client.post("/api/files", params={"name": name, **params}, content=content)


def test_a_tool_surface_is_kept_used_by_a_running_scene_and_guarded(env):
    client, scenes = env
    r = upload(client, "punch.stl", stl(punch_mesh()), kind="tool")
    assert r.status_code == 201, r.text
    assert r.json()["kind"] == "tool" and r.json()["triangles"] == 192
    toml = PRESS_TOML.replace(PUNCH, 'shape = { kind = "mesh", path = "punch.stl" }')
    r = client.put("/api/scenes/pressed", json={"toml": toml})
    assert r.status_code == 200, r.text
    run = client.post("/api/runs", json={"scene": "pressed"})
    assert run.status_code == 201, run.text
    st = wait_state(client, run.json()["id"], {"finished", "failed", "stopped"})
    assert st["state"] == "finished", st["reason"]
    result = client.get(f"/api/runs/{run.json()['id']}/result").json()
    assert result["steps"][-1]["probes"]["punch_force"] > 0  # the mesh punch pressed
    assert client.get("/api/files/punch.stl").json()["used_by"] == ["pressed"]
    r = client.delete("/api/files/punch.stl")
    assert r.status_code == 409 and "tools.1.shape.path" in r.json()["detail"], r.text
    assert client.delete("/api/scenes/pressed").status_code == 204
    assert client.delete("/api/files/punch.stl").status_code == 204


def working_faces() -> trimesh.Trimesh:
    """The punch's nose and side, its top left open: a CAD export of the faces that work."""
    m = punch_mesh()
    return trimesh.Trimesh(m.vertices, m.faces[m.triangles_center[:, 2] < 0.0099])


def test_an_open_tool_surface_is_kept_and_runs_once_the_scene_says_open(env):
    """CAD gives a die's working faces, an open surface: the upload keeps it and says it is
    open (a refusal asked the scene to set open = true, which the file it refused could not
    be given); a scene reading it as closed is refused naming the tool, one with open = true
    presses as the closed punch does (the top is far from the plate)."""
    client, scenes = env
    r = upload(client, "faces.stl", stl(working_faces()), kind="tool")
    assert r.status_code == 201, r.text
    f = r.json()
    assert f["kind"] == "tool" and f["open"] is True and f["triangles"] == 144, f
    # listed as the tool it was uploaded as before a scene names it (by what it holds, an
    # open surface is a blank's: the tool field offered it as a "blank mesh")
    assert client.get("/api/files/faces.stl").json()["kind"] == "tool"
    # the file's own units (STL: float32): what the scene's scale makes metres
    np.testing.assert_allclose(f["extent"], [0.008, 0.008, 0.01], rtol=1e-6)
    assert upload(client, "closed.stl", stl(punch_mesh()), kind="tool").json()["open"] is False
    forces = {}
    for name, shape in (("closed", '{ kind = "mesh", path = "closed.stl" }'),
                        ("asclosed", '{ kind = "mesh", path = "faces.stl" }'),
                        ("faces", '{ kind = "mesh", path = "faces.stl", open = true }')):
        toml = PRESS_TOML.replace(PUNCH, f"shape = {shape}")
        assert client.put(f"/api/scenes/{name}", json={"toml": toml}).status_code == 200
        run = client.post("/api/runs", json={"scene": name})
        if name == "asclosed":
            assert run.status_code == 422, run.text
            assert run.json()["detail"].startswith("tools.1.shape.path: tool 'punch': "
                                                   "faces.stl: open: "), run.text
            continue
        st = wait_state(client, run.json()["id"], {"finished", "failed", "stopped"})
        assert st["state"] == "finished", st["reason"]
        steps = client.get(f"/api/runs/{run.json()['id']}/result").json()["steps"]
        forces[name] = steps[-1]["probes"]["punch_force"]
    # the same nose and side, sampled alike: the same force to the spline's smoothing, far
    # below 1e-6 of it (the plate's nodes touch the flat nose only)
    assert forces["closed"] > 100.0 and forces["faces"] == pytest.approx(forces["closed"],
                                                                          rel=1e-6), forces
    for name in ("closed", "asclosed", "faces"):
        assert client.delete(f"/api/scenes/{name}").status_code == 204
    for name in ("closed.stl", "faces.stl"):
        assert client.delete(f"/api/files/{name}").status_code == 204


@pytest.mark.parametrize("name,mesh,detail", [
    ("flipped.stl", trimesh.Trimesh(punch_mesh().vertices,
                                    np.vstack([punch_mesh().faces[:1, ::-1],
                                               punch_mesh().faces[1:]])),
     "flipped.stl: 3 edges between triangles wound opposite ways"),
    ("two.stl", trimesh.util.concatenate([punch_mesh(),
                                          punch_mesh().apply_translation([0.002, 0, 0])]),
     "two.stl: self-intersecting: "),
])
def test_a_bad_tool_surface_is_refused_naming_the_problem(env, name, mesh, detail):
    client, scenes = env
    r = upload(client, name, stl(mesh), kind="tool")
    assert r.status_code == 422 and detail in r.json()["detail"], r.text
    assert not (scenes / name).exists()


def test_a_run_with_a_bad_tool_surface_is_refused_naming_the_tool(env):
    """A file put in the folder by hand, or a scale that makes it absurd: 422 before a run
    starts, naming the field, the tool and the problem."""
    client, scenes = env
    (scenes / "hand.stl").write_bytes(stl(trimesh.Trimesh(punch_mesh().vertices,
                                                          punch_mesh().faces[3:])))
    (scenes / "fine.stl").write_bytes(stl(punch_mesh()))
    for shape, detail in (('{ kind = "mesh", path = "hand.stl" }', "hand.stl: open: "),
                          ('{ kind = "mesh", path = "fine.stl", scale = 1000.0 }',
                           "fine.stl: absurd size: ")):
        toml = PRESS_TOML.replace(PUNCH, f"shape = {shape}")
        assert client.put("/api/scenes/handmade", json={"toml": toml}).status_code == 200
        run = client.post("/api/runs", json={"scene": "handmade"})
        assert run.status_code == 422, run.text
        assert run.json()["detail"].startswith(f"tools.1.shape.path: tool 'punch': {detail}")
    assert client.delete("/api/scenes/handmade").status_code == 204


def test_the_listing_names_each_mesh_file_by_what_it_is(env):
    """A mesh file is a blank's or a tool's by its extension alone: the listing names it by
    the field a scene reads it as, else by what it holds (a closed surface is a tool's)."""
    client, scenes = env
    sheet = trimesh.creation.box([0.01, 0.01, 0.001])
    sheet = trimesh.Trimesh(sheet.vertices, sheet.faces[:2])  # one open square: a blank
    files = {"tool.stl": stl(punch_mesh()), "sheet.obj": sheet.export(file_type="obj"),
             "closed.obj": punch_mesh().export(file_type="obj")}
    for name, content in files.items():
        assert upload(client, name, content).status_code == 201  # as blanks: by extension
    kinds = {f["name"]: f["kind"] for f in client.get("/api/files").json()["files"]}
    assert {n: kinds[n] for n in files} == {"tool.stl": "tool", "sheet.obj": "blank",
                                            "closed.obj": "tool"}
    # the kind an upload asks for names it until a scene does; forgotten with the file
    assert upload(client, "sheet.obj", files["sheet.obj"], kind="tool", replace="true").json()[
        "kind"] == "tool"
    assert client.get("/api/files/sheet.obj").json()["kind"] == "tool"
    assert client.delete("/api/files/sheet.obj").status_code == 204
    assert upload(client, "sheet.obj", files["sheet.obj"]).json()["kind"] == "blank"
    # named by a scene as its blank (a closed mesh is a poor blank, but the scene says so)
    toml = PRESS_TOML.replace('[mesh]\nkind = "rectangle"', '[mesh]\nkind = "file"\n'
                              'path = "closed.obj"\n[unused]\nkind = "rectangle"')
    (scenes / "asblank.toml").write_text(toml)
    assert client.get("/api/files/closed.obj").json()["kind"] == "blank"
    (scenes / "asblank.toml").unlink()
    for name in files:
        assert client.delete(f"/api/files/{name}").status_code == 204


def test_the_form_offers_tool_files_for_a_mesh_shape():
    assert schema()["$defs"]["MeshShape"]["properties"]["path"]["x-file"] == "tool"


def test_the_display_of_a_tool_file_replaced_under_its_name_is_the_new_one(tmp_path,
                                                                          monkeypatch):
    """The solver's display meshes are cached by content: a punch.stl replaced by a narrower
    one shows the new punch, not the cached old one (their shape JSON is the same)."""
    from server.worker import tool_meshes
    from sim.scene.load import scene_from_toml

    monkeypatch.setenv("Q3T_CACHE", str(tmp_path / "cache"))
    toml = PRESS_TOML.replace(PUNCH, 'shape = { kind = "mesh", path = "punch.stl" }')
    cache: dict = {}

    def shown_radius(radius: float) -> float:
        mesh = trimesh.creation.cylinder(radius=radius, height=0.01, sections=48)
        (tmp_path / "punch.stl").write_bytes(stl(mesh.apply_translation([0, 0, 0.005])))
        tools = tool_meshes(scene_from_toml(toml, folder=tmp_path), 0.04, cache)
        V = next(t for t in tools if t["name"] == "punch")["vertices"]
        return float(np.max(np.hypot(V[:, 0], V[:, 1])))

    # the display surface is the smoothed field's zero level on a grid: within a grid cell
    # (0.5 mm spacing) of the file's radius, and the two radii are 1.5 mm apart
    assert shown_radius(0.004) == pytest.approx(0.004, abs=5e-4)
    assert shown_radius(0.0025) == pytest.approx(0.0025, abs=5e-4)
    assert len(cache) == 3  # the ground plane once, the punch for each of its files

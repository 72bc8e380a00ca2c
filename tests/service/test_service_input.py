"""Bad input to the service: every hostile request a 4xx naming the field and the reason,
nothing outside the scenes folder read or touched, no half-written file."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("fastapi")
from fastapi.testclient import TestClient  # noqa: E402

from tests.support.scenes import tiny_toml  # noqa: E402
from tests.support.service import (  # noqa: E402
    file_scene,
    nested,
    no_temp_files,
    outside_scenes,
    thickness_scene,
)


@pytest.mark.parametrize("method,url,body,status,words", [
    ("get", "/api/scenes/nope", None, 404, ["nope"]),
    ("post", "/api/runs", {"scene": "nope"}, 404, ["nope"]),
    ("put", "/api/scenes/bad", {"toml": "name = [1,"}, 422, ["TOML"]),
    ("put", "/api/scenes/bad", {"toml": "X".join([tiny_toml().replace("nu = 0.49", "nu = 0.7")])},
     422, ["material.nu", "less than 0.5"]),
    ("put", "/api/scenes/bad", {"toml": tiny_toml() + "\nbogus = 1\n"}, 422, ["bogus"]),
    ("put", "/api/scenes/bad", {"toml": "x", "extra": 1}, 422, ["extra"]),
    ("post", "/api/runs", {"scene": "tiny", "colour": "red"}, 422, ["colour"]),
    ("post", "/api/runs", {"scene": "tiny", "element": "nonesuch"}, 422, ["nonesuch", "q3t"]),
    ("post", "/api/runs", {"scene": "tiny", "element": ""}, 422, ["element", "at least 1"]),
    ("get", "/api/runs/x/frames/-1", None, 422, ["step", "greater than or equal to 0"]),
    ("post", "/api/runs", {"scene": "tiny", "overrides": {"material.E": -1}}, 422,
     ["material.E"]),
    ("post", "/api/runs", {"scene": "tiny", "parameters": {"load_scale": 1e6}}, 422,
     ["load_scale", "range"]),
    ("post", "/api/runs", {"scene": "tiny", "parameters": {"gravity": 1}}, 422, ["unknown"]),
    # names that routing passes to the handlers, which must refuse them before any file access
    ("get", "/api/scenes/%2e%2e", None, 422, ["scene name"]),
    ("get", "/api/scenes/..%5C..%5Csecret", None, 422, ["scene name"]),
    ("get", "/api/scenes/a..b", None, 422, ["scene name"]),
    ("get", "/api/scenes/secret%00", None, 422, ["scene name"]),
    ("get", "/api/scenes/tiny%0A", None, 422, ["scene name"]),
    ("get", "/api/scenes/.hidden", None, 422, ["scene name"]),
    ("put", "/api/scenes/%2e%2e%5Csecret", {"toml": tiny_toml()}, 422, ["scene name"]),
    ("put", "/api/scenes/..secret", {"toml": tiny_toml()}, 422, ["scene name"]),
    ("delete", "/api/scenes/%2e%2e%5Csecret", None, 422, ["scene name"]),
    ("delete", "/api/scenes/%2E%2E", None, 422, ["scene name"]),
    ("post", "/api/scenes/%2e%2e/duplicate", {"name": "x"}, 422, ["scene name"]),
    ("post", "/api/scenes", {"name": "../evil", "toml": tiny_toml()}, 422, ["scene name"]),
    ("post", "/api/scenes", {"name": "..\\secret", "toml": tiny_toml()}, 422, ["scene name"]),
    ("post", "/api/scenes/tiny/duplicate", {"name": "a/b"}, 422, ["scene name"]),
    ("post", "/api/scenes/tiny/duplicate", {"name": "..secret"}, 422, ["scene name"]),
    ("get", "/api/scenes/..%2F..%2Fetc%2Fpasswd", None, 404, []),  # routing: no such route
    # a scene's mesh file: only relative paths inside the scenes folder
    ("put", "/api/scenes/m", {"toml": file_scene("/etc/passwd")}, 422, ["mesh.path"]),
    ("put", "/api/scenes/m", {"toml": file_scene("../secret.obj")}, 422, ["mesh.path", ".."]),
    ("put", "/api/scenes/m", {"toml": file_scene("sub/../../secret.obj")}, 422, ["mesh.path"]),
    ("put", "/api/scenes/m", {"toml": file_scene("..\\secret.obj")}, 422, ["mesh.path"]),
    ("put", "/api/scenes/m", {"toml": file_scene("C:/secret.obj")}, 422, ["mesh.path"]),
    ("put", "/api/scenes/m", {"toml": file_scene("nothere.obj")}, 422, ["mesh.path", "no file"]),
    ("put", "/api/scenes/m", {"toml": file_scene("tiny.toml")}, 422, ["mesh.path", "not a file"]),
    ("put", "/api/scenes/m", {"toml": file_scene("out.obj")}, 422, ["mesh.path", "out of the"]),
    ("post", "/api/scenes/validate", {"toml": file_scene("/etc/hostname")}, 422, ["mesh.path"]),
    # a thickness file: the same rule
    ("put", "/api/scenes/m", {"toml": thickness_scene("/etc/passwd")}, 422,
     ["shell.thickness_file"]),
    ("put", "/api/scenes/m", {"toml": thickness_scene("../h.npy")}, 422,
     ["shell.thickness_file", ".."]),
    ("post", "/api/scenes/validate", {"toml": thickness_scene("h.npy")}, 422,
     ["shell.thickness_file", "no file"]),
    ("post", "/api/runs", {"scene": "tiny", "overrides": {"mesh.kind": "file",
                                                          "mesh.path": "/etc/hostname"}},
     422, ["mesh.path"]),
    ("get", "/api/runs/..secret", None, 422, ["run id"]),
    ("get", "/api/runs/%2e%2e", None, 422, ["run id"]),
    ("delete", "/api/runs/..%5Csecret", None, 422, ["run id"]),
    ("post", "/api/runs/nope-run/pause", None, 404, ["nope-run"]),
    # the run actions are routes of their own: an unknown one is no route, not a bad value
    ("post", "/api/runs/nope-run/explode", None, 404, []),
    ("put", "/api/runs/nope-run/parameters/load_scale", {"value": "abc"}, 422, ["value"]),
])
def test_bad_input(env, method, url, body, status, words):
    client, settings = env
    out = settings.scenes_dir / "out.obj"  # a link out of the scenes folder
    if not out.is_symlink():
        out.symlink_to(settings.scenes_dir.parent / "secret.obj")
    before, outside = sorted(settings.scenes_dir.iterdir()), outside_scenes(settings)
    kw = {"json": body} if body is not None else {}
    r = client.request(method.upper(), url, **kw)
    assert r.status_code == status, r.text
    for w in words:
        assert w in r.text, (w, r.text)
    assert sorted(settings.scenes_dir.iterdir()) == before  # nothing saved
    assert no_temp_files(settings.scenes_dir) == []
    assert outside_scenes(settings) == outside  # nothing outside touched
    assert client.get("/api/health").json()["ok"]  # alive


def test_chunked_oversize_body_is_413(env):
    """A body without Content-Length (chunked) is counted as it arrives."""
    client, settings = env
    before = sorted(settings.scenes_dir.iterdir())

    def chunks():
        yield b'{"toml": "'
        for _ in range(100):
            yield b"#" * 1000
        yield b'"}'

    r = client.put("/api/scenes/big", content=chunks(), headers={"Content-Type":
                                                                  "application/json"})
    assert r.status_code == 413 and "larger" in r.text, r.text
    assert sorted(settings.scenes_dir.iterdir()) == before
    small = client.put("/api/scenes/chunky", content=iter([b'{"toml": ', json.dumps(
        tiny_toml()).encode(), b"}"]), headers={"Content-Type": "application/json"})
    assert small.status_code == 200, small.text  # a small chunked body still gets through
    assert client.delete("/api/scenes/chunky").status_code == 204


def test_internal_errors_are_500_not_404(env, monkeypatch):
    """Only request problems are 4xx: a KeyError or ValueError from a bug is a 500."""
    client, _ = env
    raw = TestClient(client.app, raise_server_exceptions=False)  # the running app's state
    store = client.app.state.store
    for exc in (KeyError("internal"), ValueError("internal")):
        def broken(exc=exc):
            raise exc

        monkeypatch.setattr(store, "names", broken)
        r = raw.get("/api/scenes")
        assert r.status_code == 500, (exc, r.status_code, r.text)
    monkeypatch.undo()
    assert client.get("/api/scenes").status_code == 200


@pytest.mark.parametrize("method,url,body,words", [
    # TOML nested past Python's recursion limit (tomllib recurses once per level)
    ("post", "/api/scenes/validate", {"toml": "a = " + nested(5000)}, ["TOML", "nested"]),
    ("post", "/api/scenes", {"name": "deep", "toml": "a = " + nested(5000)}, ["nested"]),
    ("put", "/api/scenes/deep", {"toml": "a = " + nested(5000)}, ["nested"]),
    # nested less than that, but deeper than any scene: the walks after the parser overflow
    ("put", "/api/scenes/deep", {"toml": "a = " + nested(100)}, ["a.0.0", "nested"]),
    # a lone surrogate: valid JSON, no text (no UTF-8 for it, in a file or in the answer)
    ("post", "/api/scenes/validate", {"toml": 'description = "\ud800"'},
     ["body.toml", "surrogate"]),
    ("post", "/api/scenes/parse", {"toml": 'description = "\ud800"'},
     ["body.toml", "surrogate"]),
    ("post", "/api/scenes", {"name": "sur", "toml": tiny_toml() + '\n# "\ud800"'},
     ["body.toml", "surrogate"]),
    ("put", "/api/scenes/sur", {"toml": tiny_toml().replace("tiny", "\ud800")},
     ["body.toml", "surrogate"]),
    ("post", "/api/scenes/render", {"scene": {"\ud800": 1}}, ["body.scene", "a key"]),
    ("post", "/api/runs", {"scene": "tiny", "overrides": {"material.E": "\udfff"}},
     ["body.overrides.material.E", "surrogate"]),
])
def test_hostile_bodies_are_422_naming_where(env, method, url, body, words):
    client, settings = env
    before = sorted(settings.scenes_dir.iterdir())
    content = json.dumps(body).encode()  # ASCII: surrogates escaped, as any client sends them
    r = client.request(method.upper(), url, content=content,
                       headers={"Content-Type": "application/json"})
    assert r.status_code == 422, r.text
    for w in words:
        assert w in r.json()["detail"], (w, r.text)
    assert sorted(settings.scenes_dir.iterdir()) == before


@pytest.mark.parametrize("depth", [900, 5000])
def test_render_of_a_deeply_nested_scene_is_422(env, depth):
    """The form's JSON scene, nested past the recursion limit of any walk over it (900) and of
    the JSON parser itself (5000)."""
    client, _ = env
    body = '{"scene": {"description": ' + nested(depth) + "}}"
    r = client.post("/api/scenes/render", content=body,
                    headers={"Content-Type": "application/json"})
    assert r.status_code == 422, r.text
    assert "nested deeper than 32 levels" in r.json()["detail"]


def test_scene_errors_name_the_field_without_pydantic_noise(env):
    client, _ = env
    r = client.post("/api/runs", json={"scene": "tiny", "overrides": {"": 1}})
    assert r.status_code == 422 and r.json()["detail"].startswith('"": an override key'), r.text
    r = client.post("/api/runs", json={"scene": "tiny", "element": "nonesuch"})
    assert r.json()["detail"].startswith("shell.element: unknown 'nonesuch'"), r.text
    r = client.post("/api/scenes/validate", json={"toml": '"" = 1\n' + tiny_toml()})
    assert r.json()["detail"] == '"": Extra inputs are not permitted', r.text
    # a TOML date (no field takes one; the scene is validated as JSON, which has none): named
    dated = tiny_toml().replace("[material]", "[material]\nmade = 1979-05-27", 1)
    assert dated != tiny_toml()
    for method, url, body in [("post", "/api/scenes/validate", {"toml": dated}),
                              ("post", "/api/runs", {"scene": "tiny", "toml": dated}),
                              ("post", "/api/scenes/validate",
                               {"toml": "when = 07:32:00\n" + tiny_toml()})]:
        r = client.request(method.upper(), url, json=body)
        assert r.status_code == 422, r.text
        assert r.json()["detail"].split(":")[0] in ("material.made", "when"), r.text
        assert "a TOML date or time" in r.json()["detail"], r.text
    # the scene's own name names a CLI run's folder: no path, no control character
    for name in ("../x", "a/b", "a\\b", ".hidden", "a\u0000b", "x" * 101, ""):
        r = client.post("/api/runs", json={"scene": "tiny", "overrides": {"name": name}})
        assert r.status_code == 422, (name, r.text)
        assert r.json()["detail"].startswith("name: it names the runs' folders"), r.text
    named = tiny_toml().replace('name = "tiny"', 'name = "my cup 2"', 1)
    assert named != tiny_toml()
    assert client.post("/api/scenes/validate", json={"toml": named}).status_code == 200


def test_a_list_of_integers_overrides_as_integers(env):
    """An override's list of integers (a section's steps) stays integers: it went through
    list[float] and the scene then refused 0.0 and 2.0 as no integers (the command line's
    --set took it)."""
    from tests.support.scenes import tiny_cup_toml
    from tests.support.service import wait_state

    client, settings = env
    (settings.scenes_dir / "tiny_cup.toml").write_text(tiny_cup_toml(2))
    r = client.post("/api/runs", json={"scene": "tiny_cup", "paused": True,
                                       "overrides": {"sections.0.steps": [0, 2]}})
    assert r.status_code == 201, r.text
    run = r.json()["id"]
    assert client.get(f"/api/runs/{run}").json()["overrides"]["sections.0.steps"] == [0, 2]
    client.post(f"/api/runs/{run}/stop")
    wait_state(client, run, {"stopped", "finished", "failed"})
    r = client.post("/api/runs", json={"scene": "tiny_cup", "overrides": {
        "sections.0.steps": [0, 2.5]}})
    assert r.status_code == 422 and r.json()["detail"].startswith("sections.0.steps.1"), r.text


def test_a_folder_or_a_link_out_of_the_scenes_folder_is_no_scene(env, tmp_path):
    """What a hand put in the scenes folder: a folder named like a scene broke both listings
    (404 "no scene 'dir'" for the whole list); a link to a file outside was read and sent
    whole. Neither is a scene or a file of the service; the rest is listed."""
    client, settings = env
    secret = tmp_path / "secret.toml"
    secret.write_text(tiny_toml().replace('name = "tiny"', 'name = "secret"'))
    (settings.scenes_dir / "dir.toml").mkdir()
    (settings.scenes_dir / "link.toml").symlink_to(secret)
    (settings.scenes_dir / "link.csv").symlink_to(secret)
    try:
        r = client.get("/api/scenes")
        assert r.status_code == 200, r.text
        names = [s["name"] for s in r.json()]
        assert "tiny" in names and "dir" not in names and "link" not in names, names
        r = client.get("/api/files")
        assert r.status_code == 200, r.text
        assert "link.csv" not in [f["name"] for f in r.json()["files"]]
        for url in ("/api/scenes/link", "/api/scenes/dir", "/api/files/link.csv"):
            r = client.get(url)
            assert r.status_code == 404 and "secret" not in r.text, (url, r.text)
    finally:
        (settings.scenes_dir / "dir.toml").rmdir()
        (settings.scenes_dir / "link.toml").unlink()
        (settings.scenes_dir / "link.csv").unlink()


def test_forming_limits_say_why_a_run_has_none(env):
    """A run whose build failed has no forming limits because it never stepped (the answer
    said its material was not plastic, of a plastic cup); an elastic run's says that."""
    from tests.support.scenes import tiny_cup_toml
    from tests.support.service import wait_state

    client, settings = env
    (settings.scenes_dir / "tiny_cup.toml").write_text(tiny_cup_toml(2))
    # 20 mm thick: valid as read, refused by the build (the punch's nose inside the sheet)
    run = client.post("/api/runs", json={"scene": "tiny_cup", "overrides": {
        "shell.thickness": 0.02}}).json()["id"]
    st = wait_state(client, run, {"stopped", "finished", "failed"})
    assert st["state"] == "failed", st
    r = client.get(f"/api/runs/{run}/forming_limits")
    assert r.status_code == 404, r.text
    assert r.json()["detail"].startswith(f"run {run!r} has no forming limits: it ended before "
                                         "its first step (build failed: "), r.text
    elastic = client.post("/api/runs", json={"scene": "tiny"}).json()["id"]
    assert wait_state(client, elastic, {"stopped", "finished", "failed"})["state"] == "finished"
    r = client.get(f"/api/runs/{elastic}/forming_limits")
    assert r.status_code == 404 and r.json()["detail"] == (
        f"run {elastic!r} has no forming limits (its material is not plastic)"), r.text

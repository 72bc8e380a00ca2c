"""/api/files: blank meshes and thickness files uploaded into the scenes folder, listed, used
by a scene that runs, deleted; every refusal (413, 422 naming the problem, 409), and never a
half-written or temporary file left, whether the upload is refused, too large or cut off.

The streaming cases talk ASGI to the app directly: a body that never ends, or a client that
goes away after a few chunks, is a receive() the test writes."""

from __future__ import annotations

import asyncio
import io

import numpy as np
import pytest

pytest.importorskip("fastapi")
import trimesh  # noqa: E402
from fastapi.testclient import TestClient  # noqa: E402

from server.app import create_app  # noqa: E402
from server.files import UPLOADED  # noqa: E402
from server.settings import Settings  # noqa: E402
from server.store import SceneStore  # noqa: E402
from sim.geometry.trimesh import rectangle  # noqa: E402
from tests.support.scenes import tiny_toml  # noqa: E402
from tests.support.service import HANG, file_scene, wait_ready, wait_state  # noqa: E402

LIMIT = 100_000  # bytes: the tiny plate is 3-4 kB in any format
PLATE = rectangle((0.7, 0.07), 0.035)  # tiny's own mesh: 63 vertices, 80 triangles


def mesh_bytes(kind: str, V=PLATE.vertices, F=PLATE.faces) -> bytes:
    out = trimesh.Trimesh(V, F, process=False).export(file_type=kind)
    return out.encode() if isinstance(out, str) else out  # OBJ and ASCII formats are text


def npy(values) -> bytes:
    out = io.BytesIO()
    np.save(out, np.asarray(values))
    return out.getvalue()


def left_behind(scenes) -> list:
    """Temporary files or folders in the scenes folder (hidden names; not the uploads' kinds,
    server.files.UPLOADED, which stays)."""
    return [p.name for p in scenes.iterdir() if p.name.startswith(".") and p.name != UPLOADED]


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("files")
    scenes = tmp / "scenes"
    scenes.mkdir()
    (scenes / "tiny.toml").write_text(tiny_toml())
    settings = Settings(scenes_dir=scenes, runs_dir=tmp / "runs", viewer=False,
                        max_body=64_000, max_upload=LIMIT, ack_timeout=HANG)
    with TestClient(create_app(settings)) as client:
        wait_ready(client)
        yield client, scenes


def upload(client, name, content, **params):
    return client.post("/api/files", params={"name": name, **params}, content=content)


@pytest.mark.parametrize("name,content,counts", [
    ("plate.obj", mesh_bytes("obj"), {"vertices": 63, "triangles": 80}),
    ("plate.ply", mesh_bytes("ply"), {"vertices": 63, "triangles": 80}),
    # STL keeps each triangle's corners apart: merged on reading, as the solver does
    ("plate.stl", mesh_bytes("stl"), {"vertices": 63, "triangles": 80}),
    ("h.txt", b"0.007\n" * 63, {"values": 63}),
    ("h.csv", b",".join([b"0.007"] * 63), {"values": 63}),
    ("h.npy", npy(np.full(63, 7e-3)), {"values": 63}),
])
def test_each_format_is_kept_listed_and_deletable(env, name, content, counts):
    client, scenes = env
    r = upload(client, name, content)
    assert r.status_code == 201, r.text
    assert r.headers["location"] == f"/api/files/{name}"
    entry = r.json()
    kind = "blank" if name.startswith("plate") else "thickness"
    assert entry["kind"] == kind and entry["size"] == len(content)
    assert {k: entry[k] for k in counts} == counts and entry["problem"] is None
    assert (scenes / name).read_bytes() == content
    listed = client.get("/api/files").json()
    assert listed["max_upload"] == LIMIT and ".stl" in listed["kinds"]["blank"]
    assert entry in listed["files"]
    assert client.get(f"/api/files/{name}").json() == entry
    assert client.delete(f"/api/files/{name}").status_code == 204
    assert not (scenes / name).exists() and client.get(f"/api/files/{name}").status_code == 404
    assert client.delete(f"/api/files/{name}").status_code == 404
    assert left_behind(scenes) == []


def test_a_scene_runs_on_an_uploaded_blank_and_thickness(env):
    """The blank and a thickness graded along x, uploaded, named by a scene that validates and
    runs; the files cannot be deleted while the scene names them."""
    client, scenes = env
    h = 0.007 * (1 - 0.3 * PLATE.vertices[:, 0] / 0.7)  # 7 mm at the clamp, 4.9 at the tip
    assert upload(client, "blank.obj", mesh_bytes("obj")).status_code == 201
    assert upload(client, "graded.npy", npy(h)).status_code == 201
    toml = file_scene("blank.obj").replace("thickness = 0.007", "thickness_file = 'graded.npy'")
    r = client.put("/api/scenes/uploaded", json={"toml": toml})
    assert r.status_code == 200, r.text
    assert r.json()["scene"]["mesh"]["path"] == "blank.obj"
    run = client.post("/api/runs", json={"scene": "uploaded", "element": "linear"})
    assert run.status_code == 201, run.text
    st = wait_state(client, run.json()["id"], {"finished", "failed", "stopped"})
    assert st["state"] == "finished", st["reason"]
    built = client.get(f"/api/runs/{run.json()['id']}/result").json()["built"]
    assert built["mesh"]["file"] == "blank.obj" and built["mesh"]["vertices"] == 63
    for name, field in (("blank.obj", "mesh.path"), ("graded.npy", "shell.thickness_file")):
        assert client.get(f"/api/files/{name}").json()["used_by"] == ["uploaded"]
        r = client.delete(f"/api/files/{name}")
        assert r.status_code == 409 and "uploaded" in r.json()["detail"], r.text
        assert field in r.json()["detail"] and (scenes / name).is_file()
    assert client.delete("/api/scenes/uploaded").status_code == 204
    assert client.delete("/api/files/blank.obj").status_code == 204
    assert client.delete("/api/files/graded.npy").status_code == 204


def flat() -> bytes:
    V = PLATE.vertices.copy()
    a, b, c = PLATE.faces[7]
    V[c] = (V[a] + V[b]) / 2
    return mesh_bytes("obj", V)


def fin() -> bytes:
    a, b = 10, 11  # an edge inside the plate (two triangles): a third stands on it
    V = np.vstack([PLATE.vertices, (PLATE.vertices[a] + PLATE.vertices[b]) / 2 + [0, 0, .02]])
    assert sum(set(f) >= {a, b} for f in PLATE.faces.tolist()) == 2
    return mesh_bytes("obj", V, np.vstack([PLATE.faces, [a, b, len(V) - 1]]))


def flipped() -> bytes:
    F = PLATE.faces.copy()
    F[12] = F[12, ::-1]
    return mesh_bytes("obj", PLATE.vertices, F)


@pytest.mark.parametrize("name,content,params,detail", [
    ("junk.obj", b"not a mesh at all\n", {}, "junk.obj: no triangles"),
    ("junk.stl", b"solid x\nfacet oops\n", {}, "junk.stl: "),
    ("flat.obj", flat(), {}, "flat.obj: 2 zero-area (degenerate) triangles"),
    ("fin.obj", fin(), {}, "fin.obj: 1 non-manifold edges"),
    ("flip.obj", flipped(), {}, "edges between triangles wound opposite ways"),
    ("neg.txt", b"0.007\n-0.001\n", {}, "neg.txt: 1 values are no thickness"),
    ("words.csv", b"thick,thin\n", {}, "words.csv is not an array of numbers"),
    ("../up.obj", mesh_bytes("obj"), {}, "query.name: file name '../up.obj'"),
    ("sub/x.obj", mesh_bytes("obj"), {}, "query.name: file name 'sub/x.obj'"),
    (".hidden.obj", mesh_bytes("obj"), {}, "query.name: file name '.hidden.obj'"),
    ("tiny.toml", tiny_toml().encode(), {}, "unknown extension '.toml'"),
    ("plate.step", b"ISO-10303-21;", {}, "unknown extension '.step'"),
    ("plate.STL", mesh_bytes("stl"), {}, "unknown extension '.STL'"),
    ("plate.obj", mesh_bytes("obj"), {"kind": "thickness"}, "is a blank file by its extension"),
    ("tool.obj", mesh_bytes("obj"), {"kind": "sheet"}, "query.kind: Input should be 'blank', "),
])
def test_what_cannot_be_used_is_refused_and_not_kept(env, name, content, params, detail):
    client, scenes = env
    before = sorted(p.name for p in scenes.iterdir())
    r = upload(client, name, content, **params)
    assert r.status_code == 422, r.text
    assert detail in r.json()["detail"], r.json()["detail"]
    assert sorted(p.name for p in scenes.iterdir()) == before  # nothing kept, nothing left
    assert (scenes / "tiny.toml").read_text() == tiny_toml()
    assert not (scenes.parent / "up.obj").exists()


def test_a_name_taken_is_a_conflict_unless_replacing_is_asked_for(env):
    client, scenes = env
    assert upload(client, "same.obj", mesh_bytes("obj")).status_code == 201
    r = upload(client, "same.obj", mesh_bytes("ply"))
    assert r.status_code == 409 and "replace=true" in r.json()["detail"], r.text
    assert (scenes / "same.obj").read_bytes() == mesh_bytes("obj")
    r = upload(client, "same.obj", flat(), replace=True)  # a bad file replaces nothing
    assert r.status_code == 422 and (scenes / "same.obj").read_bytes() == mesh_bytes("obj")
    half = rectangle((0.35, 0.07), 0.035)
    r = upload(client, "same.obj", mesh_bytes("obj", half.vertices, half.faces), replace=True)
    assert r.status_code == 200 and r.json()["triangles"] == len(half.faces), r.text
    assert client.delete("/api/files/same.obj").status_code == 204
    assert left_behind(scenes) == []


def test_past_the_limit_is_413_declared_or_not(env):
    client, scenes = env
    big = b"v 0 0 0\n" * (LIMIT // 8 + 1)
    r = upload(client, "big.obj", big)  # Content-Length says so: refused unread
    assert r.status_code == 413 and f"{LIMIT} bytes" in r.json()["detail"], r.text

    def chunked():  # no Content-Length: counted as it arrives
        for i in range(0, len(big), 8192):
            yield big[i:i + 8192]

    r = client.post("/api/files", params={"name": "big.obj"}, content=chunked())
    assert r.status_code == 413 and f"{LIMIT} bytes" in r.json()["detail"], r.text
    assert not (scenes / "big.obj").exists() and left_behind(scenes) == []


def test_a_hand_put_file_that_cannot_be_used_is_listed_with_its_problem(env):
    client, scenes = env
    (scenes / "by-hand.obj").write_text("v 0 0 0\n")
    entry = next(f for f in client.get("/api/files").json()["files"]
                 if f["name"] == "by-hand.obj")
    assert entry["problem"].startswith("by-hand.obj: no triangles: not a .obj mesh file")
    assert entry["triangles"] is None
    (scenes / "by-hand.obj").unlink()


# ---- the body as it streams: ASGI straight to the app, no solver needed -----------------------
@pytest.fixture
def bare(tmp_path):
    """The app without its lifespan (no solver process): the files routes need only the scene
    store. Its body deadline is a second, for a body that never comes."""
    scenes = tmp_path / "scenes"
    settings = Settings(scenes_dir=scenes, runs_dir=tmp_path / "runs", viewer=False,
                        max_upload=LIMIT, body_timeout=1.0)
    app = create_app(settings)
    app.state.store = SceneStore(scenes)
    return app, scenes


def post(app, name: str, receive) -> tuple[int, dict]:
    """POST /api/files?name=NAME with ``receive`` as the client; the status and the answer."""
    import json

    scope = {"type": "http", "asgi": {"version": "3.0"}, "http_version": "1.1",
             "method": "POST", "scheme": "http", "path": "/api/files", "raw_path": b"/api/files",
             "root_path": "", "query_string": f"name={name}".encode(), "server": ("t", 80),
             "client": ("t", 1), "headers": [(b"content-type", b"application/octet-stream")]}
    sent = []

    async def send(message):
        sent.append(message)

    asyncio.run(app(scope, receive, send))
    body = b"".join(m.get("body", b"") for m in sent if m["type"] == "http.response.body")
    return sent[0]["status"], json.loads(body) if body else {}


def test_an_endless_body_is_refused_once_past_the_limit(bare):
    """The limit is counted as the body arrives: an upload that would never end is a 413 a
    chunk past the limit, never read to its end (or into memory)."""
    app, scenes = bare
    chunk = b"v 0 0 0\n" * 1024
    pulled = 0

    async def receive():
        nonlocal pulled
        pulled += 1
        return {"type": "http.request", "body": chunk, "more_body": True}

    status, answer = post(app, "endless.obj", receive)
    assert status == 413 and f"{LIMIT} bytes" in answer["detail"], answer
    assert pulled == LIMIT // len(chunk) + 1
    assert sorted(p.name for p in scenes.iterdir()) == []


def test_an_upload_cut_off_leaves_nothing(bare):
    """A client gone mid-upload: the part received was on disk, in a hidden folder, and goes
    with it; no file of the name appears."""
    app, scenes = bare
    content = mesh_bytes("obj")
    parts = [content[:1000], content[1000:2000]]
    spooled = []

    async def receive():
        if parts:
            return {"type": "http.request", "body": parts.pop(0), "more_body": True}
        spooled.extend(p.name for p in scenes.iterdir())  # the upload so far, on disk
        return {"type": "http.disconnect"}

    post(app, "cut.obj", receive)
    assert len(spooled) == 1 and spooled[0].startswith(".upload-"), spooled
    assert sorted(p.name for p in scenes.iterdir()) == []


def test_a_body_that_stops_coming_is_408_and_leaves_nothing(bare):
    app, scenes = bare
    parts = [b"v 0 0 0\n"]

    async def receive():
        if parts:
            return {"type": "http.request", "body": parts.pop(0), "more_body": True}
        await asyncio.Event().wait()  # never: the client holds the connection and sends no more

    status, answer = post(app, "stalled.obj", receive)
    assert status == 408 and "within 1 s" in answer["detail"], answer
    assert sorted(p.name for p in scenes.iterdir()) == []


def test_a_whole_body_is_kept_under_its_name_alone(bare):
    app, scenes = bare
    content = mesh_bytes("obj")
    done = []

    async def receive():
        done.append(True)
        return {"type": "http.request", "body": content, "more_body": False}

    status, answer = post(app, "fine.obj", receive)
    assert status == 201 and answer["triangles"] == 80, answer
    assert sorted(p.name for p in scenes.iterdir()) == ["fine.obj"]


def test_q3t_serve_sets_the_upload_limit():
    import argparse

    from server.cli import add_parser, serve_settings

    ap = argparse.ArgumentParser()
    add_parser(ap.add_subparsers(dest="cmd"))
    assert serve_settings(ap.parse_args(["serve"]), None).max_upload == 64 * 2**20
    assert serve_settings(ap.parse_args(["serve", "--max-upload", "0.5"]), None).max_upload \
        == 2**19
    for bad in ("0", "-1", "inf", "nan"):
        with pytest.raises(SystemExit, match="--max-upload must be a positive size"):
            serve_settings(ap.parse_args(["serve", "--max-upload", bad]), None)

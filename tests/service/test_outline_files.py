"""Outline drawings (SVG, DXF) uploaded for mesh kind outline: kept once they read as an
outline, refused naming the problem, named by a scene that validates, not deletable while a
scene names them."""

from __future__ import annotations

import pytest

pytest.importorskip("fastapi")

from tests.support.service import in_process  # noqa: E402

SVG = (b'<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 -100 100 100">'
       b'<path d="M 0 0 H 100 V -100 H 0 Z"/><circle cx="50" cy="-50" r="10"/></svg>')
OPEN = b'<svg xmlns="http://www.w3.org/2000/svg"><path d="M 0 0 L 100 0 L 100 100"/></svg>'
SCENE = """
name = "drawn"
[mesh]
kind = "outline"
path = "blank.svg"
scale = 0.001
edge_length = 0.02
[shell]
thickness = 0.001
[material]
E = 2e11
nu = 0.3
"""


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    with in_process(tmp_path_factory.mktemp("outline"), {}) as (client, _):
        yield client


def upload(client, name, content):
    return client.post("/api/files", params={"name": name}, content=content)


def test_an_outline_drawing_is_kept_and_used(client):
    r = upload(client, "blank.svg", SVG)
    assert r.status_code == 201, r.text
    entry = r.json()
    assert entry["kind"] == "outline" and entry["holes"] == 1 and entry["problem"] is None
    assert entry["extent"] == [100.0, 100.0]  # in its own units: the scene says mm
    assert entry["units"] is None  # a viewBox without a width in mm: the scene must say
    assert entry["centre"] == [50.0, 50.0]  # its origin a corner: mesh.centre moves it
    assert ".dxf" in client.get("/api/files").json()["kinds"]["outline"]
    r = client.put("/api/scenes/drawn", json={"toml": SCENE})
    assert r.status_code == 200, r.text
    assert client.get("/api/files/blank.svg").json()["used_by"] == ["drawn"]
    r = client.delete("/api/files/blank.svg")
    assert r.status_code == 409 and "mesh.path" in r.json()["detail"]
    assert client.delete("/api/scenes/drawn").status_code == 204
    assert client.delete("/api/files/blank.svg").status_code == 204


def test_a_drawing_that_says_its_units_needs_no_scale(client):
    """An SVG 100 mm wide over a viewBox 100 wide, uploaded and read by a scene without a
    scale: in mm, as the file says (the upload shows where it says so); a scene's scale,
    where it gives one, is what counts."""
    r = upload(client, "mm.svg", SVG.replace(b"viewBox", b'width="100mm" height="100mm" viewBox'))
    assert r.json()["units"] == {"scale": 0.001, "said": 'width="100mm" over a viewBox 100 wide'}
    own = SCENE.replace('name = "drawn"', 'name = "own"').replace(
        'path = "blank.svg"\nscale = 0.001', 'path = "mm.svg"')
    store = client.app.state.store  # as a run's start checks it: the model's size, read
    scene, _ = store.checked(own, {}, 2**34)
    assert scene.mesh.scale is None
    with pytest.raises(ValueError, match="mesh.scale: absurd size: the drawing is 100000 mm"):
        store.checked(own.replace('"mm.svg"', '"mm.svg"\nscale = 1.0'), {}, 2**34)
    assert client.delete("/api/files/mm.svg").status_code == 204


@pytest.mark.parametrize("name, content, words", [
    ("open.svg", OPEN, "an open path"),
    ("bad.dxf", b"0\nSECTION\n2\nNONSENSE", "not a readable drawing"),
])
def test_a_bad_drawing_is_refused_naming_the_problem(client, name, content, words):
    r = upload(client, name, content)
    assert r.status_code == 422 and words in r.text, r.text
    assert client.get(f"/api/files/{name}").status_code == 404


def test_the_form_offers_outline_drawings_for_an_outline_path():
    from server.sceneform import schema

    assert schema()["$defs"]["OutlineMesh"]["properties"]["path"]["x-file"] == "outline"


ROUND = SCENE.replace('name = "drawn"', 'name = "round"').replace(
    'path = "blank.svg"\nscale = 0.001', "circle = { radius = 0.1, segments = 90 }")


@pytest.mark.parametrize("circle, loc, words", [
    ("{ radius = -0.1 }", "mesh.circle.radius", "greater than 0 m"),
    ("{ radius = 0.1, segments = 14 }", "mesh.circle.segments", "greater than or equal to 15"),
    ("{ radius = 0.1, center = [0.0, 0.0, 0.0] }", "mesh.circle.center", "at most 2 items"),
])
def test_a_bad_circle_is_422_naming_its_field(client, circle, loc, words):
    """From a scene's TOML (save, validate), a run's overrides, and the form's render, whose
    error the form shows by the field it names."""
    bad = ROUND.replace("{ radius = 0.1, segments = 90 }", circle)
    for r in (client.put("/api/scenes/round", json={"toml": bad}),
              client.post("/api/scenes/validate", json={"toml": bad})):
        assert r.status_code == 422 and f"{loc}: " in r.text and words in r.text, r.text
    assert client.get("/api/scenes/round").status_code == 404  # nothing saved
    scene = client.post("/api/scenes/parse", json={"toml": ROUND}).json()["scene"]
    assert scene["mesh"]["circle"] == {"radius": 0.1, "center": [0.0, 0.0], "segments": 90}
    raw = client.post("/api/scenes/parse", json={"toml": bad}).json()["raw"]
    r = client.post("/api/scenes/render", json={"scene": raw}).json()
    assert not r["ok"] and loc in {e["loc"] for e in r["errors"]}, r["errors"]


def test_a_runs_override_of_the_circle_is_checked(client):
    assert client.put("/api/scenes/round", json={"toml": ROUND}).status_code == 200
    try:
        r = client.post("/api/runs", json={"scene": "round",
                                           "overrides": {"mesh.circle.radius": 0.0}})
        assert r.status_code == 422 and "mesh.circle.radius" in r.text, r.text
        r = client.post("/api/runs", json={"scene": "round",
                                           "overrides": {"mesh.circle.segments": 10}})
        assert r.status_code == 422 and "mesh.circle.segments" in r.text, r.text
    finally:
        assert client.delete("/api/scenes/round").status_code == 204


def test_the_form_shows_a_circles_fields_with_their_units():
    """mesh.circle is an optional table (the form's "unset" box) of a length, a point and a
    whole number: the form's number, tuple and integer widgets, lengths shown in mm."""
    from server.sceneform import schema

    defs = schema()["$defs"]
    field = defs["OutlineMesh"]["properties"]["circle"]
    assert {"type": "null"} in field["anyOf"] and field["default"] is None
    props = defs["CircleSpec"]["properties"]
    assert props["radius"]["unit"] == "m" and props["radius"]["type"] == "number"
    assert props["center"]["unit"] == "m" and len(props["center"]["prefixItems"]) == 2
    assert props["segments"] == {**props["segments"], "type": "integer", "minimum": 15,
                                 "maximum": 100000, "default": 360}

"""/docs and /openapi.json describe the scene: the routes that return a validated scene
(validate, read, save) return pydantic's Scene, so its fields are listed with their
descriptions and units (the same the form and the scene reference show)."""

from __future__ import annotations

import pytest

pytest.importorskip("fastapi")


def _ref(schema: dict) -> str | None:
    """The component a (possibly nullable) property refers to."""
    for s in (schema, *schema.get("anyOf", ())):
        if "$ref" in s:
            return s["$ref"].rpartition("/")[2]
    return None


def test_the_scene_routes_return_the_scene_model(env):
    client, _ = env
    api = client.get("/openapi.json").json()
    schemas = api["components"]["schemas"]
    assert _ref(schemas["Validated"]["properties"]["scene"]) == "Scene"
    assert _ref(schemas["SceneDocument"]["properties"]["scene"]) == "Scene"
    ok = api["paths"]["/api/scenes/validate"]["post"]["responses"]["200"]
    assert _ref(ok["content"]["application/json"]["schema"]) == "Validated"


@pytest.mark.parametrize(("model", "field", "words", "unit"), [
    ("ShellSpec", "thickness", "thickness", "m"),
    ("MaterialSpec", "E", "Young's modulus", "Pa"),
    ("MaterialSpec", "nu", "Poisson's ratio", "1"),
    ("MaterialSpec", "density", "mass density", "kg/m^3"),
])
def test_scene_fields_have_descriptions_and_units(env, model, field, words, unit):
    client, _ = env
    prop = client.get("/openapi.json").json()["components"]["schemas"][model]["properties"][field]
    assert words in prop["description"] and prop["unit"] == unit, prop


def test_a_validated_scene_reads_as_the_model_with_its_defaults(env):
    client, _ = env
    text = client.get("/api/scenes/tiny").json()["toml"]
    r = client.post("/api/scenes/validate", json={"toml": text})
    assert r.status_code == 200, r.text
    scene = r.json()["scene"]
    assert scene["name"] == "tiny" and scene["material"]["density"] == 1000.0  # a default
    assert client.get("/api/scenes/tiny").json()["scene"] == scene

"""Hostile values in a scene: every float is finite, magnitudes that would overflow the model are
refused, directions are not degenerate; each is a validation error naming its field, read from
a file (sim.scene.load.load_scene) and over the API (/api/scenes/validate and overrides of
POST /api/runs, whose JSON may carry NaN and Infinity tokens)."""

from __future__ import annotations

import json
import math
import os
import tomllib

import pytest

from sim.scene.load import SceneError, apply_override, load_scene
from tests.support import ROOT

CANTILEVER = ROOT / "scenes" / "cantilever.toml"
NAN, INF = math.nan, math.inf
DYNAMIC = {"stepping.kind": "dynamic", "stepping.dt": 0.01}

# (overrides on the cantilever, the field the error must name); the cantilever's load 0 is
# gravity, region 0 the clamp plane, bc 0 its clamp, probe 0 the tip displacement
CASES = {
    "dt 1e-300": ({**DYNAMIC, "stepping.dt": 1e-300}, "stepping.dt"),
    "dt inf": ({**DYNAMIC, "stepping.dt": INF}, "stepping.dt"),
    "load_ramp inf": ({**DYNAMIC, "stepping.load_ramp": INF}, "stepping.load_ramp"),
    "thickness 1e308": ({"shell.thickness": 1e308}, "shell.thickness"),
    "thickness inf": ({"shell.thickness": INF}, "shell.thickness"),
    "E 1e308": ({"material.E": 1e308}, "material.E"),
    "density 1e308": ({"material.density": 1e308}, "material.density"),
    "gravity nan": ({"loads.0.vector": [0.0, 0.0, NAN]}, "loads.0.vector"),
    "gravity -inf": ({"loads.0.vector": [0.0, 0.0, -INF]}, "loads.0.vector"),
    "gravity -1e308": ({"loads.0.vector": [0.0, 0.0, -1e308]}, "loads.0.vector"),
    "bc displacement nan": ({"bcs.0.displacement": [NAN, 0.0, 0.0]}, "bcs.0.displacement"),
    "plane normal nan": ({"regions.0.plane.normal": [NAN, 0.0, 0.0]},
                         "regions.0.plane.normal"),
    "plane normal zero": ({"regions.0.plane.normal": [0.0, 0.0, 0.0]},
                          "regions.0.plane.normal"),
    "plane tolerance inf": ({"regions.0.plane.tolerance": INF}, "regions.0.plane.tolerance"),
    "imperfection nan": ({"mesh.imperfection": NAN}, "mesh.imperfection"),
    "size inf": ({"mesh.size": [INF, 0.07]}, "mesh.size"),
    "edge_length inf": ({"mesh.edge_length": INF}, "mesh.edge_length"),
    "probe point nan": ({"probes.0.point": [NAN, 0.035, 0.0]}, "probes.0.point"),
}


def names_only(message: str, field: str) -> None:
    """Every error of ``message`` ("loc: msg; loc: msg") is about ``field``."""
    for part in message.split("; "):
        assert part.startswith(field), (field, message)


@pytest.mark.parametrize("case", CASES)
def test_load_scene_names_the_field(case):
    overrides, field = CASES[case]
    with pytest.raises(SceneError) as err:
        load_scene(CANTILEVER, overrides)
    names_only(str(err.value), field)


def test_the_shipped_scenes_are_inside_the_bounds():
    for path in sorted((ROOT / "scenes").glob("*.toml")):
        load_scene(path)


# ---- the same over the API ------------------------------------------------------------------
pytest.importorskip("fastapi")
from fastapi.testclient import TestClient  # noqa: E402

from server.app import create_app  # noqa: E402
from server.settings import Settings  # noqa: E402
from server.tomlout import dumps  # noqa: E402


def tiny_text() -> str:
    return CANTILEVER.read_text().replace("edge_length = 0.0046667", "edge_length = 0.035")


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("bounds")
    os.environ.setdefault("XDG_CONFIG_HOME", str(tmp / "config"))
    os.environ.setdefault("XDG_DATA_HOME", str(tmp / "data"))
    (tmp / "scenes").mkdir()
    (tmp / "scenes" / "tiny.toml").write_text(tiny_text())
    settings = Settings(scenes_dir=tmp / "scenes", runs_dir=tmp / "runs", viewer=False)
    with TestClient(create_app(settings)) as c:
        yield c


def post_json(client, url: str, body: dict):
    """JSON with NaN / Infinity tokens, as Python's json writes them (httpx refuses to)."""
    return client.post(url, content=json.dumps(body),
                       headers={"content-type": "application/json"})


@pytest.mark.parametrize("case", CASES)
def test_api_validate_names_the_field(client, case):
    overrides, field = CASES[case]
    raw = tomllib.loads(tiny_text())
    for k, v in overrides.items():
        apply_override(raw, k, v)
    r = client.post("/api/scenes/validate", json={"toml": dumps(raw)})
    assert r.status_code == 422, r.text
    names_only(r.json()["detail"], field)


@pytest.mark.parametrize("case", CASES)
def test_api_run_overrides_name_the_field(client, case):
    overrides, field = CASES[case]
    r = post_json(client, "/api/runs", {"scene": "tiny", "overrides": overrides})
    assert r.status_code == 422, r.text
    names_only(r.json()["detail"], field)
    assert client.get("/api/runs").json() == []  # nothing started
    assert client.get("/api/health").json()["ok"]

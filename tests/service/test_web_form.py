"""The page's scene form and the run estimate, through FastAPI's TestClient:

- ``POST /api/scenes/render`` (scene JSON -> TOML) and ``POST /api/scenes/parse`` (TOML -> scene
  JSON) with errors naming the field, never saving; the TOML emitter (and tomli_w when installed)
  round-trips every file in scenes/; every field of the scene schema has a form widget.
- ``estimate`` of a finished run from a synthetic ``q3t study`` report in a temporary runs root:
  exact level, nearest level, analytic reference, element not studied, no study.
"""

from __future__ import annotations

import json
import math
import os
import time
import tomllib
from pathlib import Path

import pytest

pytest.importorskip("fastapi")
from fastapi.testclient import TestClient  # noqa: E402

from server import sceneform  # noqa: E402
from server.app import create_app  # noqa: E402
from server.estimate import estimate  # noqa: E402
from server.settings import Settings  # noqa: E402
from server.tomlout import dumps, have_tomli_w, number  # noqa: E402
from sim.scene.load import Scene  # noqa: E402
from sim.scene.run import SolverSpec
from tests.support import ROOT  # noqa: E402
from tests.support.scenes import SCENES, tiny_toml  # noqa: E402
from tests.support.service import file_scene  # noqa: E402

pytestmark = pytest.mark.fast  # seconds: make test-fast runs it

EMITTERS = ["builtin"] + (["tomli_w"] if have_tomli_w() else [])


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("webform")
    os.environ.setdefault("XDG_CONFIG_HOME", str(tmp / "config"))
    scenes, runs = tmp / "scenes", tmp / "runs"
    scenes.mkdir()
    (scenes / "tiny.toml").write_text(tiny_toml())
    make_runs(runs)
    settings = Settings(scenes_dir=scenes, runs_dir=runs, viewer=False)
    with TestClient(create_app(settings)) as client:
        yield client, settings


# ---- TOML emitter -------------------------------------------------------------------------------
@pytest.mark.parametrize("emitter", EMITTERS)
@pytest.mark.parametrize("path", SCENES, ids=[p.stem for p in SCENES])
def test_every_scene_round_trips(path, emitter):
    """parse -> render -> parse gives the same validated Scene."""
    first = sceneform.parse(path.read_text())
    assert first["ok"], first["error"]
    rendered = sceneform.render(first["scene"], emitter=emitter)
    assert rendered["ok"] and rendered["errors"] == [], rendered["error"]
    again = sceneform.parse(rendered["toml"])
    assert again["ok"], (again["error"], rendered["toml"])
    assert Scene.model_validate(again["scene"]) == Scene.model_validate(first["scene"])
    assert again["scene"] == first["scene"]


def test_builtin_emitter_writes_tables_arrays_of_tables_and_inline_tables():
    data = {
        "name": 'quote " backslash \\ tab \t newline \n unicode é \x01',
        "n": 3, "flag": False, "big": 6.8e10, "small": 1.25e-7, "neg": -0.0046667,
        "whole": 1000.0, "arr": [0.5, 1, True], "empty": [], "nested": [[1, 2], [3]],
        "mesh": {"kind": "disk", "size": [0.7, 0.07], "skip": None},
        "material": {"E": 1e11, "hardening": {"law": "voce", "saturation": 2.9e8}},
        "regions": [{"name": "clamp", "plane": {"point": [0.0, 0.0, 0.0],
                                                "normal": [1.0, 0.0, 0.0]}},
                    {"name": "tip", "box": {"min": [0.69, -1.0, -1.0], "max": [1.0, 1.0, 1.0]},
                     "boundary": True}],
        "tools": [{"name": "die", "shape": {"kind": "die_ring", "inner_radius": 0.0177,
                                            "outer_radius": 0.045, "height": 0.02,
                                            "edge_radius": 0.005, "corner_radius": 0.001}}],
        "odd key": {"a.b": 1},
    }
    text = dumps(data)
    back = tomllib.loads(text)
    want = json.loads(json.dumps(data))
    del want["mesh"]["skip"]
    assert back == want
    assert "[[regions]]" in text and "[material]" in text
    assert 'plane = { point = [0.0, 0.0, 0.0], normal = [1.0, 0.0, 0.0] }' in text
    assert "hardening = { law" in text  # small: inline
    assert "[tools.shape]" in text  # too long for one line: a sub-table of the tool
    assert "big = 6.8e10" in text and "whole = 1000.0" in text


@pytest.mark.parametrize("x", [0.0, -0.0, 1.0, 0.1, 1 / 3, 6.8e10, 1.0275e8, 1e-4, 9.9e-5, 1e300,
                               5e-324, -2.5e-12, 123456.0, 1e6, 0.0046667])
def test_numbers_read_back_exactly(x):
    s = number(x)
    assert tomllib.loads(f"v = {s}")["v"] == x and ("." in s or "e" in s)
    assert math.copysign(1, tomllib.loads(f"v = {s}")["v"]) == math.copysign(1, x)


def test_null_in_an_array_is_named():
    r = sceneform.render({"name": "x", "mesh": {"kind": "disk", "r_outer": 1.0,
                                                 "edge_length": 0.1},
                          "shell": {"thickness": 0.01, "thickness_gradient": [0.0, None, 0.0]},
                          "material": {"E": 1e9, "nu": 0.3}}, emitter="builtin")
    assert not r["ok"] and r["toml"] is None
    assert {"loc": "shell.thickness_gradient.1", "msg": "Input should be a valid number"} \
        in r["errors"]


# ---- render / parse through the service ---------------------------------------------------------
def test_render_names_the_field_and_never_saves(env):
    client, settings = env
    scene = client.get("/api/scenes/tiny").json()["scene"]
    before = sorted(settings.scenes_dir.iterdir())
    bad = {**scene, "material": {**scene["material"], "nu": 0.7},
           "bcs": [{**scene["bcs"][0], "region": "nowhere"}]}
    r = client.post("/api/scenes/render", json={"scene": bad})
    assert r.status_code == 200, r.text
    body = r.json()
    assert not body["ok"] and body["scene"] is None
    assert {"loc": "material.nu", "msg": "Input should be less than 0.5"} in body["errors"]
    assert "material.nu: Input should be less than 0.5" in body["error"]
    assert "nu = 0.7" in body["toml"]  # the TOML view still shows what the form says
    good = client.post("/api/scenes/render", json={"scene": scene}).json()
    assert good["ok"] and good["errors"] == [] and good["error"] is None
    assert Scene.model_validate(tomllib.loads(good["toml"])) == Scene.model_validate(scene)
    assert sorted(settings.scenes_dir.iterdir()) == before
    # a scene-level check that names its field: the loc is that field
    r = client.post("/api/scenes/render", json={"scene": {**scene, "bcs": bad["bcs"]}}).json()
    assert r["errors"] == [{"loc": "bcs.0.region", "msg": "unknown region 'nowhere'"}]
    assert client.post("/api/scenes/render", json={"scene": []}).status_code == 422


def test_parse_gives_the_scene_or_the_raw_tables_and_errors(env):
    client, _ = env
    ok = client.post("/api/scenes/parse", json={"toml": tiny_toml()}).json()
    assert ok["ok"] and ok["scene"]["name"] == "tiny" and ok["errors"] == []
    # defaults filled in for the form
    assert ok["scene"]["solver"]["max_iterations"] == SolverSpec().max_iterations
    bad = client.post("/api/scenes/parse", json={"toml": "bogus = 1\n" + tiny_toml().replace(
        "nu = 0.49", "nu = 0.7")}).json()
    assert not bad["ok"] and bad["scene"] is None and bad["raw"]["material"]["nu"] == 0.7
    locs = {e["loc"]: e["msg"] for e in bad["errors"]}
    assert locs["material.nu"] == "Input should be less than 0.5"
    assert locs["bogus"] == "Extra inputs are not permitted"
    syntax = client.post("/api/scenes/parse", json={"toml": "name = [1,"}).json()
    assert not syntax["ok"] and syntax["raw"] is None and syntax["errors"][0]["loc"] == "toml"


def test_every_schema_field_has_a_form_widget(env):
    """The form (web/form.js) knows: $ref objects, anyOf with null (unset) and one branch,
    tables of several kinds (oneOf with a discriminator: a kind select), enums, booleans,
    numbers and integers (with bounds), strings, tuples (prefixItems) and lists (items). A new
    kind of field in the schema would fall back to a JSON text box."""
    client, _ = env
    schema = client.get("/api/scenes/schema").json()

    def resolve(s):
        while "$ref" in s:
            s = schema["$defs"][s["$ref"].split("/")[-1]]
        return s

    def check(s, where):
        s = resolve(s)
        if "anyOf" in s:
            branches = [b for b in s["anyOf"] if b.get("type") != "null"]
            assert len(branches) == 1, where
            return check(branches[0], where)
        if "oneOf" in s:
            assert s.get("discriminator", {}).get("propertyName") in ("kind", "law"), where
            for branch in s["oneOf"]:
                check(branch, f"{where}[{branch['$ref'].split('/')[-1]}]")
            return
        if "enum" in s or "const" in s:
            return
        t = s.get("type")
        assert t in ("boolean", "number", "integer", "string", "array", "object"), where
        if t == "array":
            for i, item in enumerate(s.get("prefixItems") or [s.get("items", {})]):
                check(item, f"{where}.{i}")
        for k, sub in (s.get("properties") or {}).items():
            check(sub, f"{where}.{k}")

    check(schema, "scene")
    js = (ROOT / "web" / "form.js").read_text()
    for word in ("prefixItems", "exclusiveMinimum", "exclusiveMaximum", "anyOf", "enum",
                 "unset", "showErrors"):
        assert word in js
    page = client.get("/").text
    assert "/static/form.js" in page and 'id="scene-form"' in page
    assert client.get("/static/form.js").status_code == 200


# ---- error estimate of a finished run -----------------------------------------------------------
REPORT_ROWS = [  # element, edge, dofs, error, time
    ("linear", 0.07, 120, 0.88, 0.01), ("linear", 0.035, 378, 0.69, 0.02),
    ("q3t", 0.07, 180, 0.35, 0.02), ("q3t", 0.035, 567, 0.049, 0.05),
]


def report(scene: str, analytic: dict | None = None, rows=REPORT_ROWS) -> dict:
    ref = -0.0007
    study = {"plan": {"scene": f"/somewhere/scenes/{scene}.toml", "probe": "tip",
                      "elements": sorted({r[0] for r in rows}), "levels": [0.07, 0.035],
                      "reference": ["quadratic", 0.0035], "notes": []},
             "reference": {"value": ref, "dofs": 147969, "status": "converged"},
             "rows": [{"element": el, "edge_length": h, "status": "converged", "elements": 10,
                       "dofs": n, "probe": ref * (1 - e), "error": e, "time": t,
                       "solve_time": t / 2, "iterations": 2} for el, h, n, e, t in rows]}
    if analytic:
        study["analytic"] = analytic
    return {"study": study, "overhead": None}


def result_json(scene: str, element: str) -> dict:
    return {"scene": scene, "element": element, "counts": {"dofs": 567}, "converged": True,
            "steps": [{"step": 1}, {"step": 2}],
            "timing": {"total": 2.5, "assembly": 1.0, "factorisation": 0.8, "solve": 0.2,
                       "line_search": 0.1, "newton_iterations": 17, "per_iteration": 0.1235}}


def fake_run(runs: Path, run_id: str, scene: str, element: str, edge: float | None,
             state: str = "finished", overrides: dict | None = None) -> None:
    d = runs / run_id
    d.mkdir(parents=True)
    text = tiny_toml().replace('name = "tiny"', f'name = "{scene}"')
    if edge is not None:
        text = text.replace("edge_length = 0.035", f"edge_length = {edge}")
    (d / "scene.toml").write_text(text)
    (d / "result.json").write_text(json.dumps(result_json(scene, element)))
    (d / "run.json").write_text(json.dumps({
        "id": run_id, "scene": scene, "element": element,
        "overrides": {"shell.element": element, **(overrides or {})},
        "created": time.time(), "state": state, "step": 2, "n_steps": 2}))


def make_runs(runs: Path) -> None:
    (runs / "study-tiny").mkdir(parents=True)
    (runs / "study-tiny" / "report.json").write_text(json.dumps(report("tiny")))
    (runs / "study-tiny" / "report.md").write_text(
        "# Refinement study: tiny\n\n2026-11-22, x86_64 with 2 cores, Python 3.11.2.\n")
    # another folder name, the plan names the scene; an analytic reference
    (runs / "study-fig8").mkdir()
    (runs / "study-fig8" / "report.json").write_text(json.dumps(
        report("beam", {"name": "Euler-Bernoulli", "value": -0.00075})))
    (runs / "study-fig7").mkdir()  # a factorisation report is not a refinement study
    (runs / "study-fig7" / "report.json").write_text(json.dumps(
        {"scene": "tiny", "factorisation": []}))
    fake_run(runs, "tiny-exact", "tiny", "q3t", 0.035)
    fake_run(runs, "tiny-near", "tiny", "q3t", 0.03, overrides={"material.nu": 0.3})
    fake_run(runs, "tiny-quadratic", "tiny", "quadratic", 0.035)
    fake_run(runs, "tiny-stopped", "tiny", "q3t", 0.035, state="stopped")
    fake_run(runs, "beam-linear", "beam", "linear", 0.07)
    fake_run(runs, "plate-q3t", "plate", "q3t", 0.035)


def test_estimate_at_the_studied_level(env):
    client, _ = env
    st = client.get("/api/runs/tiny-exact").json()
    est = st["estimate"]
    assert est["available"] and est["match"] == "exact"
    assert est["relative_error"] == pytest.approx(0.049)
    assert est["reference"]["kind"] == "numerical" and est["reference"]["element"] == "quadratic"
    assert est["study"]["date"] == "2026-11-22" and est["study"]["probe"] == "tip"
    assert est["row"]["dofs"] == 567
    assert est["cost"] == {"wall_s": 2.5, "newton_iterations": 17, "per_iteration_s": 0.1235,
                           "dofs": 567, "steps": 2}
    assert est["text"] == ("error estimate: 4.9 % vs quadratic at 3.5 mm (study of 2026-11-22); "
                           "cost 2.5 s, 17 Newton iterations (0.12 s per iteration)")
    assert est["notes"] == []
    res = client.get("/api/runs/tiny-exact/result").json()
    assert res["timing"]["newton_iterations"] == 17 and res["estimate"] == est


def test_estimate_at_the_nearest_level_says_so(env):
    client, _ = env
    est = client.get("/api/runs/tiny-near").json()["estimate"]
    assert est["available"] and est["match"] == "nearest"
    assert est["row"]["edge_length"] == 0.035 and est["edge_length"] == 0.03
    assert "nearest studied level 35 mm" in est["text"]
    assert any("nearest studied level: 35 mm (the run used 30 mm)" in n for n in est["notes"])
    assert "the study ran the scene as saved; this run ran the scene with material.nu = 0.3" \
        in est["notes"]


def test_estimate_against_an_analytic_reference(env):
    client, _ = env
    est = client.get("/api/runs/beam-linear").json()["estimate"]
    assert est["available"] and est["reference"]["kind"] == "analytic"
    p = -0.0007 * (1 - 0.88)
    assert est["relative_error"] == pytest.approx(abs(p + 0.00075) / 0.00075)
    assert "vs Euler-Bernoulli (analytic)" in est["text"]
    assert est["study"]["path"].endswith("study-fig8/report.json")


def test_no_estimate_without_a_study_or_rows(env):
    client, _ = env
    est = client.get("/api/runs/plate-q3t").json()["estimate"]
    assert not est["available"] and est["reason"] == "no_study"
    assert est["text"] == ("no study for this scene: run `q3t study plate`; cost 2.5 s, 17 Newton "
                           "iterations (0.12 s per iteration)")
    est = client.get("/api/runs/tiny-quadratic").json()["estimate"]
    assert not est["available"] and est["reason"] == "element_not_studied"
    assert "--elements quadratic" in est["text"]
    assert client.get("/api/runs/tiny-stopped").json()["estimate"] is None


def test_estimate_follows_a_new_study_report(env, tmp_path):
    client, settings = env
    path = settings.runs_dir / "study-plate" / "report.json"
    path.parent.mkdir()
    try:
        path.write_text(json.dumps(report("plate")))
        est = client.get("/api/runs/plate-q3t").json()["estimate"]
        assert est["available"] and est["relative_error"] == pytest.approx(0.049)
    finally:
        path.unlink()
        path.parent.rmdir()
    assert not client.get("/api/runs/plate-q3t").json()["estimate"]["available"]


def test_estimate_function_edge_cases(tmp_path):
    (tmp_path / "study-s").mkdir()
    (tmp_path / "study-s" / "report.json").write_text(json.dumps(report(
        "s", rows=[("q3t", 0.01, 10, 0.1, 0.1)])))
    est = estimate(tmp_path, "s", "q3t", None, None)
    assert not est["available"] and est["reason"] == "no_edge_length"
    assert est["cost"] is None and "cost" not in est["text"]
    est = estimate(tmp_path, "s", "q3t", 0.01, result_json("s", "q3t"), [])
    assert est["available"] and est["notes"] == []
    (tmp_path / "study-s" / "report.json").write_text("{ not json")
    assert estimate(tmp_path, "s", "q3t", 0.01, None)["reason"] == "no_study"


@pytest.mark.parametrize("scene,from_file,command", [
    ("cantilever", False, "q3t study {scene}"),
    # the shell obstacle course's scenes: `q3t study SCENE` refuses their meshes (by cells)
    ("scordelis_lo", False, "q3t study --course"),
    ("pinched_cylinder", False, "q3t study --course"),
    ("pinched_hemisphere", False, "q3t study --course"),
    ("twisted_beam_inplane", False, "q3t study --course"),  # a strip, refined along it
    ("cantilever", True, None),  # its blank read from a mesh file: nothing to refine
])
def test_the_estimate_names_the_command_that_studies_the_scene(tmp_path, scene, from_file,
                                                               command):
    from server.estimate import study_command
    from sim.scene.load import scene_from_toml

    text = (ROOT / "scenes" / f"{scene}.toml").read_text()
    if from_file:
        (tmp_path / "plate.obj").write_text("v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nf 1 2 3\n")
        text = file_scene("plate.obj")
    sc = scene_from_toml(text, folder=tmp_path)
    assert study_command(sc) == command
    est = estimate(tmp_path, scene, "q3t", None, None, command=command)
    assert not est["available"] and est["reason"] == "no_study"
    if command is None:
        assert "`" not in est["text"] and "no study refines its mesh" in est["text"]
    elif command.endswith("--course"):
        assert est["text"].startswith("no study for this scene: run `q3t study --course` (")
    else:
        assert est["text"] == "no study for this scene: run `q3t study cantilever`"


def test_a_course_scene_is_estimated_from_the_shell_course_report(tmp_path):
    """A course scene's run against the published value, from the row of its element and
    cells per side in the newest ``q3t study --course`` report; a refinement study found under
    its name is not used (its levels are edge lengths, the scene's cells per side)."""
    (tmp_path / "study-scordelis_lo").mkdir()
    (tmp_path / "study-scordelis_lo" / "report.json").write_text(json.dumps(report(
        "scordelis_lo")))
    (tmp_path / "course").mkdir()
    rows = [{"scene": "scordelis_lo", "element": "q3t", "cells": 16, "status": "converged",
             "probe": 0.98 * -0.3024, "ratio": 0.98},
            {"scene": "scordelis_lo", "element": "quadratic", "cells": 64, "status": "skipped"},
            {"scene": "pinched_cylinder", "element": "q3t", "cells": 16, "ratio": 0.5}]
    (tmp_path / "course" / "report.json").write_text(json.dumps(rows))
    course = {"command": "q3t study --course"}
    est = estimate(tmp_path, "scordelis_lo", "q3t", None, None, **course, cells=16)
    assert est["available"] and est["relative_error"] == pytest.approx(0.02, rel=1e-12)
    assert est["reference"]["value"] == pytest.approx(-0.3024, rel=1e-12)
    assert est["text"].startswith("error estimate: 2 % vs the published value (shell obstacle "
                                  "course of ")
    est = estimate(tmp_path, "scordelis_lo", "linear", None, None, **course, cells=16)
    assert not est["available"] and est["reason"] == "element_not_studied"
    assert est["text"].endswith("has no linear result at 16 cells: run "
                                "`q3t study --course --elements linear --cells 16`")
    est = estimate(tmp_path, "scordelis_lo", "quadratic", None, None, **course, cells=64)
    assert est["reason"] == "no_error"  # the case was left out (its size)
    assert estimate(tmp_path, "pinched_hemisphere", "q3t", None, None, **course,
                    cells=16)["reason"] == "no_study"

"""/api/studies: a refinement study of a finished run's scene from the page (server.studies).
The plan's cases are what `q3t study` runs, each sized as sim.model.size counts it and timed by
the prediction's rule from the run; a bad request is a 422 naming the field; a study runs as the
command line's, its progress a line per case, and its report gives the run its estimate; one
study at a time; a cancelled study's processes are gone and the last report stays whole."""

from __future__ import annotations

import json
import os
import time

import pytest

from server import studies
from sim.model import size
from sim.refinement import element_overrides
from sim.scene.load import load_scene
from tests.support.scenes import tiny_toml
from tests.support.service import HANG, finished_run, in_process, until

# the cantilever at 35 mm takes about 0.35 GiB to build by sim.model.size's count, a 5 mm
# level about 0.8 GiB: a limit between them refuses the fine level and not the run
LIMIT = 0.5 * 2**30


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("studies")
    with in_process(tmp, {"tiny": tiny_toml()}, max_model_bytes=LIMIT) as (client, settings):
        yield client, settings, client.app.state.studies


@pytest.fixture(scope="module")
def run(env):
    """A finished run of the tiny cantilever with the assumed-strain prism, which the scene's
    default study does not have."""
    return finished_run(env[0], "tiny", element="q3t_ans")


def test_the_plan_sizes_and_times_each_case_from_the_run(env, run):
    client, settings, _ = env
    r = client.post("/api/studies/plan", json={"run": run})
    assert r.status_code == 200, r.text
    plan = r.json()
    # the scene has no [study] table: 4, 2 and 1 times its 35 mm edge, the three routine
    # elements and the run's own, the quadratic prism at half the finest level as reference
    assert plan["elements"] == ["linear", "q3t", "quadratic", "q3t_ans"]
    assert plan["levels_mm"] == pytest.approx([140.0, 70.0, 35.0])
    assert plan["reference"] == {"element": "quadratic", "edge_mm": pytest.approx(17.5)}
    assert plan["command"] == ("q3t study tiny --elements linear,q3t,quadratic,q3t_ans "
                               "--levels 0.14,0.07,0.035 --reference quadratic:0.0175")
    result = json.loads((settings.runs_dir / run / "result.json").read_text())
    basis = plan["basis"]
    assert basis == {"run": run, "element": "q3t_ans", "dofs": result["counts"]["dofs"],
                     "seconds": pytest.approx(result["timing"]["per_iteration"]
                                              * result["timing"]["newton_iterations"])}
    cases = plan["cases"]
    assert [(c["element"], c["edge_mm"]) for c in cases] == [
        ("quadratic", pytest.approx(17.5)),
        *[(e, pytest.approx(h)) for e in plan["elements"] for h in (140.0, 70.0, 35.0)]]
    assert [c["reference"] for c in cases] == [True] + [False] * 12
    scene = settings.scenes_dir / "tiny.toml"
    for c in cases:
        s = size.estimate(load_scene(scene, {**element_overrides(c["element"]),
                                             "mesh.edge_length": c["edge_mm"] / 1e3}))
        assert c["dofs"] == s.dofs and c["memory_gib"] == pytest.approx(s.bytes / 2**30)
        # the run's seconds scaled by a power of the DoFs and by the elements' weights
        assert c["predicted_s"] == pytest.approx(
            basis["seconds"] * (s.dofs / basis["dofs"]) ** studies.DOF_POWER
            * studies.weight(c["element"]) / studies.weight("q3t_ans"), rel=1e-12)
    # the run's own case is predicted at its own time
    own = next(c for c in cases if c["element"] == "q3t_ans" and c["edge_mm"] == 35.0)
    assert own["dofs"] == basis["dofs"] and own["predicted_s"] == pytest.approx(basis["seconds"])
    # with the run's own DoFs, which the count from the mesh parameters may miss (an
    # outline's is from its area): it alone is marked so
    assert [c["asking_run"] for c in cases] == [c is own for c in cases]
    # the study's warm-up runs each element once at the coarsest level
    warm = sum(c["predicted_s"] for c in cases if c["edge_mm"] == 140.0)
    assert plan["predicted_s"] == pytest.approx(sum(c["predicted_s"] for c in cases) + warm)
    assert any("within about a factor of two" in n for n in plan["notes"])
    assert "the run's element (q3t_ans) added to the scene's" in plan["notes"]
    assert plan["largest_gib"] == max(c["memory_gib"] for c in cases)
    # the command line's notes in mm, as the page gives lengths
    assert "reference edge length: half the finest level (17.5 mm)" in plan["notes"]
    # asked for: those elements, levels and reference only, each once
    r = client.post("/api/studies/plan", json={"run": run, "elements": ["q3t", "q3t"],
                                              "levels_mm": [35, 70, 35.0],
                                              "reference": {"element": "quadratic",
                                                            "edge_mm": 35}})
    assert r.status_code == 200, r.text
    assert [(c["element"], c["edge_mm"]) for c in r.json()["cases"]] == [
        ("quadratic", 35.0), ("q3t", 70.0), ("q3t", 35.0)]


def test_the_plan_takes_the_runs_level_and_says_what_the_run_changed(env):
    """A run at a level the scene's defaults lack gets it (its estimate is then its own
    level's, not the nearest); a run with overrides besides element and mesh is told that the
    study runs the saved scene."""
    client = env[0]
    odd = finished_run(client, "tiny", overrides={"mesh.edge_length": 0.05,
                                                  "material.nu": 0.25})
    plan = client.post("/api/studies/plan", json={"run": odd}).json()
    assert plan["levels_mm"] == pytest.approx([140.0, 70.0, 50.0, 35.0])
    assert plan["reference"]["edge_mm"] == pytest.approx(17.5)
    assert "the run's level (50 mm) added to the scene's" in plan["notes"]
    # the study runs what the run ran: its overrides (and edits, below), not its element or
    # mesh, which it varies itself; the command says so
    assert "the study runs what the run ran: material.nu = 0.25" in plan["notes"]
    assert plan["command"].endswith(" --set material.nu=0.25")


@pytest.mark.parametrize(("body", "status", "detail"), [
    ({"levels_mm": [-1.0]}, 422, r"^levels_mm: -1 mm: a mesh edge length is a positive number"),
    ({"levels_mm": [5.0], "elements": ["quadratic"],
      "reference": {"element": "linear", "edge_mm": 5.0}}, 422,
     r"^levels_mm: quadratic at 5 mm would have [\d,]+ DoFs and need "
     r"about [\d.]+ GiB to build, above the server's limit of 0\.5 GiB: a coarser level"),
    ({"reference": {"element": "quadratic", "edge_mm": 5.0}}, 422,
     r"^reference\.edge_mm: quadratic at 5 mm would have"),
    ({"reference": {"element": "quadratic", "edge_mm": 0.0}}, 422,
     r"^reference\.edge_mm: 0 mm: a mesh edge length is a positive number"),
    ({"elements": ["prism9"]}, 422, r"^elements: unknown element 'prism9'"),
    # a level longer than the sheet: the same few triangles as a finer one, no level
    ({"levels_mm": [1e6, 35]}, 422, r"^levels_mm: mesh: edge_length: 1e\+06 mm is longer "
                                    r"than the rectangle's longer side \(700 mm\)"),
    ({"levels_mm": [70], "reference": {"element": "quadratic", "edge_mm": 140.0}}, 422,
     r"^reference\.edge_mm: 140 mm is coarser than the finest level \(70 mm\): every case's "
     r"error is measured against the reference"),
    ({"reference": {"element": "prism9", "edge_mm": 20.0}}, 422,
     r"^reference\.element: unknown element 'prism9'"),
    ({"run": "no-such-run"}, 404, r"^run: "),
])
def test_a_bad_plan_is_refused_naming_the_field(env, run, body, status, detail):
    import re

    client = env[0]
    for url in ("/api/studies/plan", "/api/studies"):
        r = client.post(url, json={"run": run, **body})
        assert r.status_code == status, r.text
        assert re.search(detail, r.json()["detail"]), r.json()["detail"]
    assert env[2].current is None  # nothing started


def test_a_level_not_a_number_is_refused_naming_it(env, run):
    r = env[0].post("/api/studies/plan", content=f'{{"run": "{run}", "levels_mm": [NaN]}}',
                    headers={"Content-Type": "application/json"})
    assert r.status_code == 422, r.text
    assert r.json()["detail"] == "body.levels_mm.0: Input should be a finite number"


def test_a_study_runs_as_the_command_lines_and_gives_the_run_its_estimate(env, run):
    client, settings, runner = env
    assert client.get(f"/api/runs/{run}").json()["estimate"]["reason"] == "no_study"
    body = {"run": run, "elements": ["q3t_ans", "q3t"], "levels_mm": [70, 35]}
    r = client.post("/api/studies", json=body)
    assert r.status_code == 201, r.text
    assert r.json()["state"] == "running" and r.json()["cases"] == 5
    # the first case of the plan runs first: the reference
    assert r.json()["now"]["reference"] and r.json()["now"]["edge_mm"] == pytest.approx(17.5)
    # one at a time: the first one's Dask cluster takes seconds to start
    again = client.post("/api/studies", json=body)
    assert again.status_code == 409, again.text
    assert again.json()["detail"].startswith("a study of 'tiny' is running (")

    def ended():
        st = client.get("/api/studies").json()["study"]
        return st if st["state"] != "running" else None

    st = until(ended, "the study did not end", HANG)
    assert st["state"] == "finished", st
    assert st["done"] == st["cases"] == 5 and st["now"] is None and not st["had_report"]
    # the command's line per case, in mm: the plan's cases in the plan's order
    plan = client.post("/api/studies/plan", json=body).json()
    assert [(c["element"], c["edge_mm"], c["reference"], c["dofs"]) for c in st["finished"]] \
        == [(c["element"], pytest.approx(c["edge_mm"]), c["reference"], pytest.approx(
            c["dofs"], rel=0.05)) for c in plan["cases"]]
    assert all(c["status"] == "converged" and c["seconds"] > 0 for c in st["finished"])
    # planned again: the study it would replace is named
    assert any(n.startswith("replaces the study of ") for n in plan["notes"])
    # a run of unsaved edits takes its estimate from the saved scene's study, and says so
    text = tiny_toml()
    assert "\nnu = 0.49\n" in text
    edited = finished_run(client, "tiny", element="q3t",
                          toml=text.replace("\nnu = 0.49\n", "\nnu = 0.25\n"))
    est = client.get(f"/api/runs/{edited}").json()["estimate"]
    assert est["available"], est
    assert ("the study ran the scene as saved; this run ran the scene with material.nu "
            "0.49 → 0.25") in est["notes"], est["notes"]
    report = json.loads((settings.runs_dir / "study-tiny" / "report.json").read_text())
    assert report["study"]["changes"] == []
    rows = report["study"]["rows"]
    assert [(r["element"], r["edge_length"]) for r in rows] == [
        ("q3t_ans", 0.07), ("q3t_ans", 0.035), ("q3t", 0.07), ("q3t", 0.035)]
    est = client.get(f"/api/runs/{run}").json()["estimate"]
    assert est["available"] and est["match"] == "exact", est
    own = rows[1]
    assert est["relative_error"] == pytest.approx(own["error"])
    # studied from the run of edits, the study runs what that run ran (its scene.toml, as
    # the scene's name, beside the report); its report says so, and the run's estimate has
    # no word of it, where the saved scene's run now has
    small = {"run": edited, "elements": ["q3t_ans", "q3t"], "levels_mm": [35]}
    plan = client.post("/api/studies/plan", json=small).json()
    assert "the study runs what the run ran: material.nu 0.49 → 0.25" in plan["notes"]
    copy = settings.runs_dir / "study-tiny" / f"ran-{edited}" / "tiny.toml"
    assert plan["command"].startswith(f"q3t study {copy} --elements q3t_ans,q3t --levels "
                                      "0.035")
    assert "\nnu = 0.25\n" in copy.read_text()
    assert client.post("/api/studies", json=small).status_code == 201
    assert until(ended, "the study did not end", HANG)["state"] == "finished"
    report = json.loads((settings.runs_dir / "study-tiny" / "report.json").read_text())
    assert report["study"]["changes"] == ["material.nu 0.49 → 0.25"]
    assert report["study"]["rows"][1]["probe"] != rows[3]["probe"]  # another nu, another sag
    est = client.get(f"/api/runs/{edited}").json()["estimate"]
    assert est["available"] and est["match"] == "exact" and est["notes"] == [], est
    est = client.get(f"/api/runs/{run}").json()["estimate"]
    assert ("the study ran the scene with material.nu 0.49 → 0.25; this run ran the scene as "
            "saved") in est["notes"], est["notes"]


def test_a_cancelled_study_ends_its_processes_and_leaves_the_last_report(env, run):
    client, settings, runner = env
    report = settings.runs_dir / "study-tiny" / "report.json"
    before = report.read_bytes() if report.exists() else None
    # cancelled at once: the study's Dask cluster alone takes seconds to start
    r = client.post("/api/studies", json={"run": run, "levels_mm": [35, 17.5],
                                         "reference": {"element": "quadratic", "edge_mm": 10}})
    assert r.status_code == 201, r.text
    proc = runner.current.proc
    st = client.post("/api/studies/cancel")
    assert st.status_code == 200, st.text
    assert st.json()["state"] == "cancelled"
    assert st.json()["reason"] == "cancelled from the page"
    assert proc.poll() is not None
    # its group (the command and the Dask workers it started) is gone
    deadline = time.monotonic() + HANG
    while time.monotonic() < deadline:
        try:
            os.killpg(proc.pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.1)
    else:
        pytest.fail("the study's processes outlived the cancel")
    assert (report.read_bytes() if report.exists() else None) == before
    assert client.get("/api/studies").json()["study"]["state"] == "cancelled"
    again = client.post("/api/studies/cancel")
    assert again.status_code == 409 and again.json()["detail"] == "no study is running"

"""The service end to end through FastAPI's TestClient (which runs the lifespan): scenes,
runs, live parameters, results, recordings, and a solver process killed mid-run."""

from __future__ import annotations

import json
import os
import signal
import threading

import pytest

pytest.importorskip("fastapi")

from tests.support.scenes import tiny_toml  # noqa: E402
from tests.support.service import (  # noqa: E402
    file_scene,
    nested,
    no_temp_files,
    wait_done,
    wait_state,
    wait_step,
)


def test_happy_path(env):
    """Create a scene, start a run, change load_scale while it runs, step it (a running run
    pauses), resume, finish; the parameter's step comes from the solver, is recorded, and the
    response follows it from that step on."""
    client, settings = env
    r = client.post("/api/scenes", json={"name": "mine", "toml": tiny_toml(steps=200)})
    assert r.status_code == 201, r.text
    assert "mine" in [s["name"] for s in client.get("/api/scenes").json()]
    # E = 1e11: the tip deflects 0.15 % of the length at load_scale 2, so the response is
    # linear in the load to ~(w/L)^2 ~ 2e-6 and load_scale's effect is a clean factor of 2
    r = client.post("/api/runs", json={"scene": "mine", "element": "linear",
                                       "overrides": {"material.E": 1.0e11}})
    assert r.status_code == 201, r.text
    run_id = r.json()["id"]
    st = wait_step(client, run_id, 3)
    assert st["state"] == "running", st
    r = client.put(f"/api/runs/{run_id}/parameters/load_scale", json={"value": 2.0})
    assert r.status_code == 202, r.text
    reply = r.json()
    assert reply["applied"], reply  # the solver answers between steps (~5 ms here)
    k = reply["applies_from_step"]
    assert 3 < k < 200
    r = client.post(f"/api/runs/{run_id}/step")  # on a running run: pauses after one step
    assert r.status_code == 200 and r.json()["state"] == "paused", r.text
    assert r.json()["pending"] == ["step"]
    st = wait_done(client, run_id)  # the step under way, then the one asked for: paused
    assert st["state"] == "paused", st  # the solver said so too, not only the request
    paused_at = st["step"]
    assert client.post(f"/api/runs/{run_id}/pause").status_code == 200  # a round trip
    assert wait_done(client, run_id)["step"] == paused_at  # paused: no step meanwhile
    assert client.post(f"/api/runs/{run_id}/resume").status_code == 200
    r = client.post(f"/api/runs/{run_id}/resume")  # running again (or over): nothing to resume
    assert r.status_code == 409 and r.json()["detail"] in (
        f"run {run_id!r} is running, not paused: nothing to resume",
        f"run {run_id!r} is finished, not active"), r.text
    st = wait_state(client, run_id, {"finished", "failed", "stopped"})
    assert st["state"] == "finished", st["reason"]
    assert [r["step"] for r in st["records"]] == list(range(1, 201))
    assert st["parameter_log"] == [{"step": k, "name": "load_scale", "value": 2.0}]
    # gravity ramps linearly with the step: tip / step is constant, and doubles from step k on
    # (rel 1e-4: the nonlinearity above is ~2e-6; the wrong step would be off by 100 %)
    ratio = {r["step"]: r["probes"]["tip_deflection"] / r["step"] for r in st["records"]}
    base = ratio[1]
    assert base < 0
    for step, v in ratio.items():
        assert v == pytest.approx(base * (2.0 if step >= k else 1.0), rel=1e-4), (step, k)
    res = client.get(f"/api/runs/{run_id}/result").json()
    assert res["converged"] and res["element"] == "linear"
    assert res["parameters"] == st["parameter_log"]
    est = st["estimate"]  # a finished run without a study of its scene says how to get one
    assert not est["available"] and est["reason"] == "no_study"
    assert est["text"].startswith("no study for this scene: run `q3t study mine`; cost ")
    assert est["cost"]["newton_iterations"] == res["timing"]["newton_iterations"]
    assert res["estimate"] == est
    assert st["frames"]["produced"] == 200
    rec = client.get(f"/api/runs/{run_id}/recording")
    assert rec.status_code == 200 and len(rec.content) > 1000
    assert client.get(f"/api/runs/{run_id}?since=2").json()["records"][0]["step"] == 3
    assert run_id in [r["id"] for r in client.get("/api/runs").json()]
    assert client.delete(f"/api/runs/{run_id}").status_code == 204
    assert client.get(f"/api/runs/{run_id}").status_code == 404
    assert not (settings.runs_dir / run_id).exists()


def test_scene_crud(env):
    client, settings = env
    assert client.post("/api/scenes/tiny/duplicate", json={"name": "copy"}).status_code == 201
    # the copy's name field follows its new name; the rest as it was
    assert client.get("/api/scenes/copy").json()["toml"] == \
        tiny_toml().replace('name = "tiny"', 'name = "copy"')
    changed = tiny_toml().replace("nu = 0.49", "nu = 0.3")
    r = client.put("/api/scenes/copy", json={"toml": changed})
    assert r.status_code == 200 and r.json()["scene"]["material"]["nu"] == 0.3
    assert client.delete("/api/scenes/copy").status_code == 204
    assert client.get("/api/scenes/copy").status_code == 404
    assert "properties" in client.get("/api/scenes/schema").json()
    assert client.get("/docs").status_code == 200
    assert client.get("/openapi.json").json()["info"]["title"]


def test_scene_with_a_mesh_file_in_the_scenes_folder_runs(env):
    """A relative mesh.path is read from the scenes folder (not the server's working folder)."""
    import trimesh

    from sim.geometry.trimesh import rectangle

    client, settings = env
    m = rectangle((0.7, 0.07), 0.035)
    (settings.scenes_dir / "meshes").mkdir(exist_ok=True)
    trimesh.Trimesh(m.vertices, m.faces, process=False).export(
        settings.scenes_dir / "meshes" / "plate.obj")
    r = client.put("/api/scenes/fromfile", json={"toml": file_scene("meshes/plate.obj")})
    assert r.status_code == 200, r.text
    run_id = client.post("/api/runs", json={"scene": "fromfile", "element": "linear"}).json()
    st = wait_state(client, run_id["id"], {"finished", "failed", "stopped"})
    assert st["state"] == "finished", st["reason"]
    assert "mesh.path" not in st["overrides"]  # the full path went to the solver only
    assert client.delete("/api/scenes/fromfile").status_code == 204


def test_concurrent_creates_of_one_scene_one_wins(env):

    from server.problems import Conflict
    from server.store import SceneStore

    _, settings = env
    store, n = SceneStore(settings.scenes_dir), 8
    barrier, results = threading.Barrier(n), []

    def create(i: int) -> None:
        barrier.wait()
        try:
            store.create("race", tiny_toml().replace("tiny", f"tiny{i}"))
            results.append(i)
        except Conflict:
            results.append(None)

    threads = [threading.Thread(target=create, args=(i,)) for i in range(n)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    winners = [i for i in results if i is not None]
    assert len(results) == n and len(winners) == 1, results
    assert f"tiny{winners[0]}" in (settings.scenes_dir / "race.toml").read_text()
    assert no_temp_files(settings.scenes_dir) == []
    (settings.scenes_dir / "race.toml").unlink()


def test_parameter_out_of_range_on_a_run(env):
    client, _ = env
    run_id = client.post("/api/runs", json={"scene": "tiny", "paused": True}).json()["id"]
    try:
        r = client.put(f"/api/runs/{run_id}/parameters/load_scale", json={"value": 101})
        assert r.status_code == 422 and "out of range" in r.text
        r = client.put(f"/api/runs/{run_id}/parameters/friction", json={"value": 0.1})
        assert r.status_code == 422 and "unknown parameter" in r.text
        r = client.post("/api/runs", json={"scene": "tiny"})  # one solver, busy: queued
        assert r.status_code == 201 and r.json()["state"] == "queued", r.text
        assert r.json()["place"] == 1, r.text
        assert client.delete(f"/api/runs/{run_id}").status_code == 409  # active
        assert client.delete(f"/api/runs/{r.json()['id']}").status_code == 204  # never runs
    finally:
        client.post(f"/api/runs/{run_id}/stop")
    st = wait_state(client, run_id, {"stopped", "finished", "failed"})
    assert st["state"] == "stopped"


def test_worker_crash_fails_the_run_and_the_next_run_succeeds(env):
    client, _ = env
    (env[1].scenes_dir / "long.toml").write_text(tiny_toml(steps=200))
    run_id = client.post("/api/runs", json={"scene": "long"}).json()["id"]
    assert wait_step(client, run_id, 1)["state"] == "running"
    pid = client.get("/api/health").json()["worker_pid"]
    os.kill(pid, signal.SIGKILL)
    st = wait_state(client, run_id, {"failed", "finished", "stopped"})
    assert st["state"] == "failed" and "solver process died" in st["reason"], st
    assert "signal 9" in st["reason"]
    health = client.get("/api/health").json()
    assert health["ok"] and health["worker_pid"] != pid
    nxt = client.post("/api/runs", json={"scene": "tiny"})
    assert nxt.status_code == 201, nxt.text
    st = wait_state(client, nxt.json()["id"], {"finished", "failed", "stopped"})
    assert st["state"] == "finished", st["reason"]


def test_finished_run_shows_its_error_estimate_from_a_study(env):
    """A synthetic ``q3t study`` report for the scene in the runs root: the finished run's
    status carries the row of its element and edge length, and the run's own cost."""
    client, settings = env
    study = settings.runs_dir / "study-tiny"
    study.mkdir()
    rows = [{"element": "q3t", "edge_length": h, "status": "converged", "elements": 10,
             "dofs": 100, "probe": -1.0, "error": e, "time": 0.1, "iterations": 2}
            for h, e in ((0.07, 0.2), (0.035, 0.049))]
    (study / "report.json").write_text(json.dumps({"study": {
        "plan": {"scene": "scenes/tiny.toml", "probe": "tip", "elements": ["q3t"],
                 "levels": [0.07, 0.035], "reference": ["quadratic", 0.0035], "notes": []},
        "reference": {"value": -1.0}, "rows": rows, "date": "2026-11-22"}}))
    try:
        run_id = client.post("/api/runs", json={"scene": "tiny", "element": "q3t"}).json()["id"]
        first = client.get(f"/api/runs/{run_id}").json()
        if first["state"] != "finished":  # the tiny run may be over already (a quiet machine)
            assert first["estimate"] is None, first
        st = wait_state(client, run_id, {"finished", "failed", "stopped"})
        assert st["state"] == "finished", st["reason"]
        est = st["estimate"]
        assert est["available"] and est["match"] == "exact", est
        assert est["relative_error"] == 0.049 and est["row"]["edge_length"] == 0.035
        res = client.get(f"/api/runs/{run_id}/result").json()
        assert est["cost"]["wall_s"] == res["timing"]["total"]
        assert est["cost"]["newton_iterations"] == res["timing"]["newton_iterations"] > 0
        assert est["text"].startswith("error estimate: 4.9 % vs quadratic at 3.5 mm (study of "
                                      "2026-11-22); cost ")
        saved = json.loads((settings.runs_dir / run_id / "run.json").read_text())
        assert saved["estimate"]["relative_error"] == 0.049  # kept with the run
    finally:
        for f in study.iterdir():
            f.unlink()
        study.rmdir()


def test_the_longest_scene_name_can_run(env):
    """A run id is the scene name plus "-<element>-<time>-<4 hex>": an 80-character scene name
    (the most a scene may have) runs with every element, and its run is addressable."""
    from server.settings import RUN_ID_MAX, SCENE_NAME_MAX
    from sim.elements import ELEMENTS

    client, _ = env
    name = "n" * SCENE_NAME_MAX
    assert client.post("/api/scenes", json={"name": name, "toml": tiny_toml()}).status_code == 201
    assert client.post("/api/scenes", json={"name": name + "n", "toml": tiny_toml()}
                       ).status_code == 422
    longest = max(ELEMENTS, key=len)
    r = client.post("/api/runs", json={"scene": name, "element": longest, "paused": True})
    assert r.status_code == 201, r.text
    run_id = r.json()["id"]
    try:
        assert len(run_id) <= RUN_ID_MAX
        assert client.get(f"/api/runs/{run_id}").status_code == 200
    finally:
        client.post(f"/api/runs/{run_id}/stop")
        wait_state(client, run_id, {"stopped", "finished", "failed"})
        client.delete(f"/api/scenes/{name}")
    assert client.delete(f"/api/runs/{run_id}").status_code == 204


def test_files_the_server_writes_have_the_usual_mode(env):
    """Scenes and run files are created 0666 less the umask, as the shipped scenes were
    (mkstemp's 0600 made them unreadable to anyone else)."""
    client, settings = env
    umask = os.umask(0o022)
    os.umask(umask)
    mode = 0o666 & ~umask
    assert client.put("/api/scenes/moded", json={"toml": tiny_toml()}).status_code == 200
    run_id = client.post("/api/runs", json={"scene": "moded", "paused": True}).json()["id"]
    client.post(f"/api/runs/{run_id}/stop")
    wait_state(client, run_id, {"stopped", "finished", "failed"})
    written = [settings.scenes_dir / "moded.toml", settings.runs_dir / run_id / "run.json",
               settings.runs_dir / run_id / "scene.toml"]
    assert {p.name: oct(p.stat().st_mode & 0o777) for p in written} == \
        {p.name: oct(mode) for p in written}
    assert client.delete("/api/scenes/moded").status_code == 204


def test_status_pages_its_records(env):
    """The status sends at most ``limit`` records after ``since`` and says how many are left;
    asking again from the last step returned gets the rest, as the page does."""
    client, settings = env
    (settings.scenes_dir / "paged.toml").write_text(tiny_toml(steps=12))
    run_id = client.post("/api/runs", json={"scene": "paged", "element": "linear"}).json()["id"]
    st = wait_state(client, run_id, {"finished", "failed", "stopped"})
    assert st["state"] == "finished", st["reason"]
    assert len(st["records"]) == 12 and st["records_left"] == 0  # the default page holds them
    steps, since = [], 0
    while True:
        page = client.get(f"/api/runs/{run_id}?since={since}&limit=5").json()
        steps += [r["step"] for r in page["records"]]
        assert len(page["records"]) <= 5 and page["records_left"] == 12 - len(steps)
        if not page["records_left"]:
            break
        since = steps[-1]
    assert steps == list(range(1, 13))
    assert client.get(f"/api/runs/{run_id}?limit=0").status_code == 422


def test_a_scene_file_put_there_by_hand_never_breaks_the_list(env):
    """A scene file that is not UTF-8, or nested past the parser's recursion, or named so that
    no request could address it: the list still answers (the first two as not valid), reading
    the bad one is a 422 naming why."""
    client, settings = env
    bad = {"latin1.toml": "description = 'Gr\xfc\xdfe'".encode("latin-1"),
           "deep.toml": ("a = " + nested(5000)).encode(), "has space.toml": b"x = 1"}
    for name, data in bad.items():
        (settings.scenes_dir / name).write_bytes(data)
    try:
        listed = {s["name"]: s["valid"] for s in client.get("/api/scenes").json()}
        assert listed["latin1"] is False and listed["deep"] is False
        assert "has space" not in listed
        r = client.get("/api/scenes/latin1")
        assert r.status_code == 422 and "not UTF-8" in r.json()["detail"], r.text
    finally:
        for name in bad:
            (settings.scenes_dir / name).unlink()


def test_a_failed_steps_time_is_the_runs_solver_time(env):
    """A step that fails after its cut-backs took time the run's solver time left out (the
    Runs table said 13 s where Compare, from result.json, said 22 s: a browser review). One
    Newton iteration and no cut-back: the first step fails; the solver time the server counts
    spans the result's own timing of the same step (timed around it in the solver process)."""
    client, settings = env
    r = client.post("/api/runs", json={"scene": "tiny", "overrides": {
        "material.E": 1e7, "solver.max_iterations": 1, "stepping.max_cutbacks": 0}})
    run = r.json()["id"]
    st = wait_state(client, run, {"finished", "failed", "stopped"})
    assert st["state"] == "failed" and st["step"] == 0, st
    total = json.loads((settings.runs_dir / run / "result.json").read_text())["timing"]["total"]
    assert st["stepping_s"] >= total > 0, (st["stepping_s"], total)

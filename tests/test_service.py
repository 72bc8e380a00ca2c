"""The service end to end through FastAPI's TestClient (which runs the lifespan): scenes, runs,
live parameters, results, recordings, bad input, and a solver process killed mid-run."""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import pytest

pytest.importorskip("fastapi")
from fastapi.testclient import TestClient  # noqa: E402

from server.app import create_app  # noqa: E402
from server.settings import Settings  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


def tiny_toml(steps: int = 4) -> str:
    """The cantilever at a coarse mesh and stiff material: a step takes well under a second."""
    text = (ROOT / "scenes/cantilever.toml").read_text()
    text = text.replace("edge_length = 0.0046667", "edge_length = 0.035")
    text = text.replace("steps = 4", f"steps = {steps}")
    return text.replace("E = 5.0e6", "E = 1.0e9").replace('name = "cantilever"', 'name = "tiny"')


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("service")
    os.environ.setdefault("XDG_CONFIG_HOME", str(tmp / "config"))
    os.environ.setdefault("XDG_DATA_HOME", str(tmp / "data"))
    scenes = tmp / "scenes"
    scenes.mkdir()
    (scenes / "tiny.toml").write_text(tiny_toml())
    settings = Settings(scenes_dir=scenes, runs_dir=tmp / "runs", viewer=False, max_body=64_000)
    with TestClient(create_app(settings)) as client:
        yield client, settings


def wait_state(client, run_id: str, states: set[str], timeout: float = 60.0) -> dict:
    deadline = time.time() + timeout
    while time.time() < deadline:
        st = client.get(f"/api/runs/{run_id}").json()
        if st["state"] in states:
            return st
        time.sleep(0.05)
    raise AssertionError(f"run {run_id} stuck in {st['state']} ({st.get('reason')})")


def no_temp_files(root: Path) -> list[Path]:
    return [p for p in root.rglob("*") if p.name.startswith(".") or ".tmp" in p.name]


def test_happy_path(env):
    client, settings = env
    r = client.post("/api/scenes", json={"name": "mine", "toml": tiny_toml(steps=3)})
    assert r.status_code == 201, r.text
    assert "mine" in [s["name"] for s in client.get("/api/scenes").json()]
    r = client.post("/api/runs", json={"scene": "mine", "element": "linear", "paused": True})
    assert r.status_code == 201, r.text
    run_id = r.json()["id"]
    wait_state(client, run_id, {"paused"})
    r = client.put(f"/api/runs/{run_id}/parameters/load_scale", json={"value": 2.0})
    assert r.status_code == 202, r.text
    assert r.json()["applies_from_step"] == 1
    assert client.post(f"/api/runs/{run_id}/step").status_code == 200
    deadline = time.time() + 30
    while client.get(f"/api/runs/{run_id}").json()["step"] < 1 and time.time() < deadline:
        time.sleep(0.05)
    st = client.get(f"/api/runs/{run_id}").json()
    assert st["step"] == 1 and st["state"] == "paused"
    assert client.post(f"/api/runs/{run_id}/resume").status_code == 200
    st = wait_state(client, run_id, {"finished", "failed", "stopped"})
    assert st["state"] == "finished", st["reason"]
    assert [r["step"] for r in st["records"]] == [1, 2, 3]
    assert st["parameter_log"] == [{"step": 1, "name": "load_scale", "value": 2.0}]
    res = client.get(f"/api/runs/{run_id}/result").json()
    assert res["converged"] and res["element"] == "linear"
    assert res["parameters"] == st["parameter_log"]
    est = st["estimate"]  # a finished run without a study of its scene says how to get one
    assert not est["available"] and est["reason"] == "no_study"
    assert est["text"].startswith("no study for this scene: run `q3t study mine`; cost ")
    assert est["cost"]["newton_iterations"] == res["timing"]["newton_iterations"]
    assert res["estimate"] == est
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
    assert client.get("/api/scenes/copy").json()["toml"] == tiny_toml()
    changed = tiny_toml().replace("nu = 0.49", "nu = 0.3")
    r = client.put("/api/scenes/copy", json={"toml": changed})
    assert r.status_code == 200 and r.json()["scene"]["material"]["nu"] == 0.3
    assert client.delete("/api/scenes/copy").status_code == 204
    assert client.get("/api/scenes/copy").status_code == 404
    assert "properties" in client.get("/api/scenes/schema").json()
    assert client.get("/docs").status_code == 200
    assert client.get("/openapi.json").json()["info"]["title"]


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
    ("post", "/api/runs", {"scene": "tiny", "overrides": {"material.E": -1}}, 422,
     ["material.E"]),
    ("post", "/api/runs", {"scene": "tiny", "parameters": {"load_scale": 1e6}}, 422,
     ["load_scale", "range"]),
    ("post", "/api/runs", {"scene": "tiny", "parameters": {"gravity": 1}}, 422, ["unknown"]),
    ("get", "/api/scenes/..", None, 404, []),
    ("get", "/api/scenes/..%2F..%2Fetc%2Fpasswd", None, 404, []),
    ("get", "/api/scenes/.hidden", None, 422, ["scene name"]),
    ("post", "/api/scenes", {"name": "../evil", "toml": tiny_toml()}, 422, ["scene name"]),
    ("post", "/api/scenes/tiny/duplicate", {"name": "a/b"}, 422, ["scene name"]),
    ("put", "/api/scenes/big", {"toml": "#" * 100_000}, 413, ["larger"]),
    ("get", "/api/runs/..secret", None, 422, ["run id"]),
    ("post", "/api/runs/nope-run/pause", None, 404, ["nope-run"]),
    ("post", "/api/runs/nope-run/explode", None, 422, []),
    ("put", "/api/runs/nope-run/parameters/load_scale", {"value": "abc"}, 422, ["value"]),
])
def test_bad_input(env, method, url, body, status, words):
    client, settings = env
    before = sorted(settings.scenes_dir.iterdir())
    r = getattr(client, method)(url, **({"json": body} if body is not None else {}))
    assert r.status_code == status, r.text
    for w in words:
        assert w in r.text, (w, r.text)
    assert sorted(settings.scenes_dir.iterdir()) == before  # nothing saved
    assert no_temp_files(settings.scenes_dir) == []
    assert client.get("/api/health").json()["ok"]  # alive


def test_parameter_out_of_range_on_a_run(env):
    client, _ = env
    run_id = client.post("/api/runs", json={"scene": "tiny", "paused": True}).json()["id"]
    try:
        r = client.put(f"/api/runs/{run_id}/parameters/load_scale", json={"value": 101})
        assert r.status_code == 422 and "out of range" in r.text
        r = client.put(f"/api/runs/{run_id}/parameters/friction", json={"value": 0.1})
        assert r.status_code == 422 and "unknown parameter" in r.text
        r = client.post("/api/runs", json={"scene": "tiny"})
        assert r.status_code == 409 and run_id in r.text
        assert client.delete(f"/api/runs/{run_id}").status_code == 409
    finally:
        client.post(f"/api/runs/{run_id}/stop")
    st = wait_state(client, run_id, {"stopped", "finished", "failed"})
    assert st["state"] == "stopped"


def test_worker_crash_fails_the_run_and_the_next_run_succeeds(env):
    client, _ = env
    (env[1].scenes_dir / "long.toml").write_text(tiny_toml(steps=200))
    run_id = client.post("/api/runs", json={"scene": "long"}).json()["id"]
    deadline = time.time() + 30
    while client.get(f"/api/runs/{run_id}").json()["step"] < 1 and time.time() < deadline:
        time.sleep(0.05)
    pid = client.get("/api/health").json()["worker_pid"]
    os.kill(pid, signal.SIGKILL)
    st = wait_state(client, run_id, {"failed", "finished", "stopped"}, timeout=20)
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
        assert client.get(f"/api/runs/{run_id}").json()["estimate"] is None  # not finished
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


def test_viewer_stays_on_loopback_unless_exposed():
    """The API asks for a token off loopback; viser cannot, so it is not exposed by default."""
    import argparse

    from server.cli import add_parser, serve_settings

    ap = argparse.ArgumentParser()
    add_parser(ap.add_subparsers(dest="cmd"))
    args = ap.parse_args(["serve", "--host", "0.0.0.0", "--token", "t"])
    assert serve_settings(args, "t").viewer_host == "127.0.0.1"
    args = ap.parse_args(["serve", "--host", "0.0.0.0", "--token", "t", "--expose-viewer"])
    assert serve_settings(args, "t").viewer_host == "0.0.0.0"

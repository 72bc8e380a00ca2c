"""The service end to end through FastAPI's TestClient (which runs the lifespan): scenes, runs,
live parameters, results, recordings, bad input, and a solver process killed mid-run."""

from __future__ import annotations

import json
import os
import signal
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("fastapi")
from fastapi.testclient import TestClient  # noqa: E402

from server.app import create_app  # noqa: E402
from server.settings import Settings  # noqa: E402
from tests.support import ROOT  # noqa: E402
from tests.support.scenes import tiny_toml  # noqa: E402
from tests.support.service import (  # noqa: E402
    HANG,
    free_port,
    until,
    wait_done,
    wait_state,
    wait_step,
)


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("service")
    os.environ.setdefault("XDG_CONFIG_HOME", str(tmp / "config"))
    os.environ.setdefault("XDG_DATA_HOME", str(tmp / "data"))
    scenes = tmp / "scenes"
    scenes.mkdir()
    (scenes / "tiny.toml").write_text(tiny_toml())
    # files next to the scenes folder that no request may read, write or delete
    (tmp / "secret.toml").write_text(tiny_toml())
    (tmp / "secret.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    # the solver answers a parameter change between two steps: on a loaded machine that may
    # take longer than the default second, never this long (a hang guard)
    settings = Settings(scenes_dir=scenes, runs_dir=tmp / "runs", viewer=False, max_body=64_000,
                        ack_timeout=HANG)
    with TestClient(create_app(settings)) as client:
        until(lambda: client.get("/api/config").json()["ready"], "the solver never got ready")
        yield client, settings


def no_temp_files(root: Path) -> list[Path]:
    return [p for p in root.rglob("*") if p.name.startswith(".") or ".tmp" in p.name]


def outside_scenes(settings) -> dict:
    """Every file in the test folder outside scenes/ and runs/, with its content and mtime."""
    root = settings.scenes_dir.parent
    keep = (settings.scenes_dir, settings.runs_dir, root / "config", root / "data")
    return {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in root.rglob("*")
            if p.is_file() and not any(p.is_relative_to(k) for k in keep)}


def file_scene(path: str) -> str:
    """tiny, its mesh read from ``path``."""
    return tiny_toml().replace('kind = "rectangle"', f"kind = \"file\"\npath = '{path}'")


def thickness_scene(path: str) -> str:
    """tiny, its per-vertex thickness read from ``path``."""
    return tiny_toml().replace("thickness = 0.007", f"thickness_file = '{path}'")


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
    import threading

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


def test_viewer_stays_on_loopback_unless_exposed(capsys):
    """The API asks for a token off loopback; viser cannot, so it is not exposed by default,
    and exposing it warns that its run controls are open too."""
    from server.cli import serve_settings

    assert serve_settings(serve_args("--host", "0.0.0.0", "--token", "t"), "t").viewer_host \
        == "127.0.0.1"
    assert capsys.readouterr().err == ""
    args = serve_args("--host", "0.0.0.0", "--token", "t", "--expose-viewer")
    assert serve_settings(args, "t").viewer_host == "0.0.0.0"
    err = capsys.readouterr().err
    assert "no token check" in err and "Pause, Resume, Step and Stop" in err
    assert serve_settings(serve_args("--record-every", "3"), None).record_every == 3


class BlockingViewer:
    """A viewer whose first frame blocks until the test releases it: meanwhile the solver runs
    on and nothing drains its frame queue."""

    def __init__(self):
        self.shown = []
        self.inside, self.release = threading.Event(), threading.Event()

    def show(self, frame, status, final=False, live=True):
        self.inside.set()
        assert self.release.wait(HANG)
        self.shown.append(frame["step"])

    def new_run(self, *a, **k): pass
    def run_status(self, *a): pass
    def show_run(self, *a): pass
    def add_parameters(self, *a): pass
    def set_parameter_value(self, *a): pass
    def set_runs(self, *a): pass


def test_frames_are_dropped_for_a_slow_viewer(env, monkeypatch):
    """A viewer stuck in its first frame (the rest state of a run started paused): status
    reads do not wait for it; resumed, the solver drops the frames its bounded queue cannot
    hold and none pile up; released, the viewer gets only the newest of the queued frames
    (the bridge skips stale ones) and the last frame; the recording still has every N-th
    mesh."""
    from dataclasses import replace

    from tests.support.recording import series, sheet_steps

    client, settings = env
    m = client.app.state.manager
    viewer = BlockingViewer()
    monkeypatch.setattr(m, "viewer", viewer)
    monkeypatch.setattr(m, "settings", replace(m.settings, record_every=7, push_hz=1000.0))
    (settings.scenes_dir / "fast.toml").write_text(tiny_toml(steps=2000))
    run_id = client.post("/api/runs", json={"scene": "fast", "element": "linear",
                                            "paused": True}).json()["id"]
    assert viewer.inside.wait(HANG), "no frame shown"
    # the viewer holds the bridge, not the run lock: a status read does not wait for it
    read = threading.Thread(target=client.get, args=(f"/api/runs/{run_id}",))
    read.start()
    read.join(HANG)
    assert not read.is_alive(), "a status read waited for the viewer"
    assert client.post(f"/api/runs/{run_id}/resume").status_code == 200
    # behind the rest frame the events queue holds at most 4 events besides the steps' (the
    # paused state, the start's reply, the running state, the resume's reply) and a record
    # per step, each sent before its frame: frame_queue + 2 records mean a frame was offered
    # to the full queue
    need = 4 + settings.frame_queue + 2
    until(lambda: m.worker.events.qsize() >= need, "the solver did not step")
    assert m.worker.frames.qsize() == settings.frame_queue  # full, not more
    viewer.release.set()
    # the queued frames reach the bridge while the run goes on (2000 steps take seconds)
    until(lambda: client.get(f"/api/runs/{run_id}").json()["frames"].get("received", 0)
          > settings.frame_queue, "the queued frames never arrived")
    assert client.post(f"/api/runs/{run_id}/stop").status_code == 200
    st = wait_state(client, run_id, {"stopped", "failed", "finished"})
    assert st["state"] == "stopped", st["reason"]
    last, f = st["step"], st["frames"]
    assert f["produced"] == last
    assert f["dropped"] > 0, f  # the queue was full: dropped by the solver, not queued
    sent = f["produced"] - f["dropped"] + 2  # + the rest frame and the stopped state's
    # those still queued when the run ended are not taken for it: at most frame_queue
    assert sent - settings.frame_queue <= f["received"] <= sent, f
    until(lambda: viewer.shown and viewer.shown[-1] == last, "the last frame was dropped")
    f = client.get(f"/api/runs/{run_id}").json()["frames"]
    assert len(viewer.shown) == f["pushed"] < f["received"]  # the bridge skipped stale ones
    assert viewer.shown == sorted(viewer.shown)
    path = settings.runs_dir / run_id / "run.rrd"
    assert sheet_steps(path) == sorted({*range(0, last + 1, 7), last})  # every N, the last
    assert sorted(series(path, "/solver/iterations")) == list(range(1, last + 1))  # all


def test_frames_read_after_the_run_ended_are_kept(env, monkeypatch):
    """Frames come by one queue, the run's states by another: a bridge that reads both late
    (a loaded machine) books the run's end before the frames the solver made earlier. Those
    frames are still kept for scrubbing. Here the bridge is held until the solver is done."""
    from server.bridge import Bridge

    client, settings = env
    m = client.app.state.manager
    parked, go = threading.Event(), threading.Event()
    step = Bridge._step

    def late(self):
        parked.set()
        go.wait(HANG)
        step(self)

    (settings.scenes_dir / "three.toml").write_text(tiny_toml(steps=3))
    monkeypatch.setattr(Bridge, "_step", late)
    try:
        assert parked.wait(HANG), "the bridge never came round"
        run_id = client.post("/api/runs", json={"scene": "three"}).json()["id"]
        # building, meta, the rest frame, running, the start's reply, 3 step records, the
        # last frame and the finished state; frames 1 and 2 wait on the frame queue
        until(lambda: m.worker.events.qsize() >= 10, "the solver did not finish the run")
    finally:
        go.set()
    st = wait_state(client, run_id, {"finished", "failed", "stopped"})
    assert st["state"] == "finished", st["reason"]
    # the end is booked from the event queue; frames 1 and 2 may still be in the frame queue's
    # pipe then (its feeder thread flushes on its own): they must arrive, and be kept
    kept = lambda: client.get(f"/api/runs/{run_id}/frames").json()["steps"]  # noqa: E731
    until(lambda: kept() == [0, 1, 2, 3], f"frames 1 and 2 not kept: {kept()}")


def test_a_bridge_error_fails_the_run_and_the_service_goes_on(env, monkeypatch):
    """An exception while the bridge books an event (here: the disk is full) fails the active
    run with the reason; the bridge stays alive, /api/health says so, the next run runs."""
    client, settings = env
    m = client.app.state.manager

    def full(frame):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(m.history, "add", full)
    (settings.scenes_dir / "long.toml").write_text(tiny_toml(steps=200))
    run_id = client.post("/api/runs", json={"scene": "long"}).json()["id"]
    st = wait_state(client, run_id, {"failed", "finished", "stopped"})
    assert st["state"] == "failed", st
    assert "No space left on device" in st["reason"] and "'frame' event" in st["reason"]
    health = client.get("/api/health").json()
    assert health["ok"] and health["bridge_alive"] and health["bridge_errors"] >= 1, health
    assert health["active"] is None
    monkeypatch.undo()
    nxt = client.post("/api/runs", json={"scene": "tiny"})
    assert nxt.status_code == 201, nxt.text  # not 409: the failed run is not left active
    st = wait_state(client, nxt.json()["id"], {"finished", "failed", "stopped"})
    assert st["state"] == "finished", st["reason"]


def test_a_recording_error_in_the_solver_fails_the_run(tmp_path, monkeypatch):
    """The solver process writes the recording; a write error (disk full) fails the run with
    the reason and the solver goes on to the next run. Driven in this process, queues and all,
    with the recorder's frame write failing."""
    import queue

    from server import recording
    from server.worker import Solver

    events, frames = queue.Queue(), queue.Queue(maxsize=4)
    solver = Solver(events, frames, record_every=1, step_delay=0.0)
    calls = {"n": 0}
    real = recording.Recorder.frame

    def full_on_step_2(self, frame, mesh=True):
        calls["n"] += 1
        if frame["step"] == 2:
            raise OSError(28, "No space left on device")
        return real(self, frame, mesh)

    monkeypatch.setattr(recording.Recorder, "frame", full_on_step_2)
    for run in ("r1", "r2"):  # the server makes the run's folder
        (tmp_path / run).mkdir()
    solver.handle({"id": 1, "cmd": "start", "run": "r1", "out": str(tmp_path / "r1"),
                   "scene_toml": tiny_toml(steps=5), "overrides": {"shell.element": "linear"}})
    states = _step_to_end(solver, events)
    assert states[-1][0] == "failed", states
    assert "No space left on device" in states[-1][1] and "recording" in states[-1][1]
    assert (tmp_path / "r1" / "result.json").is_file()  # the results are still written
    monkeypatch.undo()
    solver.handle({"id": 2, "cmd": "start", "run": "r2", "out": str(tmp_path / "r2"),
                   "scene_toml": tiny_toml(steps=2), "overrides": {"shell.element": "linear"}})
    states = _step_to_end(solver, events)
    assert states[-1][0] == "finished", states


def _step_to_end(solver, events) -> list[tuple[str, str | None]]:
    """Step the in-process solver until its run ends; the (state, reason) events it sent."""
    while solver.stepping:
        solver.step()
    states = []
    while not events.empty():
        ev = events.get()
        if ev["kind"] == "state":
            states.append((ev["state"], ev.get("reason")))
    return states


def sleepy_worker(commands, events, frames, record_every, step_delay):
    """A solver process that never gets ready (for the tests of a slow start)."""
    threading.Event().wait()


class NeverReady(threading.Event):
    """The solver's ready event, never set, recording every wait on it (returned at once)."""

    def __init__(self):
        super().__init__()
        self.waits = []

    def wait(self, timeout=None):
        self.waits.append(timeout)
        return False


def test_nothing_waits_long_for_a_slow_solver_start(tmp_path):
    """The config does not wait for the solver at all; a run with live parameters (which the
    solver names) waits ack_timeout, then says to retry."""
    settings = Settings(scenes_dir=tmp_path / "scenes", runs_dir=tmp_path / "runs",
                        viewer=False, ack_timeout=0.5)
    (tmp_path / "scenes").mkdir()
    (tmp_path / "scenes" / "tiny.toml").write_text(tiny_toml())
    with TestClient(create_app(settings, worker_target=sleepy_worker)) as client:
        ready = client.app.state.manager.ready = NeverReady()
        cfg = client.get("/api/config").json()
        assert ready.waits == []  # no wait for the solver
        assert cfg["ready"] is False and cfg["parameters"] == {}
        r = client.post("/api/runs", json={"scene": "tiny", "parameters": {"load_scale": 2}})
        assert r.status_code == 503 and "starting" in r.text, r.text
        assert r.headers["retry-after"] == "1"
        assert ready.waits == [settings.ack_timeout]


def test_shutdown_stops_the_active_run_with_a_result(tmp_path):
    """Leaving the app (as on Ctrl-C) stops the active run: state 'stopped', result.json and
    a closed recording; no solver process is started during the shutdown."""
    settings = Settings(scenes_dir=tmp_path / "scenes", runs_dir=tmp_path / "runs",
                        viewer=False, stop_timeout=HANG)  # the solver stops within a step
    (tmp_path / "scenes").mkdir()
    (tmp_path / "scenes" / "long.toml").write_text(tiny_toml(steps=2000))
    with TestClient(create_app(settings)) as client:
        run_id = client.post("/api/runs", json={"scene": "long"}).json()["id"]
        wait_step(client, run_id, 2)
        m = client.app.state.manager
        worker = m.worker
    assert m.restarts == 0 and m.worker is worker and not worker.alive()
    saved = json.loads((settings.runs_dir / run_id / "run.json").read_text())
    assert saved["state"] == "stopped" and saved["reason"] == "server shut down", saved
    result = json.loads((settings.runs_dir / run_id / "result.json").read_text())
    assert 2 <= len(result["steps"]) < 2000


def test_ctrl_c_stops_the_run_and_the_server(tmp_path):
    """SIGINT to the whole process group (Ctrl-C in a terminal): the solver process ignores
    it, the server stops the active run (state 'stopped' with a result) and exits; no solver
    process is left or restarted."""
    import subprocess
    import sys

    import httpx

    (tmp_path / "scenes").mkdir()
    (tmp_path / "scenes" / "long.toml").write_text(tiny_toml(steps=2000))
    port = free_port()
    log = open(tmp_path / "server.log", "wb")  # noqa: SIM115 - closed below
    proc = subprocess.Popen(
        [sys.executable, "-m", "sim.apps", "serve", "long", "--port", str(port), "--no-viewer",
         "--scenes-dir", str(tmp_path / "scenes"), "--runs-dir", str(tmp_path / "runs")],
        stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        url = f"http://127.0.0.1:{port}"
        deadline = time.time() + HANG
        while True:
            try:
                if httpx.get(url + "/api/health", timeout=1).json()["ok"]:
                    break
            except httpx.HTTPError:
                pass
            assert time.time() < deadline and proc.poll() is None, \
                (tmp_path / "server.log").read_text()
            time.sleep(0.2)
        run_id = httpx.post(url + "/api/runs", json={"scene": "long"}).json()["id"]
        while httpx.get(f"{url}/api/runs/{run_id}").json()["step"] < 2:
            assert time.time() < deadline
            time.sleep(0.05)
        worker_pid = httpx.get(url + "/api/health").json()["worker_pid"]
        os.killpg(proc.pid, signal.SIGINT)
        assert proc.wait(HANG) == 0, (tmp_path / "server.log").read_text()
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)
        log.close()
    saved = json.loads((tmp_path / "runs" / run_id / "run.json").read_text())
    assert saved["state"] == "stopped" and saved["reason"] == "server shut down", saved
    assert (tmp_path / "runs" / run_id / "result.json").is_file()
    with pytest.raises(ProcessLookupError):
        os.kill(worker_pid, 0)
    deadline = time.time() + 60  # multiprocessing's resource tracker exits after the server
    while True:
        left = subprocess.run(["ps", "-o", "pid,args", "--no-headers", "-s", str(proc.pid)],
                              capture_output=True, text=True).stdout.splitlines()
        left = [p for p in left if "<defunct>" not in p]  # exited, not yet reaped by init
        if not left or time.time() > deadline:
            break
        time.sleep(0.2)
    assert left == [], left  # nothing left running in the session (no new solver)
    assert "solver process died" not in (tmp_path / "server.log").read_text()


def test_token_is_required_and_checked_as_bytes(tmp_path):
    """With a token every request needs it (query, then cookie; or a Bearer header); a wrong
    or non-ASCII one is a 401, never a 500. (No lifespan: the check comes first.)"""
    settings = Settings(scenes_dir=tmp_path, runs_dir=tmp_path / "runs", viewer=False,
                        token="s3cret")
    client = TestClient(create_app(settings))
    assert client.get("/static/style.css").status_code == 401
    assert client.get("/static/style.css?token=wrong").status_code == 401
    assert client.get("/static/style.css?token=%C3%BC%00").status_code == 401
    r = client.get("/static/style.css", headers={"Authorization": "Bearer \u00fc".encode()})
    assert r.status_code == 401, r.text
    r = client.get("/static/style.css", headers={"Authorization": b"Bearer \xff\xfe"})
    assert r.status_code == 401, r.text
    assert client.get("/static/style.css?token=s3cret").status_code == 200
    assert client.get("/static/style.css").status_code == 200  # the cookie it set
    fresh = TestClient(create_app(settings))
    assert fresh.get("/static/style.css", headers={"Authorization": "Bearer s3cret"}
                     ).status_code == 200


def serve_args(*argv):
    import argparse

    from server.cli import add_parser

    ap = argparse.ArgumentParser()
    add_parser(ap.add_subparsers(dest="cmd"))
    return ap.parse_args(["serve", *argv])


def test_serve_refuses_other_hosts_without_a_token(monkeypatch, capsys):
    from server.cli import cmd_serve

    monkeypatch.delenv("Q3T_TOKEN", raising=False)
    assert cmd_serve(serve_args("--host", "0.0.0.0")) == 2
    assert "refusing to serve on 0.0.0.0 without a token" in capsys.readouterr().err
    assert cmd_serve(serve_args("--host", "192.168.1.5", "--token", "\u00fcber")) == 2
    assert "printable ASCII" in capsys.readouterr().err


def test_health_counts_a_long_recording_repair_as_alive(env, monkeypatch):
    """The bridge repairs a killed solver's recording itself (rerun rrd merge, up to minutes on
    a long run): health reports the repair, not a dead bridge, while it lasts."""
    from server.bridge import HEARTBEAT_S
    from server.records import Run

    client, _ = env
    m = client.app.state.manager
    seen = {}

    def slow_repair(path):  # the heartbeat is long stale when health is asked
        monkeypatch.setattr(m.bridge, "heartbeat", m.bridge.heartbeat - 10 * HEARTBEAT_S)
        seen["health"] = m.health()

    monkeypatch.setattr("server.recording.repair", slow_repair)
    assert m.repair(Run("r-repair", "tiny", "q3t", {}, 0.0)) == ""
    assert seen["health"]["bridge_alive"] and seen["health"]["repairing_recording"] == "r-repair"
    after = m.health()
    assert after["bridge_alive"] and after["repairing_recording"] is None


def _nested(depth: int) -> str:
    return "[" * depth + "]" * depth


@pytest.mark.parametrize("method,url,body,words", [
    # TOML nested past Python's recursion limit (tomllib recurses once per level)
    ("post", "/api/scenes/validate", {"toml": "a = " + _nested(5000)}, ["TOML", "nested"]),
    ("post", "/api/scenes", {"name": "deep", "toml": "a = " + _nested(5000)}, ["nested"]),
    ("put", "/api/scenes/deep", {"toml": "a = " + _nested(5000)}, ["nested"]),
    # nested less than that, but deeper than any scene: the walks after the parser overflow
    ("put", "/api/scenes/deep", {"toml": "a = " + _nested(100)}, ["a.0.0", "nested"]),
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
    body = '{"scene": {"description": ' + _nested(depth) + "}}"
    r = client.post("/api/scenes/render", content=body,
                    headers={"Content-Type": "application/json"})
    assert r.status_code == 422, r.text
    assert "nested deeper than 32 levels" in r.json()["detail"]


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


def test_scene_errors_name_the_field_without_pydantic_noise(env):
    client, _ = env
    r = client.post("/api/runs", json={"scene": "tiny", "overrides": {"": 1}})
    assert r.status_code == 422 and r.json()["detail"].startswith('"": an override key'), r.text
    r = client.post("/api/runs", json={"scene": "tiny", "element": "nonesuch"})
    assert r.json()["detail"].startswith("shell.element: unknown 'nonesuch'"), r.text
    r = client.post("/api/scenes/validate", json={"toml": '"" = 1\n' + tiny_toml()})
    assert r.json()["detail"] == '"": Extra inputs are not permitted', r.text


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


def test_sigterm_stops_the_server_cleanly(tmp_path):
    """SIGTERM (systemd, docker stop, kill): the server shuts down as on Ctrl-C, exits 0, and
    multiprocessing's exit handlers run (no "leaked semaphore objects" warning)."""
    import subprocess
    import sys

    import httpx

    (tmp_path / "scenes").mkdir()
    (tmp_path / "scenes" / "tiny.toml").write_text(tiny_toml())
    port = free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "sim.apps", "serve", "tiny", "--port", str(port), "--no-viewer",
         "--scenes-dir", str(tmp_path / "scenes"), "--runs-dir", str(tmp_path / "runs")],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        deadline = time.time() + 120
        while True:  # up, and the solver process too (it owns the queues' other ends)
            try:
                if httpx.get(f"http://127.0.0.1:{port}/api/config", timeout=1).json()["ready"]:
                    break
            except httpx.HTTPError:
                pass
            assert time.time() < deadline and proc.poll() is None
            time.sleep(0.2)
        proc.terminate()
        out, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)
    assert proc.returncode == 0, out.decode()
    assert b"leaked semaphore" not in out, out.decode()


def test_a_scene_file_put_there_by_hand_never_breaks_the_list(env):
    """A scene file that is not UTF-8, or nested past the parser's recursion, or named so that
    no request could address it: the list still answers (the first two as not valid), reading
    the bad one is a 422 naming why."""
    client, settings = env
    bad = {"latin1.toml": "description = 'Gr\xfc\xdfe'".encode("latin-1"),
           "deep.toml": ("a = " + _nested(5000)).encode(), "has space.toml": b"x = 1"}
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

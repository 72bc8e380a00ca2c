"""Every run writes runs/<id>/run.rrd from the solver process: it verifies with the rerun CLI
and reads back the probe series step by step (the punch force of a press), matching the run's
records, with the sheet mesh every ``record_every`` steps. Whichever process is killed - the
solver that records, the server, or both - the file verifies afterwards. Its channels are those
the model built, and no shipped scene has a channel for an absent quantity."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np
import pytest

pytest.importorskip("rerun")
from fastapi.testclient import TestClient  # noqa: E402
from rerun.chunk import RrdReader  # noqa: E402

from server.app import create_app  # noqa: E402
from server.cli import play_command  # noqa: E402
from server.recording import Recorder, channels  # noqa: E402
from server.settings import Settings  # noqa: E402
from sim.model.build import build_model  # noqa: E402
from sim.scene.load import load_scene, scene_from_toml  # noqa: E402
from sim.stepping.simulation import Simulation  # noqa: E402
from tests.support import ROOT  # noqa: E402
from tests.support.recording import series, sheet_steps  # noqa: E402
from tests.support.scenes import PRESS_TOML, SCENES, coarsest_mesh, tiny_toml  # noqa: E402
from tests.support.service import HANG, free_port, until, wait_state, wait_step  # noqa: E402

RERUN = Path(sys.executable).with_name("rerun")


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("recording")
    os.environ.setdefault("XDG_CONFIG_HOME", str(tmp / "config"))
    os.environ.setdefault("XDG_DATA_HOME", str(tmp / "data"))
    if RERUN.exists():  # the config lives in the temporary XDG_CONFIG_HOME
        subprocess.run([str(RERUN), "analytics", "disable"], capture_output=True, timeout=HANG)
    (tmp / "scenes").mkdir()
    (tmp / "scenes" / "tiny.toml").write_text(tiny_toml(steps=5))
    (tmp / "scenes" / "press.toml").write_text(PRESS_TOML)
    (tmp / "scenes" / "long.toml").write_text(tiny_toml(steps=2000))
    settings = Settings(scenes_dir=tmp / "scenes", runs_dir=tmp / "runs", viewer=False,
                        record_every=2)
    with TestClient(create_app(settings)) as c:
        yield c, settings


def verify(path: Path) -> subprocess.CompletedProcess:
    if not RERUN.exists():
        pytest.skip("the rerun CLI is not installed next to python")
    return subprocess.run([str(RERUN), "rrd", "verify", str(path)], capture_output=True,
                          text=True, timeout=HANG)


def assert_verifies(path: Path) -> None:
    r = verify(path)
    assert r.returncode == 0, r.stderr


def test_recording_verifies_and_reads_back_the_punch_force(client):
    c, settings = client
    run_id = c.post("/api/runs", json={"scene": "press", "element": "linear"}).json()["id"]
    st = wait_state(c, run_id, {"finished", "failed", "stopped"})
    assert st["state"] == "finished", st["reason"]
    path = settings.runs_dir / run_id / "run.rrd"
    assert_verifies(path)
    force = series(path, "/probes/punch_force")
    want = {r["step"]: r["probes"]["punch_force"] for r in st["records"]}
    assert sorted(force) == [1, 2, 3] and force == pytest.approx(want, rel=1e-6)
    assert all(v > 0 for v in force.values())  # the punch presses: a real force, not zeros
    assert sorted(series(path, "/solver/iterations")) == [1, 2, 3]
    assert sorted(series(path, "/solver/max_thinning_pct")) == [0, 1, 2, 3]
    assert sheet_steps(path) == [0, 2, 3]  # every record_every = 2 steps, and the last


def test_sheet_triangles_are_stored_once(client):
    """The triangles are static: one copy, however many meshes are recorded."""
    c, settings = client
    run_id = c.post("/api/runs", json={"scene": "tiny", "element": "linear"}).json()["id"]
    assert wait_state(c, run_id, {"finished", "failed", "stopped"})["state"] == "finished"
    path = settings.runs_dir / run_id / "run.rrd"
    assert sheet_steps(path) == [0, 2, 4, 5]
    tri = 0
    for chunk in RrdReader(str(path)).stream():
        rb = chunk.to_record_batch()
        if str(chunk.entity_path) == "/sheet" and "Mesh3D:triangle_indices" in rb.schema.names:
            tri += sum(v.is_valid for v in rb.column("Mesh3D:triangle_indices"))
    assert tri == 1


def test_killed_solver_leaves_a_verifiable_recording(client):
    """The solver process records: SIGKILL it mid-run and the server repairs the file."""
    c, settings = client
    run_id = c.post("/api/runs", json={"scene": "long", "element": "linear"}).json()["id"]
    wait_step(c, run_id, 3)
    os.kill(c.get("/api/health").json()["worker_pid"], signal.SIGKILL)
    st = wait_state(c, run_id, {"failed"})
    assert "killed by signal 9" in st["reason"]
    path = settings.runs_dir / run_id / "run.rrd"
    assert_verifies(path)
    assert len(series(path, "/probes/tip_deflection")) >= 3
    assert sheet_steps(path)[0] == 0


def start_server(tmp: Path, log_name: str) -> tuple[subprocess.Popen, str]:
    port = free_port()
    log = open(tmp / log_name, "wb")  # noqa: SIM115 - the child keeps it; closed with the test
    proc = subprocess.Popen(
        [sys.executable, "-m", "sim.apps", "serve", "long", "--port", str(port), "--no-viewer",
         "--scenes-dir", str(tmp / "scenes"), "--runs-dir", str(tmp / "runs")],
        stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)})
    log.close()
    url = f"http://127.0.0.1:{port}"
    deadline = time.time() + HANG
    while True:
        try:
            if httpx.get(url + "/api/health", timeout=1).json()["ok"]:
                return proc, url
        except httpx.HTTPError:
            pass
        if time.time() > deadline or proc.poll() is not None:
            os.killpg(proc.pid, signal.SIGKILL)
            raise AssertionError((tmp / log_name).read_text())
        time.sleep(0.2)


def run_to_step(url: str, step: int) -> tuple[str, int]:
    run_id = httpx.post(url + "/api/runs", json={"scene": "long", "element": "linear"}).json()
    run_id = run_id["id"]
    until(lambda: httpx.get(f"{url}/api/runs/{run_id}").json()["step"] >= step,
          f"run {run_id} did not reach step {step}")
    return run_id, httpx.get(url + "/api/health").json()["worker_pid"]


def wait_gone(pid: int, what: str) -> None:
    def dead() -> bool:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        return False

    until(dead, what)


def _every_record(client, run_id: str) -> dict:
    """The run's status with all its records, page after page: a loaded machine lets the
    tiny run step past one page (1,713 steps once) between the step the test waits for and
    the SIGKILL."""
    st = client.get(f"/api/runs/{run_id}").json()
    while st["records_left"]:
        more = client.get(f"/api/runs/{run_id}?since={st['records'][-1]['step']}").json()
        st = {**more, "records": st["records"] + more["records"]}
    return st


def test_killed_server_leaves_verifiable_recordings(tmp_path):
    """SIGKILL the server: its solver process notices, closes the recording and exits.
    SIGKILL server and solver together: the file has no footer; the next server start finds
    the interrupted run, marks it failed and repairs the file."""
    (tmp_path / "scenes").mkdir()
    (tmp_path / "scenes" / "long.toml").write_text(tiny_toml(steps=2000))
    procs = []
    try:
        proc, url = start_server(tmp_path, "server1.log")
        procs.append(proc)
        first, worker = run_to_step(url, 3)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
        wait_gone(worker, "the solver process outlived its server")
        assert_verifies(tmp_path / "runs" / first / "run.rrd")

        proc, url = start_server(tmp_path, "server2.log")
        procs.append(proc)
        second, worker = run_to_step(url, 3)
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(10)
        wait_gone(worker, "the solver process outlived the SIGKILL")
    finally:
        for p in procs:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait(10)
    path = tmp_path / "runs" / second / "run.rrd"
    assert verify(path).returncode != 0  # no footer: this is what needs the repair
    # the first run's solver outlived its server and wrote the result; the second's did not
    result = json.loads((tmp_path / "runs" / first / "result.json").read_text())
    assert len(result["steps"]) >= 3 and not (tmp_path / "runs" / second / "result.json").exists()
    settings = Settings(scenes_dir=tmp_path / "scenes", runs_dir=tmp_path / "runs",
                        viewer=False)
    with TestClient(create_app(settings)) as c:
        lost = {run_id: _every_record(c, run_id) for run_id in (first, second)}
    # the first run's solver said why in its result (the status agrees with it); the second's
    # reason is the server's own
    assert lost[first]["state"] == "failed", lost[first]
    assert lost[first]["reason"] == result["failure"]["reason"] == "the server process died"
    st = lost[second]
    assert st["state"] == "failed" and st["reason"] == "the server stopped during the run", st
    # what the status shows is rebuilt from disk: the result's steps, else the recording's
    assert lost[first]["records"] == result["steps"]
    assert lost[first]["step"] == result["steps"][-1]["step"]
    assert_verifies(path)
    tip = series(path, "/probes/tip_deflection")
    assert len(tip) >= 3
    # a step the SIGKILL cut short has its probes in the recording but not all its solver
    # numbers, and is left out of the records (server.recording.read_steps): at most the last
    rebuilt = {r["step"]: r["probes"]["tip_deflection"] for r in lost[second]["records"]}
    assert rebuilt == {k: v for k, v in tip.items() if k in rebuilt}
    assert set(tip) - set(rebuilt) <= {max(tip)}, (sorted(rebuilt)[-3:], sorted(tip)[-3:])
    assert lost[second]["step"] == max(rebuilt)
    assert all(r["iterations"] > 0 for r in lost[second]["records"])
    saved = json.loads((tmp_path / "runs" / second / "run.json").read_text())
    assert saved["state"] == "failed" and saved["records"] == lost[second]["records"]


def test_a_lost_run_that_finished_reads_finished(tmp_path):
    """The server died after its solver had finished the run but before it heard so: run.json
    still says running, without records; result.json is the truth."""
    run_id = "tiny-linear-20260101-000000-abcd"
    d = tmp_path / "runs" / run_id
    d.mkdir(parents=True)
    (tmp_path / "scenes").mkdir()
    (d / "scene.toml").write_text(tiny_toml(steps=2))
    steps = [{"step": k, "time": k / 2, "iterations": 3, "residual": 1e-9, "energy": -1.0,
              "cutbacks": 0, "probes": {"tip_deflection": -0.001 * k}, "tools": {},
              "friction_change": 0.0} for k in (1, 2)]
    (d / "result.json").write_text(json.dumps({"converged": True, "failure": None,
                                               "steps": steps, "counts": {"dofs": 66}}))
    (d / "run.json").write_text(json.dumps({"id": run_id, "scene": "tiny", "element": "linear",
                                            "overrides": {}, "created": 0.0,
                                            "state": "running", "n_steps": 2}))
    settings = Settings(scenes_dir=tmp_path / "scenes", runs_dir=tmp_path / "runs",
                        viewer=False)
    with TestClient(create_app(settings)) as c:
        st = c.get(f"/api/runs/{run_id}").json()
    assert st["state"] == "finished" and st["reason"] is None, st
    assert st["records"] == steps and st["step"] == 2 and st["counts"] == {"dofs": 66}
    assert json.loads((d / "run.json").read_text())["state"] == "finished"


def test_play_command(tmp_path):
    assert play_command(tmp_path / "a.rrd", web=False, port=9090)[1:] == [str(tmp_path / "a.rrd")]
    web = play_command(tmp_path / "a.rrd", web=True, port=9090)
    assert "--serve-web" in web and web[web.index("--bind") + 1] == "127.0.0.1"


def test_recording_holds_exactly_the_channels_the_model_built(client):
    """The entity paths of a real recording are those ``channels`` predicts from the model's
    ``built`` outputs: an elastic scene without tools records no tool, plastic or contact
    channel."""
    c, settings = client
    run_id = c.post("/api/runs", json={"scene": "tiny", "element": "q3t"}).json()["id"]
    st = wait_state(c, run_id, {"finished", "failed", "stopped"})
    assert st["state"] == "finished", st["reason"]
    paths = {str(ch.entity_path).lstrip("/") for ch in RrdReader(str(settings.runs_dir / run_id
                                                                     / "run.rrd")).stream()}
    paths = {p for p in paths if not p.startswith("__")}  # rerun's own properties
    outputs = build_model(scene_from_toml(tiny_toml(steps=3))).built["outputs"]
    assert paths == set(channels(outputs))
    assert "sheet" in paths and "probes/tip_deflection" in paths
    assert not any(p.startswith("tools") or "plastic" in p or "contact" in p for p in paths)


TOOL_PROBES = {"tool_force", "penetration", "contact_nodes", "tool_position"}


@pytest.mark.parametrize("path", SCENES, ids=[p.stem for p in SCENES])
def test_every_shipped_scene_records_no_channel_for_an_absent_quantity(path):
    sc = load_scene(path)
    sim = Simulation.from_scene(load_scene(path, coarsest_mesh(sc)))
    ch = channels(sim.model.built["outputs"])
    tools = {t.name for t in sc.tools}
    plastic = sc.material.model == "plastic"
    assert len(ch) == len(set(ch))
    assert {p.split("/", 1)[1] for p in ch if p.startswith("tools/")} == tools
    for p in sc.probes:  # a tool's force, contact or position only where the tool exists
        if p.kind in TOOL_PROBES:
            assert p.tool in tools
        assert p.kind != "plastic_strain" or plastic
    assert ("solver/max_eq_plastic_strain_pct" in ch) == plastic
    if not plastic:
        assert not any("plastic" in c for c in ch)
    if not tools:
        assert not any(c.startswith("tools/") or "punch" in c or "contact" in c or "holder"
                       in c or "penetration" in c for c in ch)
    # the frame the recorder colours and summarises carries exactly the fields reported
    assert list(sim.frame().fields) == sim.model.built["outputs"]["frame_fields"]


def test_replay_reads_back_tool_rotations(tmp_path):
    """A turning tool's rotation is recorded with its translation and read back per step (the
    viewer and `q3t play --viser` turn the tool mesh with it); a step between records has the
    latest one."""
    from server import replay

    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    rec = Recorder(tmp_path / "run.rrd", "turn")
    rec.meta(np.array([[0, 1, 2]]), [{"name": "lid", "vertices": V, "faces": [[0, 1, 2]]}])
    half = 0.3  # a 0.6 rad turn about y
    turned = np.array([np.cos(half), 0.0, np.sin(half), 0.0])
    for k, q in enumerate([[1.0, 0, 0, 0], turned]):
        rec.frame({"step": 2 * k, "time": float(k), "positions": V,
                   "fields": {"thickness_mm": np.ones(3, np.float32)},
                   "tools": {"lid": [0.0, 0.0, -0.01 * k]}, "tool_rotations": {"lid": q}},
                  mesh=k == 0)
    rec.close()
    rep = replay.load(tmp_path / "run.rrd")
    # float32 in the file: 1e-7 is its resolution for a unit quaternion
    assert np.allclose(rep.rotation("lid", 0), [1, 0, 0, 0], atol=1e-7)
    assert np.allclose(rep.rotation("lid", 2), turned, atol=1e-7)
    assert np.allclose(rep.rotation("lid", 1), [1, 0, 0, 0], atol=1e-7)  # latest before 1
    assert np.isclose(rep.pose("lid", 2)[2], -0.01, atol=1e-9)

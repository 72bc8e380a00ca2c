"""Every run writes runs/<id>/run.rrd: it verifies with the rerun CLI and reads back the probe
series step by step, matching the run's records; a killed solver still leaves a readable file."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("rerun")
from fastapi.testclient import TestClient  # noqa: E402
from rerun.chunk import RrdReader  # noqa: E402

from server.app import create_app  # noqa: E402
from server.cli import play_command  # noqa: E402
from server.settings import Settings  # noqa: E402
from tests.test_service import tiny_toml, wait_state  # noqa: E402

RERUN = Path(sys.executable).with_name("rerun")


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("recording")
    os.environ.setdefault("XDG_CONFIG_HOME", str(tmp / "config"))
    os.environ.setdefault("XDG_DATA_HOME", str(tmp / "data"))
    if RERUN.exists():  # the config lives in the temporary XDG_CONFIG_HOME
        subprocess.run([str(RERUN), "analytics", "disable"], capture_output=True, timeout=30)
    (tmp / "scenes").mkdir()
    (tmp / "scenes" / "tiny.toml").write_text(tiny_toml(steps=3))
    (tmp / "scenes" / "long.toml").write_text(tiny_toml(steps=200))
    settings = Settings(scenes_dir=tmp / "scenes", runs_dir=tmp / "runs", viewer=False)
    with TestClient(create_app(settings)) as c:
        yield c, settings


def series(path: Path, entity: str) -> dict[int, float]:
    out = {}
    for chunk in RrdReader(str(path)).stream():
        if str(chunk.entity_path) == entity:
            rb = chunk.to_record_batch()
            for step, v in zip(rb.column("step").to_pylist(),
                               rb.column("Scalars:scalars").to_pylist(), strict=True):
                out[step] = v[0]
    return out


def verify(path: Path) -> None:
    if not RERUN.exists():
        pytest.skip("the rerun CLI is not installed next to python")
    r = subprocess.run([str(RERUN), "rrd", "verify", str(path)], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0, r.stderr


def test_recording_verifies_and_reads_back_probes(client):
    c, settings = client
    run_id = c.post("/api/runs", json={"scene": "tiny", "element": "linear"}).json()["id"]
    st = wait_state(c, run_id, {"finished", "failed", "stopped"})
    assert st["state"] == "finished", st["reason"]
    path = settings.runs_dir / run_id / "run.rrd"
    verify(path)
    tip = series(path, "/probes/tip_deflection")
    want = {r["step"]: r["probes"]["tip_deflection"] for r in st["records"]}
    assert tip == pytest.approx(want)
    assert sorted(series(path, "/solver/iterations")) == [1, 2, 3]
    assert sorted(series(path, "/solver/max_thinning_pct")) == [0, 1, 2, 3]
    meshes = [ch for ch in RrdReader(str(path)).stream() if str(ch.entity_path) == "/sheet"]
    assert meshes, "no sheet mesh in the recording"


def test_killed_solver_leaves_a_readable_recording(client):
    c, settings = client
    run_id = c.post("/api/runs", json={"scene": "long", "element": "linear"}).json()["id"]
    deadline = time.time() + 30
    while c.get(f"/api/runs/{run_id}").json()["step"] < 2 and time.time() < deadline:
        time.sleep(0.05)
    os.kill(c.get("/api/health").json()["worker_pid"], signal.SIGKILL)
    wait_state(c, run_id, {"failed"}, timeout=20)
    path = settings.runs_dir / run_id / "run.rrd"
    verify(path)
    assert len(series(path, "/probes/tip_deflection")) >= 2


def test_play_command(tmp_path):
    assert play_command(tmp_path / "a.rrd", web=False, port=9090)[1:] == [str(tmp_path / "a.rrd")]
    web = play_command(tmp_path / "a.rrd", web=True, port=9090)
    assert "--serve-web" in web and web[web.index("--bind") + 1] == "127.0.0.1"


def test_recording_has_no_channels_for_absent_quantities(client):
    """An elastic scene without tools records no tool, no plastic and no contact channel: the
    channels follow what the scene built (issue: compute only what a scene needs)."""
    c, settings = client
    run_id = c.post("/api/runs", json={"scene": "tiny", "element": "q3t"}).json()["id"]
    st = wait_state(c, run_id, {"finished", "failed", "stopped"})
    assert st["state"] == "finished", st["reason"]
    paths = {str(ch.entity_path) for ch in RrdReader(str(settings.runs_dir / run_id
                                                          / "run.rrd")).stream()}
    assert "/sheet" in paths and "/probes/tip_deflection" in paths
    assert not any(p.startswith("/tools") for p in paths)
    assert not any("plastic" in p or "contact" in p or "punch" in p for p in paths)

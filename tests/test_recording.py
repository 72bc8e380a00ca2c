"""Every run writes runs/<id>/run.rrd: it verifies with the rerun CLI and reads back the probe
series step by step, matching the run's records; a killed solver still leaves a readable file; its
channels are those the model built, and no shipped scene has a channel for an absent quantity."""

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
from server.recording import channels  # noqa: E402
from server.settings import Settings  # noqa: E402
from sim.model import build_model  # noqa: E402
from sim.scene import load_scene, scene_from_toml  # noqa: E402
from sim.simulation import Simulation  # noqa: E402
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


SCENES = sorted((Path(__file__).resolve().parent.parent / "scenes").glob("*.toml"))
TOOL_PROBES = {"tool_force", "penetration", "contact_nodes", "tool_position"}


def _coarse(sc) -> dict:
    """About 20-60 triangles: the channel list depends on the scene, not on the mesh."""
    m = sc.mesh
    edge = {"rectangle": lambda: max(m.size or (0,)) / 8, "disk": lambda: m.r_outer / 4,
            "annulus": lambda: m.r_outer / 4, "cylinder_band": lambda: m.height / 2}
    return {"mesh.edge_length": edge[m.kind]()} if m.kind in edge else {}


@pytest.mark.parametrize("path", SCENES, ids=[p.stem for p in SCENES])
def test_every_shipped_scene_records_no_channel_for_an_absent_quantity(path):
    sc = load_scene(path)
    sim = Simulation.from_scene(load_scene(path, _coarse(sc)))
    ch = channels(sim.model.built["outputs"])
    tools = {t.name for t in sc.tools}
    plastic = sc.material.model == "plastic"
    assert len(ch) == len(set(ch))
    assert {p.split("/", 1)[1] for p in ch if p.startswith("tools/")} == tools
    for p in sc.probes:  # a tool's force, contact or position only where the tool exists
        if p.kind in TOOL_PROBES:
            assert p.tool in tools
        assert p.kind != "plastic_strain" or plastic
    assert ("solver/max_eq_plastic_strain" in ch) == plastic
    if not plastic:
        assert not any("plastic" in c for c in ch)
    if not tools:
        assert not any(c.startswith("tools/") or "punch" in c or "contact" in c or "holder"
                       in c or "penetration" in c for c in ch)
    # the frame the recorder colours and summarises carries exactly the fields reported
    assert list(sim.frame().fields) == sim.model.built["outputs"]["frame_fields"]

"""A run with tools through the service (TestClient, viser viewer on, no browser): a 20 x 20 mm,
0.5 mm plastic plate on a ground plane, pressed 0.2 mm by a punch in 3 steps. The run finishes,
frames carry every field (plastic strain included) and the tools' translations, the punch moves
down step by step, the viewer draws one mesh per tool and moves it, offers every field in its
dropdown and scrubs kept frames, and the recording holds the tool meshes and transforms (read
back, and replayed by ``q3t play --viser``'s loader and by the service's viewer, which shows
the selected run); the viewer's Pause/Resume/Step/Stop buttons drive the selected run and never
start one (pressed through viser's server-side handles of one connected browser's view)."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("viser")
pytest.importorskip("rerun")
from fastapi.testclient import TestClient  # noqa: E402
from rerun.chunk import RrdReader  # noqa: E402

from server.app import create_app  # noqa: E402
from server.colormap import FAILURE_PCT, MARGINAL_PCT  # noqa: E402
from server.history import FrameHistory  # noqa: E402
from server.settings import Settings  # noqa: E402
from tests.support.scenes import PRESS_TOML, tiny_toml  # noqa: E402
from tests.support.service import (  # noqa: E402
    HANG,
    free_port,
    stop_all,
    until,
    wait_done,
    wait_state,
    wait_step,
)
from tests.support.viewer import attached  # noqa: E402

# a plastic scene's frame: its major and minor strain too (forming limits), no FLD zone
# without a forming limit curve
FIELDS = {"thickness_mm", "thinning_pct", "von_mises_MPa", "eq_plastic_strain_pct",
          "major_strain_pct", "minor_strain_pct"}


@pytest.fixture(scope="module")
def done(tmp_path_factory):
    """One finished press run: (client, settings, run status)."""
    tmp = tmp_path_factory.mktemp("viewer")
    os.environ.setdefault("XDG_CONFIG_HOME", str(tmp / "config"))
    os.environ.setdefault("XDG_DATA_HOME", str(tmp / "data"))
    (tmp / "scenes").mkdir()
    (tmp / "scenes" / "press.toml").write_text(PRESS_TOML)
    (tmp / "scenes" / "long.toml").write_text(tiny_toml(steps=4000))
    settings = Settings(scenes_dir=tmp / "scenes", runs_dir=tmp / "runs", viewer=True,
                        viewer_port=free_port(), record_every=2)
    with TestClient(create_app(settings)) as client:
        r = client.post("/api/runs", json={"scene": "press", "element": "linear"})
        assert r.status_code == 201, r.text
        st = wait_state(client, r.json()["id"], {"finished", "failed", "stopped"})
        assert st["state"] == "finished", st["reason"]
        yield client, settings, st


@pytest.fixture(scope="module")
def viewer(done):
    """A browser's view (no view id: the default view, which the API selects for)."""
    with attached(done[0].app.state.manager.viewer) as cv:
        yield cv


def test_tool_run_frames_and_poses(done):
    client, _, st = done
    run = st["id"]
    assert st["tools"] == ["ground", "punch"]
    assert [r["step"] for r in st["records"]] == [1, 2, 3]
    assert {"build_s", "tool_meshes_s", "first_frame_s"} <= set(st["timing"])
    kept = client.get(f"/api/runs/{run}/frames").json()
    # the rest state and the last frame always arrive; a frame between may be dropped when
    # the server is slower than the solver (by design, server.worker: a loaded machine kept
    # [0, 3] once, the last frame's message overtaking the two queued before it)
    steps = kept["steps"]
    assert steps[0] == 0 and steps[-1] == 3 and set(steps) <= {0, 1, 2, 3}, steps
    assert kept["stride"] == 1
    frames = [client.get(f"/api/runs/{run}/frames/{k}").json() for k in steps]
    for f in frames:
        assert set(f["fields"]) == FIELDS
        assert f["fields"]["thickness_mm"]["min"] > 0
    assert frames[0]["fields"]["eq_plastic_strain_pct"]["max"] == 0.0
    assert frames[-1]["fields"]["eq_plastic_strain_pct"]["max"] > 0.0  # the press yields
    punch_z = [f["tools"]["punch"][2] for f in frames]
    assert np.all(np.diff(punch_z) < 0), punch_z  # the punch moves down every step
    assert punch_z[-1] == pytest.approx(0.00025 - 0.0002, abs=1e-7)
    for f in frames:  # the ground stays put
        assert f["tools"]["ground"] == pytest.approx([0.0, 0.0, -0.00025], abs=1e-9)
    assert st["records"][-1]["probes"]["punch_force"] > 0
    assert client.get("/api/runs/nope-run/frames").status_code == 404


def test_viewer_draws_moves_recolours_and_scrubs(done, viewer):
    client, _, st = done
    # the bridge pushes the last frame to the viewer after the run's state reads finished
    until(lambda: viewer.gui.time.value == 3, "the last frame was not shown")
    last = client.get(f"/api/runs/{st['id']}/frames/3").json()["tools"]
    assert sorted(viewer.canvas.tools) == ["ground", "punch"]
    assert viewer.selected == viewer.gui.run.value == st["id"]  # the new run is selected
    np.testing.assert_allclose(viewer.canvas.tools["punch"].position, last["punch"], atol=1e-9)
    options = viewer.canvas.field.options
    assert len(options) == len(FIELDS) and "Equivalent plastic strain (%)" in options
    assert "Major true strain (%)" in options  # as the FLD gives it
    viewer.canvas.field.value = "Equivalent plastic strain (%)"
    assert "Equivalent plastic strain" in viewer.canvas.legend.content
    viewer.canvas.field.value = "von Mises stress (MPa)"
    assert "MPa" in viewer.canvas.legend.content
    assert viewer.gui.time.value == 3 and viewer.gui.time.max == 3  # followed the live run
    viewer.gui.time.value = 1  # as a user dragging the slider of the finished run
    step1 = client.get(f"/api/runs/{st['id']}/frames/1").json()["tools"]["punch"]
    np.testing.assert_allclose(viewer.canvas.tools["punch"].position, step1, atol=1e-9)
    assert "showing step 1/3" in viewer.gui.status.content
    assert viewer.canvas.frame["step"] == 1


def test_the_viewer_says_probes_in_the_units_the_page_shows():
    """The viewer's status line under a running run's step: each probe in its kind's unit,
    labelled, as the page's plots (kN, mm, %), not the SI number."""
    from server.plots import probe_text

    assert probe_text("punch_force", 151.7, "tool_force") == "punch_force = 0.1517 kN"
    assert probe_text("max_plastic_strain", 0.0123, "plastic_strain") == (
        "max_plastic_strain = 1.23 %")
    assert probe_text("travel", -0.0002, "displacement") == "travel = -0.2 mm"
    assert probe_text("contacts", 12.0, "contact_nodes") == "contacts = 12"
    assert probe_text("old", 151.7, None) == "old = 151.7"  # a run before kinds were kept


def tool_chunks(path: Path) -> tuple[dict, dict]:
    """Static tool meshes (name -> vertex count) and translations (name -> {step: xyz})."""
    meshes, poses = {}, {}
    for chunk in RrdReader(str(path)).stream():
        entity = str(chunk.entity_path)
        if not entity.startswith("/tools/"):
            continue
        rb, name = chunk.to_record_batch(), entity.removeprefix("/tools/")
        if "Mesh3D:vertex_positions" in rb.schema.names:
            meshes[name] = len(rb.column("Mesh3D:vertex_positions")[0])
        if "Transform3D:translation" in rb.schema.names:
            for step, t in zip(rb.column("step").to_pylist(),
                               rb.column("Transform3D:translation").to_pylist(), strict=True):
                poses.setdefault(name, {})[step] = t[0]
    return meshes, poses


def test_recording_has_tool_meshes_and_transforms(done):
    client, settings, st = done
    path = settings.runs_dir / st["id"] / "run.rrd"
    meshes, poses = tool_chunks(path)
    assert set(meshes) == {"ground", "punch"} and meshes["punch"] > 100
    assert sorted(poses["punch"]) == [0, 1, 2, 3]
    for k in range(4):
        want = client.get(f"/api/runs/{st['id']}/frames/{k}").json()["tools"]["punch"]
        assert poses["punch"][k] == pytest.approx(want, abs=1e-9)


def test_replay_loads_the_recording(done):
    from server import replay

    _, settings, st = done
    rep = replay.load(settings.runs_dir / st["id"] / "run.rrd")
    assert rep.steps == [0, 2, 3] and rep.faces is not None  # record_every = 2, and the last
    assert all(p.shape == rep.positions[0].shape for p in rep.positions)
    assert sorted(rep.tools) == ["ground", "punch"]
    assert rep.pose("punch", 3)[2] < rep.pose("punch", 0)[2]
    server = replay.serve(rep, port=free_port(), block=False)
    server.stop()


def test_history_keeps_every_kth_frame_past_the_cap():
    h = FrameHistory(max_frames=10)
    h.reset("r")

    def frame(k: int, run: str = "r") -> dict:
        return {"run": run, "step": k, "time": float(k), "positions": np.zeros((5, 3)),
                "fields": {"thickness_mm": np.full(5, k, np.float32)}}

    for k in range(38):
        h.add(frame(k))
    h.add(frame(99, run="other"))  # another run's frame is ignored
    s = h.summary()
    assert s["steps"] == [0, 8, 16, 24, 32, 37] and s["stride"] == 8  # even spacing + newest
    assert h.at(13)["step"] == 8 and h.at(1000)["step"] == 37
    h.add(frame(38))
    assert h.summary()["steps"][-2:] == [32, 38]  # the old newest (off the grid) made way
    h.add(frame(38))  # a frame kept already is not kept twice
    assert h.summary()["steps"][-2:] == [32, 38]
    late = FrameHistory(max_frames=10)  # the rest frame after step 1 (it came by the other queue)
    late.reset("r")
    for k in (1, 0, 2, 3):
        late.add(frame(k))
    assert late.summary()["steps"] == [0, 1, 2, 3] and late.at(0)["step"] == 0
    small = FrameHistory(max_frames=400, max_bytes=5 * 80)  # 80 bytes a frame
    small.reset("r")
    for k in range(20):
        small.add(frame(k))
    assert small.summary()["bytes"] <= 5 * 80


def test_viewer_buttons_drive_the_run(done, viewer):
    """Pause, Step, Resume and Stop pressed in the viewer act on the selected run
    (``button.value = True`` runs the click handlers, as a click from a browser does); none
    starts a run, and they are disabled once the run is over."""
    client, _, _ = done
    b = viewer.gui.buttons
    assert list(b) == ["Pause", "Resume", "Step", "Stop"]  # the page's words, in its order
    run = client.post("/api/runs", json={"scene": "long", "element": "linear"}).json()["id"]
    status = lambda: client.get(f"/api/runs/{run}").json()  # noqa: E731
    try:
        wait_step(client, run, 2)
        assert not b["Pause"].disabled
        b["Pause"].value = True
        assert viewer.gui.status.content.startswith("pause: ")
        st = wait_done(client, run)  # the step under way when Pause arrived, then paused
        assert st["state"] == "paused", st
        at = st["step"]
        b["Step"].value = True
        st = wait_done(client, run)  # the solver made the step it was asked for
        assert st["step"] == at + 1 and st["state"] == "paused", st  # one step, still paused
        b["Resume"].value = True
        until(lambda: status()["step"] > at + 3 and status()["state"] == "running", "Resume")
        b["Stop"].value = True
        assert wait_state(client, run, {"stopped", "finished", "failed"})["state"] == "stopped"
        until(lambda: b["Resume"].disabled, "the buttons stayed enabled after the run ended")
        b["Resume"].value = True  # pressed anyway (a stale client): refused, no new run
        assert "not active" in viewer.gui.status.content, viewer.gui.status.content
        assert client.get("/api/health").json()["active"] == []
        assert [r["id"] for r in client.get("/api/runs").json()][0] == run
    finally:
        stop_all(client)


def test_viewer_replays_an_older_recorded_run(done, viewer):
    """Selecting an older run (the viewer's "Run" dropdown) shows its recording, the time
    slider scrubs it, and selecting the latest run shows it live again."""
    from server import replay

    client, settings, st = done
    until(lambda: st["id"] in viewer.gui.run.options, "the run is not offered")
    latest = viewer.v.live_run
    assert latest != st["id"], "needs a later run (test_viewer_buttons_drive_the_run)"
    rep = replay.load(settings.runs_dir / st["id"] / "run.rrd")
    viewer.gui.run.value = st["id"]  # as a user picking it
    assert client.get("/api/view").json()["run"] == st["id"]  # the page follows
    until(lambda: viewer.mode == "replay", "the recording was not shown")  # read in background
    assert viewer.replay.steps == [0, 2, 3]
    # the recording holds the field values: coloured on the viewer's scales, not as recorded
    assert set(viewer.replay.fields[-1]) == FIELDS
    assert "as recorded" not in viewer.gui.status.content
    assert viewer.gui.time.max == 3 and viewer.gui.time.value == 3
    assert sorted(viewer.canvas.tools) == ["ground", "punch"]
    viewer.gui.time.value = 1  # recorded at 0 and 2: shows 0, the nearest before
    assert viewer.gui.status.content.endswith("showing recorded step 0")
    assert viewer.gui.time.value == 0  # and the slider's box says so
    viewer.gui.time.value = 1  # on by one from 0: the next recorded frame, not back to 0
    assert viewer.gui.status.content.endswith("showing recorded step 2")
    assert viewer.gui.time.value == 2
    viewer.gui.time.value = 0
    np.testing.assert_allclose(viewer.canvas.tools["punch"].position, rep.pose("punch", 0),
                               atol=1e-9)
    viewer.gui.time.value = 2
    assert viewer.gui.status.content.endswith("showing recorded step 2")
    np.testing.assert_allclose(viewer.canvas.tools["punch"].position, rep.pose("punch", 2),
                               atol=1e-9)
    assert rep.pose("punch", 2)[2] < rep.pose("punch", 0)[2]
    # Play: from the last step, back to the start and through the recorded frames, the page
    # told each step; at the end it unticks itself
    assert not viewer.gui.play.disabled  # an ended run plays back
    seen: list[int] = []
    viewer.gui.time.on_update(lambda _e: seen.append(int(viewer.gui.time.value)))
    viewer.gui.time.value = 3
    seen.clear()
    viewer.gui.play.value = True  # as a user ticking it
    until(lambda: not viewer.gui.play.value, "Play never reached the end")
    # the recorded frames in order (a step the slider passed through snaps to one)
    assert seen[0] == 0 and seen[-1] == 3 and seen == sorted(seen) and 2 in seen, seen
    assert viewer.gui.status.content.endswith("showing recorded step 3")
    # ticked and unticked at once, then ticked: only the newest tick's play moves on, and
    # another run chosen while it plays unticks it
    viewer.gui.play.value = True
    viewer.gui.play.value = False
    viewer.gui.play.value = True
    assert viewer.plays >= 3
    viewer.gui.run.value = latest
    until(lambda: not viewer.gui.play.value, "Play stayed ticked for another run")
    assert viewer.mode == "live" and viewer.replay is None
    assert client.get("/api/view").json()["run"] == latest


def test_a_users_choice_counts_while_the_code_updates_the_viewer(done, viewer):
    """viser runs the callbacks of a value set in code in the thread that set it; the code's
    own updates (the bridge's, in its thread) are told apart per thread, so a user's choice
    made meanwhile is acted on, not taken for an echo of the code's."""
    client, _, st = done
    until(lambda: st["id"] in viewer.gui.run.options, "the run is not offered")
    latest = viewer.v.live_run
    inside, release = threading.Event(), threading.Event()

    def bridge() -> None:  # the bridge, halfway through an update of its own
        with viewer.v.from_code():
            inside.set()
            release.wait(HANG)

    t = threading.Thread(target=bridge)
    t.start()
    try:
        assert inside.wait(HANG)
        viewer.gui.run.value = st["id"]  # a user picks the run meanwhile
        assert client.get("/api/view").json()["run"] == st["id"]
        until(lambda: viewer.mode == "replay", "the recording was not shown")
        viewer.gui.run.value = latest
        assert viewer.mode == "live" and client.get("/api/view").json()["run"] == latest
    finally:
        release.set()
        t.join()


def test_thinning_bands_start_from_the_material_cards_limit(done, viewer):
    """A run whose material card sets a thinning limit (flc.max_thinning 15 %) is coloured
    in bands from it (failure from 15 %, marginal from 7.5 %), as its summary flags from it,
    live and replayed from its recording; a run without one in the defaults; limits a user
    set stay for every run."""
    client, settings, _ = done
    limited = PRESS_TOML.replace('name = "press"', 'name = "press_limit"').replace(
        'hardening = { law = "perfect" }',
        'hardening = { law = "perfect" }\n'
        'flc = { kind = "points", points = [[-0.5, 0.5], [0.5, 0.5]], max_thinning = 0.15 }')
    assert limited != PRESS_TOML
    (settings.scenes_dir / "press_limit.toml").write_text(limited)

    def ran(scene: str) -> str:
        r = client.post("/api/runs", json={"scene": scene, "element": "linear"})
        assert r.status_code == 201, r.text
        run = r.json()["id"]
        assert wait_state(client, run, {"finished", "failed", "stopped"})["state"] == "finished"
        until(lambda: viewer.selected == run and viewer.mode == "live", "not shown")
        return run

    def bands() -> tuple[float, float]:
        c = viewer.canvas
        assert c.palette.thinning.bounds[1:] == (c.colour["marginal"].value,
                                                 c.colour["failure"].value)
        return c.palette.thinning.bounds[1:]

    first = ran("press_limit")
    assert bands() == (7.5, 15.0)
    assert client.get(f"/api/runs/{first}").json()["thinning_limit"] == pytest.approx(15.0)
    latest = ran("press")
    assert bands() == (MARGINAL_PCT, FAILURE_PCT)
    assert client.get(f"/api/runs/{latest}").json()["thinning_limit"] is None
    viewer.gui.run.value = first  # no longer live (one solver): its recording
    until(lambda: viewer.mode == "replay", "the recording was not shown")
    assert bands() == (7.5, 15.0)
    viewer.gui.run.value = latest
    assert viewer.mode == "live" and bands() == (MARGINAL_PCT, FAILURE_PCT)
    viewer.canvas.colour["failure"].value = 25.0  # as a user setting it
    assert bands() == (MARGINAL_PCT, 25.0)
    ran("press_limit")
    assert bands() == (MARGINAL_PCT, 25.0)  # the user's limits stay

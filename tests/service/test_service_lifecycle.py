"""The service's processes and their ends: slow viewers and solvers, errors in the bridge
and the recording, shutdown, Ctrl-C and SIGTERM, tokens and hosts, the health check."""

from __future__ import annotations

import json
import os
import signal
import threading
import time

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
    wait_state,
    wait_step,
)


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
    worker = m.slots[0].worker
    until(lambda: worker.events.qsize() >= need, "the solver did not step")
    assert worker.frames.qsize() == settings.frame_queue  # full, not more
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
        until(lambda: m.slots[0].worker.events.qsize() >= 10,
              "the solver did not finish the run")
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
    assert health["active"] == []
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
        # the Run box's choice before a scene is open: what a scene naming none runs
        assert cfg["default_element"] == "q3t" and "q3t" in cfg["elements"]
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
        worker = m.slots[0].worker
    assert m.restarts == 0 and m.slots[0].worker is worker and not worker.alive()
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

"""A run that cannot go on fails with the reason and a result.json, in strict JSON: whatever
goes wrong while building or stepping (the solver, the command line, the service's solver
process), a record or frame that is not finite, a model too large for the machine (refused
before the build), and a stop while a run is still building."""

from __future__ import annotations

import json
import os
import queue
import time
from pathlib import Path

import numpy as np
import pytest

from sim.apps.cli import main
from sim.elements import ROUTINE
from sim.model import size
from sim.scene.load import SceneError, load_scene
from sim.stepping.simulation import Simulation
from tests.support import ROOT

pytestmark = pytest.mark.fast  # seconds: make test-fast runs it

CANTILEVER = ROOT / "scenes" / "cantilever.toml"
COARSE = {"mesh.edge_length": 0.035, "stepping.steps": 3, "shell.element": "linear"}
DYNAMIC = {**COARSE, "stepping.kind": "dynamic", "stepping.dt": 0.01}


def strict_json(path: Path):
    """The file as JSON, refusing NaN and Infinity tokens as any strict reader does."""
    def refuse(token):
        raise ValueError(f"{path.name} holds {token}")
    return json.loads(path.read_text(), parse_constant=refuse)


def fail_in_inertia(monkeypatch, from_call: int = 1):
    """The inertia term raises what dt = 1e-300 once raised in it (ZeroDivisionError)."""
    from sim.terms import inertia

    real, calls = inertia.Inertia.energy, {"n": 0}

    def energy(self, x):
        calls["n"] += 1
        if calls["n"] >= from_call:
            raise ZeroDivisionError("float division by zero")
        return real(self, x)

    monkeypatch.setattr(inertia.Inertia, "energy", energy)


# ---- the solver -------------------------------------------------------------------------------
def test_an_error_inside_a_step_is_a_failure_naming_it(monkeypatch, tmp_path):
    sim = Simulation.from_scene(load_scene(CANTILEVER, DYNAMIC))
    assert sim.step().step == 1
    fail_in_inertia(monkeypatch)
    assert sim.run() is False
    assert sim.failure["step"] == 2
    assert sim.failure["reason"] == "ZeroDivisionError: float division by zero"
    sim.write(tmp_path)
    res = strict_json(tmp_path / "result.json")
    assert res["converged"] is False and res["failure"]["reason"].startswith("ZeroDivision")
    assert [s["step"] for s in res["steps"]] == [1]  # what was done is kept


def test_a_record_that_is_not_finite_fails_the_step(monkeypatch, tmp_path):
    from sim.frames import probes

    real = probes.evaluate
    monkeypatch.setattr(probes, "evaluate", lambda *a, **k: {**real(*a, **k), "volume": np.nan})
    sim = Simulation.from_scene(load_scene(CANTILEVER, COARSE))
    assert sim.run() is False
    assert sim.failure["step"] == 1 and "not finite: probes.volume" in sim.failure["reason"]
    assert sim.records == []
    sim.write(tmp_path)
    assert strict_json(tmp_path / "result.json")["converged"] is False


def test_a_result_that_is_not_finite_is_written_as_null_and_listed(monkeypatch, tmp_path):
    """The last line of defence: a value that is still not finite (here the timing) becomes
    null, is listed in non_finite, and the run does not count as converged."""
    sim = Simulation.from_scene(load_scene(CANTILEVER, {**COARSE, "stepping.steps": 1}))
    assert sim.run()
    sim.wall = float("inf")
    sim.write(tmp_path)
    res = strict_json(tmp_path / "result.json")
    assert res["timing"]["total"] is None and res["non_finite"] == ["timing.total"]
    assert res["converged"] is False and "timing.total" in res["failure"]["reason"]


# ---- the command line -------------------------------------------------------------------------
@pytest.mark.parametrize("sets,field", [
    (["stepping.kind=dynamic", "stepping.dt=1e-300"], "stepping.dt"),
    (["stepping.kind=dynamic", "stepping.dt=inf"], "stepping.dt"),
    (["shell.thickness=1e308"], "shell.thickness"),
    (["material.E=1e308"], "material.E"),
    (["mesh.edge_length=1e-4"], "mesh.edge_length"),
])
def test_cli_bad_input_exits_2_naming_the_field(tmp_path, capsys, sets, field):
    args = [a for s in sets for a in ("--set", s)]
    assert main(["run", "cantilever", *args, "--out", str(tmp_path / "x")]) == 2
    assert capsys.readouterr().err.startswith(f"q3t: {field}")
    assert not (tmp_path / "x").exists()


def test_cli_run_failing_inside_a_step_exits_1_with_a_result(monkeypatch, tmp_path, capsys):
    fail_in_inertia(monkeypatch, from_call=5)
    args = [a for k, v in DYNAMIC.items() for a in ("--set", f"{k}={v}")]
    assert main(["run", "cantilever", *args, "--quiet", "--out", str(tmp_path)]) == 1
    assert "FAILED: ZeroDivisionError" in capsys.readouterr().err
    assert strict_json(tmp_path / "result.json")["failure"]["reason"].startswith("ZeroDivision")


def test_cli_build_failing_exits_1_with_a_result(monkeypatch, tmp_path, capsys):
    from sim.stepping import simulation

    def broken(scene):
        raise TypeError("a bug in the build")

    monkeypatch.setattr(simulation, "build_model", broken)
    assert main(["run", "cantilever", "--set", "mesh.edge_length=0.035", "--quiet",
                 "--out", str(tmp_path)]) == 1
    assert "build failed: TypeError: a bug in the build" in capsys.readouterr().err
    res = strict_json(tmp_path / "result.json")
    assert res["converged"] is False and res["scene"] == "cantilever"
    assert res["failure"]["reason"] == "build failed: TypeError: a bug in the build"


# ---- the model's size ---------------------------------------------------------------------------
@pytest.mark.parametrize("scene,over", [
    ("cantilever", {}), ("cup_blank", {}), ("cookie_cutter", {}),
    ("cup_blank", {"mesh.kind": "annulus", "mesh.r_inner": 0.01}),
])
@pytest.mark.parametrize("element", ROUTINE)
def test_the_size_estimate_counts_what_the_build_makes(scene, over, element):
    """Vertices and elements exactly (the generators' own rounding), nodes to the few that
    Euler's formula (edges = vertices + faces) misses on the boundary: at most 1 per
    in-plane node row through the thickness for p = 2."""
    sc = load_scene(ROOT / "scenes" / f"{scene}.toml", {**over, "shell.element": element})
    est = size.estimate(sc)
    sim = Simulation.from_scene(sc)
    sh = sim.model.shell
    assert (est.vertices, est.elements) == (sh.n_vertices, len(sh.conn))
    assert 0 <= est.nodes - sh.n_nodes <= sh.element.n_layers


def test_a_model_beyond_the_limit_is_refused_naming_the_edge_length():
    """The issue's reproducer: the cantilever at edge 0.1 mm (4.9 M vertices) is refused at
    once, with the estimate; the default limit lets every shipped scene through."""
    sc = load_scene(CANTILEVER, {"mesh.edge_length": 1e-4})
    with pytest.raises(SceneError) as err:
        size.check(sc, size.DEFAULT_LIMIT)
    msg = str(err.value)
    assert msg.startswith("mesh.edge_length: the model would have about 4910000 vertices")
    assert "44200000 DoFs" in msg and "GiB" in msg
    for path in sorted((ROOT / "scenes").glob("*.toml")):
        size.check(load_scene(path), size.DEFAULT_LIMIT)


# ---- the service's solver process, in this process (as tests/service/test_service.py does) ---
def tiny_toml(**over) -> str:
    text = CANTILEVER.read_text().replace("edge_length = 0.0046667", "edge_length = 0.035")
    return text.replace('name = "cantilever"', 'name = "tiny"')


def run_in_process(tmp_path, run: str, overrides: dict):
    """Start a run on an in-process solver and step it to its end: the solver, its (state,
    reason) events and the run's folder."""
    from server.worker import Solver

    events = queue.Queue()
    solver = Solver(events, queue.Queue(maxsize=4), record_every=1, step_delay=0.0)
    out = tmp_path / run
    out.mkdir()
    solver.handle({"id": 1, "cmd": "start", "run": run, "out": str(out),
                   "scene_toml": tiny_toml(), "overrides": overrides})
    while solver.stepping:
        solver.step()
    states = []
    while not events.empty():
        ev = events.get()
        if ev["kind"] == "state":
            states.append((ev["state"], ev.get("reason")))
    return solver, states, out


def test_an_error_in_a_step_fails_the_run_and_the_solver_goes_on(monkeypatch, tmp_path):
    fail_in_inertia(monkeypatch, from_call=5)
    solver, states, out = run_in_process(tmp_path, "r1", DYNAMIC)
    assert states[-1][0] == "failed" and "ZeroDivisionError" in states[-1][1]
    assert strict_json(out / "result.json")["failure"]["reason"].startswith("ZeroDivision")
    monkeypatch.undo()
    _, states, _ = run_in_process(tmp_path, "r2", COARSE)
    assert states[-1][0] == "finished", states


def test_a_frame_that_is_not_finite_reaches_neither_recording_nor_server(monkeypatch,
                                                                          tmp_path):
    from server import recording

    real_frame = Simulation.frame

    def frame(self):
        f = real_frame(self)
        if f.step == 2:
            f.fields["thickness_mm"][3] = np.nan
        return f

    recorded = []
    real_record = recording.Recorder.frame
    monkeypatch.setattr(Simulation, "frame", frame)
    monkeypatch.setattr(recording.Recorder, "frame", lambda self, fr, mesh=True: (
        recorded.append(fr["step"]), real_record(self, fr, mesh)))
    solver, states, out = run_in_process(tmp_path, "r1", COARSE)
    assert states[-1][0] == "failed" and "not finite in thickness_mm" in states[-1][1]
    assert 2 not in recorded and recorded[:2] == [0, 1]
    assert strict_json(out / "result.json")["converged"] is False


def test_a_build_error_fails_the_run_with_a_result(monkeypatch, tmp_path):
    from sim.stepping import simulation

    def broken(scene):
        raise TypeError("a bug in the build")

    monkeypatch.setattr(simulation, "build_model", broken)
    solver, states, out = run_in_process(tmp_path, "r1", COARSE)
    assert states[-1] == ("failed", "build failed: TypeError: a bug in the build")
    res = strict_json(out / "result.json")
    assert res["failure"]["reason"] == "build failed: TypeError: a bug in the build"
    assert not (out / "run.rrd").exists()  # nothing was recorded


def test_a_meta_that_cannot_be_sent_fails_the_run_naming_it(monkeypatch, tmp_path):
    """The run's model (its meta) must reach the server: one a multiprocessing queue cannot
    pickle would be dropped by the queue's feeder thread, leaving a blank viewer and a run
    with no word on the page. It fails the run, naming why, with its result.json."""
    from server import worker

    real = worker.plotted
    monkeypatch.setattr(worker, "plotted", lambda *a: {**real(*a), "punches": lambda: None})
    solver, states, out = run_in_process(tmp_path, "r1", COARSE)
    assert states[-1][0] == "failed", states
    assert states[-1][1].startswith("sending the run's model to the server failed: ")
    assert "pickle" in states[-1][1]
    assert "failed" not in [s for s, _ in states[:-1]] and solver.sim is None  # not stepped on
    assert strict_json(out / "result.json")["failure"]["reason"] == states[-1][1]


def test_tools_that_cannot_be_shown_are_noted_and_the_run_goes_on_to_its_end(monkeypatch, tmp_path):
    from server import worker

    def broken(*a):
        raise RuntimeError("no surface")

    monkeypatch.setattr(worker, "tool_meshes", broken)
    events = queue.Queue()
    solver = worker.Solver(events, queue.Queue(maxsize=4), record_every=1, step_delay=0.0)
    (tmp_path / "r1").mkdir()
    solver.handle({"id": 1, "cmd": "start", "run": "r1", "out": str(tmp_path / "r1"),
                   "scene_toml": tiny_toml(), "overrides": COARSE})
    sent = [events.get() for _ in range(events.qsize())]
    meta = next(ev for ev in sent if ev["kind"] == "meta")
    note = "the viewer shows no tools: meshing them failed (RuntimeError: no surface)"
    assert meta["tools"] == [] and meta["note"] == note
    while solver.stepping:  # the run goes on to its end, which says it too
        solver.step()
    states = [ev for ev in (events.get() for _ in range(events.qsize())) if ev["kind"] == "state"]
    assert (states[-1]["state"], states[-1]["reason"]) == ("finished", note)


# ---- the service: the size limit, and a stop while building -----------------------------------
pytest.importorskip("fastapi")
from fastapi.testclient import TestClient  # noqa: E402

from server.app import create_app  # noqa: E402
from server.settings import Settings  # noqa: E402
from server.worker import worker_main  # noqa: E402


def slow_build_worker(commands, events, frames, record_every, step_delay):
    """The solver process, whose build of a scene named 'slow' never ends (a model that takes
    minutes to build, without the minutes), and whose meta of a scene named 'unsent' cannot be
    sent."""
    from server import worker
    from sim.stepping import simulation

    real = simulation.build_model

    def build(scene):
        while scene.name == "slow":
            time.sleep(0.05)
        return real(scene)

    simulation.build_model = build
    plotted = worker.plotted  # the meta of a scene named 'unsent' cannot be pickled
    worker.plotted = lambda scene, poses: {**plotted(scene, poses), **(
        {"punches": lambda: None} if scene.name == "unsent" else {})}
    worker_main(commands, events, frames, record_every, step_delay)


def wait_for(client, run_id: str, states: set[str], timeout: float = 120.0) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        st = client.get(f"/api/runs/{run_id}").json()
        if st["state"] in states:
            return st
        time.sleep(0.05)
    raise AssertionError(f"run {run_id} stuck in {st['state']}")


@pytest.fixture(scope="module")
def service(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("failures")
    os.environ.setdefault("XDG_CONFIG_HOME", str(tmp / "config"))
    os.environ.setdefault("XDG_DATA_HOME", str(tmp / "data"))
    scenes = tmp / "scenes"
    scenes.mkdir()
    (scenes / "tiny.toml").write_text(tiny_toml())
    (scenes / "slow.toml").write_text(tiny_toml().replace('name = "tiny"', 'name = "slow"'))
    (scenes / "unsent.toml").write_text(tiny_toml().replace('name = "tiny"', 'name = "unsent"'))
    settings = Settings(scenes_dir=scenes, runs_dir=tmp / "runs", viewer=False,
                        max_model_bytes=2 * 2**30)
    with TestClient(create_app(settings, worker_target=slow_build_worker)) as client:
        yield client, settings


def test_the_service_refuses_a_model_beyond_its_limit(service):
    client, settings = service
    r = client.post("/api/runs", json={"scene": "tiny",
                                       "overrides": {"mesh.edge_length": 1e-4}})
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert detail.startswith("mesh.edge_length: the model would have about 4910000 vertices")
    assert "above the limit of 2 GiB (the server's --max-memory)" in detail
    assert client.get("/api/runs").json() == []


def test_a_stop_during_the_build_ends_it(service):
    """The build of 'slow' never ends: the stop must end it all the same, and the service
    goes on with a new solver process. Waits on states, with generous deadlines."""
    client, settings = service
    before = client.get("/api/health").json()
    pid = before["worker_pid"]
    run_id = client.post("/api/runs", json={"scene": "slow"}).json()["id"]
    wait_for(client, run_id, {"building"})  # the solver said so: it is inside the build
    r = client.post(f"/api/runs/{run_id}/stop")
    assert r.status_code == 200 and r.json()["state"] == "stopped", r.text
    st = client.get(f"/api/runs/{run_id}").json()
    assert st["state"] == "stopped" and "during the build" in st["reason"]
    assert st["step"] == 0 and st["records"] == []
    res = strict_json(settings.runs_dir / run_id / "result.json")
    assert res["converged"] is False and "during the build" in res["failure"]["reason"]
    saved = json.loads((settings.runs_dir / run_id / "run.json").read_text())
    assert saved["state"] == "stopped"
    health = client.get("/api/health").json()
    assert health["worker_pid"] != pid
    assert health["worker_restarts"] == before["worker_restarts"] + 1
    with pytest.raises(ProcessLookupError):  # the old process is gone
        os.kill(pid, 0)
    nxt = client.post("/api/runs", json={"scene": "tiny"})
    assert nxt.status_code == 201, nxt.text
    st = wait_for(client, nxt.json()["id"], {"finished", "failed", "stopped"})
    assert st["state"] == "finished", st["reason"]
    deadline = time.monotonic() + 30
    while not client.get("/api/health").json()["ok"] and time.monotonic() < deadline:
        time.sleep(0.05)
    assert client.get("/api/health").json()["ok"]


def test_a_run_whose_model_cannot_reach_the_server_fails_naming_it(service):
    """Through the solver process's real queue, whose feeder thread would drop the meta
    without a word: the run fails at once with the reason, and the service goes on."""
    client, settings = service
    run_id = client.post("/api/runs", json={"scene": "unsent"}).json()["id"]
    st = wait_for(client, run_id, {"failed", "finished", "stopped"})
    assert st["state"] == "failed" and st["step"] == 0, st
    assert st["reason"].startswith("sending the run's model to the server failed: ")
    res = strict_json(settings.runs_dir / run_id / "result.json")
    assert res["failure"]["reason"] == st["reason"]
    nxt = client.post("/api/runs", json={"scene": "tiny"}).json()["id"]
    assert wait_for(client, nxt, {"finished", "failed", "stopped"})["state"] == "finished"


def test_a_solver_process_killed_mid_run_leaves_a_result(service):
    """The solver dies (an out-of-memory kill) while stepping: the run fails with the reason,
    and result.json holds the steps the server received."""
    import signal

    client, settings = service
    (settings.scenes_dir / "long.toml").write_text(tiny_toml().replace("steps = 4",
                                                                      "steps = 2000"))
    run_id = client.post("/api/runs", json={"scene": "long", "element": "linear"}).json()["id"]
    deadline = time.monotonic() + 120
    while client.get(f"/api/runs/{run_id}").json()["step"] < 2:
        assert time.monotonic() < deadline
        time.sleep(0.05)
    os.kill(client.get("/api/health").json()["worker_pid"], signal.SIGKILL)
    st = wait_for(client, run_id, {"failed", "finished", "stopped"})
    assert st["state"] == "failed" and "solver process died" in st["reason"]
    res = strict_json(settings.runs_dir / run_id / "result.json")
    assert res["failure"]["reason"] == st["reason"]
    assert [s["step"] for s in res["steps"]] == [r["step"] for r in st["records"]]
    assert len(res["steps"]) >= 2

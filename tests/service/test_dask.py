"""``q3t serve --scheduler``: the run queue on the workers of a Dask cluster (a LocalCluster of
two worker processes here), through the service's API: a run's whole cycle (live parameter,
frames, pause, step, resume, stop), a finished run's result and recording served from the
server's folder (sent back from the worker: the test's workers write into folders of their
own), two runs at once on the two workers, a worker killed mid-run failing that run only, and
a scheduler that does not answer refused at start-up.

Every wait is on a state, with a generous deadline (``HANG``), never on the clock."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

pytest.importorskip("fastapi")
distributed = pytest.importorskip("distributed")
from fastapi.testclient import TestClient  # noqa: E402

from server.app import create_app  # noqa: E402
from server.settings import ROOT, Settings  # noqa: E402
from tests.support.recording import series  # noqa: E402
from tests.support.scenes import tiny_toml  # noqa: E402
from tests.support.service import (  # noqa: E402
    ENDED,
    HANG,
    free_port,
    until,
    wait_done,
    wait_ready,
    wait_state,
    wait_step,
)

LONG = 100_000  # steps: a run that goes on until the test stops it (or kills its worker)


@pytest.fixture(scope="module")
def cluster(tmp_path_factory) -> Iterator[distributed.LocalCluster]:
    """Two worker processes of one thread each (a solver runs in a thread of its own), of
    1.5 GiB each: a worker holds about 0.65 GiB once it has stepped the tiny scene (the
    solver's compiled kernels and SciPy), and its nanny pauses it at 80 % of its limit. Their
    scratch folders are theirs, apart from the server's runs folder. The workers import this
    checkout (PYTHONPATH), as an installed q3t would be imported on a real cluster."""
    scratch = tmp_path_factory.mktemp("dask-workers")
    path = os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  memory_limit="1.5GiB", dashboard_address=None,
                                  local_directory=str(scratch),
                                  env={"PYTHONPATH": path}) as c:
        c.scratch = scratch
        yield c


@pytest.fixture(scope="module")
def cluster_client(cluster) -> Iterator[distributed.Client]:
    with distributed.Client(cluster.scheduler_address, set_as_default=False) as c:
        yield c


def worker_pids(client: distributed.Client) -> dict[str, int]:
    return client.run(os.getpid)


@contextlib.contextmanager
def served(tmp: Path, cluster, **options: object) -> Iterator[TestClient]:
    """The service over the scenes tiny (4 steps) and long, its solvers on ``cluster``."""
    (tmp / "scenes").mkdir(exist_ok=True)
    (tmp / "scenes" / "tiny.toml").write_text(tiny_toml())
    (tmp / "scenes" / "long.toml").write_text(tiny_toml(steps=LONG))
    (tmp / "scenes" / "slow.toml").write_text(tiny_toml().replace('name = "tiny"',
                                                                  'name = "slow"'))
    settings = Settings(scenes_dir=tmp / "scenes", runs_dir=tmp / "runs",
                        scheduler=cluster.scheduler_address,
                        **{"viewer": False, "ack_timeout": HANG, "stop_timeout": HANG,
                           **options})
    with TestClient(create_app(settings)) as client:
        wait_ready(client)
        yield client


def start(client: TestClient, scene: str = "tiny", **body: object) -> str:
    r = client.post("/api/runs", json={"scene": scene, **body})
    assert r.status_code == 201, r.text
    return r.json()["id"]


def test_a_run_steps_on_a_worker_through_its_whole_cycle(tmp_path, cluster, cluster_client):
    """Start, a live parameter, frames (kept, and pushed to the viewer), pause, one step,
    resume, stop; the run's files are in the server's folder, none left on the worker."""
    pytest.importorskip("viser")
    with served(tmp_path, cluster, viewer=True, viewer_port=free_port()) as client:
        run = start(client, "long", parameters={"friction_scale": 0.5})
        wait_step(client, run, 1)
        health = client.get("/api/health").json()
        assert health["ok"] and health["solvers"][0]["run"] == run
        assert health["solvers"][0]["pid"] in worker_pids(cluster_client).values()

        r = client.put(f"/api/runs/{run}/parameters/load_scale", json={"value": 2.0})
        assert r.status_code == 202 and r.json()["applied"], r.text
        applies = r.json()["applies_from_step"]
        st = wait_step(client, run, applies + 1)
        assert st["parameters"]["load_scale"] == 2.0
        assert st["parameters"]["friction_scale"] == 0.5  # given at the start, applied there
        assert {"name": "load_scale", "value": 2.0} \
            .items() <= st["parameter_log"][-1].items()
        kept = until(lambda: client.get(f"/api/runs/{run}/frames").json()["steps"],
                     "no frame of the run reached the server")
        assert max(kept) >= 1
        until(lambda: client.get(f"/api/runs/{run}").json()["frames"].get("pushed", 0) >= 2,
              "no frame of the run reached the viewer")

        assert client.post(f"/api/runs/{run}/pause").status_code == 200
        at = wait_done(client, run)["step"]
        assert client.post(f"/api/runs/{run}/step").status_code == 200
        st = wait_done(client, run)
        assert st["state"] == "paused" and st["step"] == at + 1
        assert client.post(f"/api/runs/{run}/resume").status_code == 200
        wait_step(client, run, at + 3)
        assert client.post(f"/api/runs/{run}/stop").status_code == 200
        st = wait_state(client, run, ENDED)
        assert st["state"] == "stopped" and st["reason"] == "stopped by request", st

        result = client.get(f"/api/runs/{run}/result").json()  # written on the worker
        assert len(result["steps"]) == st["step"] >= at + 3
        # the parameter given at the start, then the change made as it ran
        assert [(e["name"], e["value"]) for e in result["parameters"]] == \
            [("friction_scale", 0.5), ("load_scale", 2.0)]
        assert result["parameters"][-1] == st["parameter_log"][-1]
        folder = tmp_path / "runs" / run
        assert {"result.json", "run.rrd", "scene.toml", "run.json"} <= \
            {p.name for p in folder.iterdir()}
        assert not list(cluster.scratch.rglob(run)), "the run's files were left on the worker"


def test_a_finished_run_is_served_with_its_recording(tmp_path, cluster):
    with served(tmp_path, cluster) as client:
        run = start(client)
        st = wait_state(client, run, ENDED)
        assert st["state"] == "finished", st
        result = client.get(f"/api/runs/{run}/result").json()
        assert result["converged"] and len(result["steps"]) == 4
        assert client.get(f"/api/runs/{run}/summary").status_code == 200
        # the saved frames came back too: every download is offered, the VTU series made
        formats = client.get(f"/api/runs/{run}/exports").json()["formats"]
        assert all(f["available"] for f in formats if f["format"] != "png"), formats
        assert client.get(f"/api/runs/{run}/export/vtu").status_code == 200
        r = client.get(f"/api/runs/{run}/recording")
        assert r.status_code == 200
        got = tmp_path / "got.rrd"
        got.write_bytes(r.content)
        # a scalar of every step, the same value the status has for the last one
        tip = series(got, "/probes/tip_deflection")
        assert sorted(tip) == [1, 2, 3, 4]
        assert tip[4] == pytest.approx(st["records"][-1]["probes"]["tip_deflection"],
                                       rel=1e-6)  # float32 in the recording


def test_two_runs_at_once_on_the_two_workers(tmp_path, cluster, cluster_client):
    """Two runs step at once, one on each worker; shutting the server down stops both, and
    their files come back before it is down."""
    with served(tmp_path, cluster, solvers=2) as client:
        runs = [start(client, "long"), start(client, "long")]
        for run in runs:
            wait_step(client, run, 2)
        health = client.get("/api/health").json()
        assert sorted(health["active"]) == sorted(runs)
        pids = {s["pid"] for s in health["solvers"]}
        assert len(pids) == 2 and pids <= set(worker_pids(cluster_client).values())
    for run in runs:
        folder = tmp_path / "runs" / run
        status = json.loads((folder / "run.json").read_text())
        assert status["state"] == "stopped" and status["reason"] == "server shut down"
        result = json.loads((folder / "result.json").read_text())
        assert len(result["steps"]) == status["step"] >= 2
        assert (folder / "run.rrd").stat().st_size > 0


def test_a_lost_worker_fails_its_run_and_nothing_else(tmp_path, cluster, cluster_client):
    """A worker killed mid-run: its run fails naming the lost worker, with a result.json of
    the steps the server had; the other run goes on; the slot takes the next run."""
    with served(tmp_path, cluster, solvers=2) as client:
        lost, kept = start(client, "long"), start(client, "long")
        for run in (lost, kept):
            wait_step(client, run, 2)
        health = client.get("/api/health").json()
        pid = next(s["pid"] for s in health["solvers"] if s["run"] == lost)
        os.kill(pid, signal.SIGKILL)
        st = wait_state(client, lost, ENDED)
        assert st["state"] == "failed" and "Dask worker tcp://" in st["reason"] \
            and "was lost" in st["reason"], st
        result = client.get(f"/api/runs/{lost}/result").json()
        assert len(result["steps"]) >= 2 and result["failure"]["reason"] == st["reason"]
        health = client.get("/api/health")
        assert health.status_code == 200 and health.json()["solver_losses"] == [st["reason"]]
        at = client.get(f"/api/runs/{kept}").json()
        st = wait_step(client, kept, at["step"] + 2)  # it went on through all this
        assert st["state"] == "running", st
        after = start(client)  # on the slot's new solver
        assert wait_state(client, after, ENDED)["state"] == "finished"
        client.post(f"/api/runs/{kept}/stop")
        assert wait_state(client, kept, ENDED)["state"] == "stopped"
    until(lambda: len(cluster_client.scheduler_info(n_workers=-1)["workers"]) == 2,
          "the killed worker was not restarted by its nanny")


def slow_builds(on: bool) -> None:
    """On a worker: while ``on``, the build of a scene named 'slow' does not end (a model that
    takes minutes to build, without the minutes)."""
    from sim.stepping import simulation

    real = getattr(simulation, "real_build_model", simulation.build_model)

    def build(scene):
        while scene.name == "slow" and simulation.slow_builds:
            time.sleep(0.05)
        return real(scene)

    simulation.real_build_model, simulation.build_model = real, build
    simulation.slow_builds = on


def solver_threads() -> int:
    """On a worker: its solvers' loops still running."""
    return sum(t.name == "q3t-solver" for t in threading.enumerate())


def test_a_stop_during_the_build_lets_its_solver_go(tmp_path, cluster, cluster_client):
    """A build cannot be interrupted on a worker: the stop ends the run at once, a new solver
    takes the slot, and the old one ends once its build is over. No solver outlives its
    server."""
    cluster_client.run(slow_builds, True)
    try:
        with served(tmp_path, cluster) as client:
            run = start(client, "slow")
            wait_state(client, run, {"building"})  # the solver said so: inside the build
            r = client.post(f"/api/runs/{run}/stop")
            assert r.status_code == 200 and r.json()["state"] == "stopped", r.text
            st = client.get(f"/api/runs/{run}").json()
            assert "during the build" in st["reason"] and "was let go" in st["reason"], st
            result = json.loads((tmp_path / "runs" / run / "result.json").read_text())
            assert result["failure"]["reason"] == st["reason"]
            assert client.get("/api/health").json()["worker_restarts"] == 1
            after = start(client)
            assert wait_state(client, after, ENDED)["state"] == "finished"
    finally:
        cluster_client.run(slow_builds, False)
    until(lambda: not any(cluster_client.run(solver_threads).values()),
          "a solver's loop outlived its server on a worker")


def serve_args(*argv: str):
    import argparse

    from server.cli import add_parser

    ap = argparse.ArgumentParser()
    add_parser(ap.add_subparsers(dest="cmd"))
    return ap.parse_args(["serve", *argv])


@pytest.mark.parametrize("address", ["tcp://127.0.0.1:{port}", "no such:address::"])
def test_a_scheduler_that_does_not_answer_is_an_error_at_start_up(address, capsys):
    """Exit 2 naming the address, within the timeout: never a hang, never a server up."""
    from server.cli import cmd_serve

    address = address.format(port=free_port())  # nothing listens there
    assert cmd_serve(serve_args("--scheduler", address, "--scheduler-timeout", "2")) == 2
    err = capsys.readouterr().err
    assert f"--scheduler {address}: no Dask scheduler answered" in err, err


@pytest.mark.parametrize("bad", ["0", "-1", "nan", "soon"])
def test_the_scheduler_timeout_is_a_positive_number_of_seconds(bad, capsys):
    with pytest.raises(SystemExit) as exc:
        serve_args("--scheduler", "tcp://127.0.0.1:8786", "--scheduler-timeout", bad)
    assert exc.value.code == 2
    assert "argument --scheduler-timeout: " in capsys.readouterr().err

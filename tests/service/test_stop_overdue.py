"""A stop the solver cannot act on still ends the run: the solver reads commands between
steps, so a step that does not end (a huge model, a solver stuck) would hold the run and its
solver process for ever. After ``stop_grace`` the process is killed and a new one started."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("fastapi")
from fastapi.testclient import TestClient  # noqa: E402

from server.app import create_app  # noqa: E402
from tests.support.scenes import PRESS_TOML  # noqa: E402
from tests.support.service import (  # noqa: E402
    service_settings,
    stuck_worker,
    wait_ready,
    wait_state,
)


def test_a_stop_ends_a_step_that_does_not_end(tmp_path):
    settings = service_settings(tmp_path, {"press": PRESS_TOML}, {"stop_grace": 1.0})
    with TestClient(create_app(settings, worker_target=stuck_worker)) as client:
        wait_ready(client)
        run = client.post("/api/runs", json={"scene": "press"}).json()["id"]
        assert wait_state(client, run, {"running"})["step"] == 0  # inside step 1, for ever
        assert client.post(f"/api/runs/{run}/stop").status_code == 200
        st = wait_state(client, run, {"stopped", "failed", "finished"})
        assert st["state"] == "stopped", st
        assert "step 1, which had not ended 1 s after the stop" in st["reason"], st["reason"]
        assert "a new one started" in st["reason"]
        # its folder is whole: run.json says stopped, result.json says so too
        folder = settings.runs_dir / run
        assert json.loads((folder / "run.json").read_text())["state"] == "stopped"
        result = client.get(f"/api/runs/{run}/result")
        assert result.status_code == 200 and result.json()["converged"] is False
        # the new solver process takes the next run; the stopped one can be deleted
        nxt = client.post("/api/runs", json={"scene": "press"}).json()["id"]
        assert wait_state(client, nxt, {"running"})["state"] == "running"
        assert client.delete(f"/api/runs/{run}").status_code in (200, 204)
        client.post(f"/api/runs/{nxt}/stop")
        assert wait_state(client, nxt, {"stopped"})["state"] == "stopped"

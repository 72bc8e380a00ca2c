"""The run queue: runs started on a busy server wait their turn (their place shown), start in
order on the solver processes as those free up, can be cancelled before they start, and past
the queue's bound are refused with 429. Threads starting and cancelling at once lose no run
and start none twice; a solver process that dies fails only its run and the queue goes on; two
solver processes step two runs at once; no solver process outlives its server.

Every wait is on a state, with a generous deadline; paused runs hold a solver while a test
arranges the queue, so nothing depends on how fast the machine is."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

pytest.importorskip("fastapi")
from fastapi.testclient import TestClient  # noqa: E402

from server.app import create_app  # noqa: E402
from server.records import NOT_RUN  # noqa: E402
from server.settings import Settings  # noqa: E402
from tests.support.scenes import tiny_toml  # noqa: E402
from tests.support.service import (  # noqa: E402
    ENDED,
    HANG,
    free_port,
    until,
    wait_ready,
    wait_state,
    wait_step,
)
from tests.support.viewer import attached

LONG = 100_000  # steps: a run that goes on until a test stops it (or kills its solver)


def solver_children() -> set[int]:
    """The live (not zombie) solver processes this test process has spawned."""
    out = set()
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat, cmd = (d / "stat").read_text(), (d / "cmdline").read_bytes()
        except OSError:  # ended meanwhile
            continue
        state, ppid = stat.rsplit(")", 1)[1].split()[:2]
        if int(ppid) == os.getpid() and state != "Z" and b"spawn_main" in cmd:
            out.add(int(d.name))
    return out


@contextlib.contextmanager
def served(tmp: Path, **options: object) -> Iterator[tuple[TestClient, Settings]]:
    """A server over the scenes tiny (4 steps) and long (LONG steps), with ``options``; on
    leaving, no solver process it started is left."""
    before = solver_children()
    (tmp / "scenes").mkdir(exist_ok=True)
    (tmp / "scenes" / "tiny.toml").write_text(tiny_toml())
    (tmp / "scenes" / "long.toml").write_text(tiny_toml(steps=LONG))
    settings = Settings(scenes_dir=tmp / "scenes", runs_dir=tmp / "runs",
                        **{"viewer": False, "ack_timeout": HANG, "stop_timeout": HANG,
                           **options})
    with TestClient(create_app(settings)) as client:
        wait_ready(client)
        yield client, settings
    assert solver_children() - before == set(), "a solver process outlived its server"


def start(client: TestClient, scene: str = "tiny", **body: object) -> dict:
    r = client.post("/api/runs", json={"scene": scene, **body})
    assert r.status_code == 201, r.text
    return r.json()


def places(client: TestClient) -> dict[str, int | None]:
    return {r["id"]: r["place"] for r in client.get("/api/runs").json()}


def queue_ends_empty(client: TestClient) -> dict:
    health = until(lambda: (h := client.get("/api/health").json())["active"] == []
                   and h["queued"] == [] and h, "runs left active or queued")
    pids = {s["pid"] for s in health["solvers"]}
    assert all(s["alive"] for s in health["solvers"]) and pids <= solver_children()
    return health


def test_queued_runs_start_in_order_and_a_cancelled_one_never(tmp_path):
    with served(tmp_path, solvers=1) as (client, settings):
        holder = start(client, paused=True)  # holds the one solver until it is resumed
        assert holder["state"] in ("starting", "building", "paused")
        runs = [start(client) for _ in range(3)]
        assert [r["state"] for r in runs] == ["queued"] * 3
        assert [r["place"] for r in runs] == [1, 2, 3]
        b, c, d = (r["id"] for r in runs)
        st = client.get(f"/api/runs/{c}").json()
        assert st["place"] == 2 and st["progress"]["elapsed_s"] is None
        # what it waits for: the run on the one solver, paused (the page says to resume it)
        wait_state(client, holder["id"], {"paused"})
        st = client.get(f"/api/runs/{c}").json()
        assert st["waiting_for"] == [{"id": holder["id"], "state": "paused"}], st
        assert client.get(f"/api/runs/{holder['id']}").json()["waiting_for"] == []
        r = client.post(f"/api/runs/{c}/pause")  # only a stop acts on a queued run
        assert r.status_code == 409 and "queued (2nd in the queue)" in r.json()["detail"]
        r = client.post(f"/api/runs/{c}/stop")
        assert r.status_code == 200 and r.json()["state"] == "cancelled", r.text
        assert places(client) == {holder["id"]: None, b: 1, c: None, d: 2}
        assert client.get("/api/health").json()["queued"] == [b, d]
        st = client.get(f"/api/runs/{b}/wait", params={"timeout": 0.5}).json()
        assert st["state"] == "queued"  # a script's wait goes on: the run has not begun
        client.post(f"/api/runs/{holder['id']}/resume")
        for run in (holder["id"], b, d):
            assert wait_state(client, run, ENDED)["state"] == "finished", run
        ended = {r["id"]: r for r in client.get("/api/runs").json()}
        assert ended[holder["id"]]["started"] < ended[b]["started"] < ended[d]["started"]
        # each started once its predecessor had ended: one solver, in queue order
        assert ended[holder["id"]]["ended"] <= ended[b]["started"]
        assert ended[b]["ended"] <= ended[d]["started"]
        cancelled = ended[c]
        assert cancelled["state"] == "cancelled" and cancelled["started"] is None
        assert cancelled["reason"] == "cancelled before it started"
        assert sorted(p.name for p in (settings.runs_dir / c).iterdir()) == \
            ["run.json", "scene.toml"]  # it never reached a solver
        assert json.loads((settings.runs_dir / c / "run.json").read_text())["state"] == \
            "cancelled"
        queue_ends_empty(client)


def test_past_the_bound_a_start_is_refused_with_429(tmp_path):
    with served(tmp_path, solvers=1, queue_limit=2) as (client, settings):
        holder = start(client, paused=True)
        queued = [start(client)["id"] for _ in range(2)]
        folders = sorted(p.name for p in settings.runs_dir.iterdir())
        r = client.post("/api/runs", json={"scene": "tiny"})
        assert r.status_code == 429, r.text
        detail = r.json()["detail"]
        assert "run queue is full" in detail and "2 runs wait for 1 solver" in detail
        assert "--queue 2" in detail
        assert sorted(p.name for p in settings.runs_dir.iterdir()) == folders  # nothing written
        assert client.delete(f"/api/runs/{queued[0]}").status_code == 204  # leaves the queue
        assert places(client)[queued[1]] == 1
        third = start(client)  # room again
        assert third["place"] == 2
        client.post(f"/api/runs/{holder['id']}/resume")
        for run in (holder["id"], queued[1], third["id"]):
            assert wait_state(client, run, ENDED)["state"] == "finished", run
        queue_ends_empty(client)


def test_concurrent_starts_and_cancels_lose_no_run_and_start_none_twice(tmp_path):
    """Threads start runs at once; some stop (cancel) theirs at once, some delete them. Every
    run answered 201 is listed exactly once unless deleted, ends in a final state, and the runs
    left alone finish with every step made once: none lost, none started twice."""
    threads, each = 4, 4
    with served(tmp_path, solvers=1, queue_limit=threads * each) as (client, settings):
        kept, stopped, deleted, refused = [], [], [], []
        lock = threading.Lock()

        def user(k: int) -> None:
            for i in range(each):
                r = client.post("/api/runs", json={"scene": "tiny"})
                if r.status_code != 201:
                    with lock:
                        refused.append(r.text)
                    continue
                run, action = r.json()["id"], (k + i) % 3
                if action == 1:
                    assert client.post(f"/api/runs/{run}/stop").status_code in (200, 409)
                elif action == 2:
                    code = client.delete(f"/api/runs/{run}").status_code
                    if code == 409:  # active already: stopped instead
                        client.post(f"/api/runs/{run}/stop")
                        action = 1
                    else:
                        assert code == 204
                with lock:
                    (kept, stopped, deleted)[action].append(run)

        workers = [threading.Thread(target=user, args=(k,)) for k in range(threads)]
        for t in workers:
            t.start()
        for t in workers:
            t.join(HANG)
        assert not any(t.is_alive() for t in workers), "a request hung"
        assert refused == []  # the bound holds every run at once
        ids = kept + stopped + deleted
        assert len(ids) == len(set(ids)) == threads * each
        listed = [r["id"] for r in client.get("/api/runs").json()]
        assert sorted(listed) == sorted(kept + stopped)  # none lost, none doubled
        assert sorted(p.name for p in settings.runs_dir.iterdir()) == sorted(listed)
        for run in listed:
            wait_state(client, run, ENDED)
        for run in kept:
            st = client.get(f"/api/runs/{run}").json()
            assert st["state"] == "finished" and st["reason"] is None, st
            assert [r["step"] for r in st["records"]] == [1, 2, 3, 4]  # each step once
        for run in stopped:
            st = client.get(f"/api/runs/{run}").json()
            # a stop reaches a queued run (cancelled), a building or running one (stopped),
            # or one that finished first
            assert st["state"] in ("cancelled", "stopped", "finished"), st
            assert st["state"] != "cancelled" or st["started"] is None
        queue_ends_empty(client)


def test_a_dying_solver_fails_only_its_run_and_the_queue_goes_on(tmp_path):
    with served(tmp_path, solvers=1) as (client, settings):
        dying = start(client, "long")["id"]
        wait_step(client, dying, 1)
        behind = [start(client)["id"] for _ in range(2)]
        health = client.get("/api/health").json()
        assert health["active"] == [dying] and health["queued"] == behind
        os.kill(health["solvers"][0]["pid"], signal.SIGKILL)
        st = wait_state(client, dying, ENDED)
        assert st["state"] == "failed" and "solver process died" in st["reason"], st
        for run in behind:  # on the new solver process, in order
            st = wait_state(client, run, ENDED)
            assert st["state"] == "finished", st
        after = queue_ends_empty(client)
        assert after["worker_restarts"] == health["worker_restarts"] + 1
        assert after["solvers"][0]["pid"] != health["solvers"][0]["pid"]


def test_two_solvers_step_two_runs_at_once(tmp_path):
    """--solvers 2: two long runs step at the same time, a third waits; killing one run's
    process fails that run only, the other goes on stepping, and the third takes the slot."""
    with served(tmp_path, solvers=2) as (client, settings):
        a, b = start(client, "long")["id"], start(client, "long")["id"]
        third = start(client)
        assert third["state"] == "queued" and third["place"] == 1
        for run in (a, b):
            wait_step(client, run, 2)
        health = client.get("/api/health").json()
        assert sorted(health["active"]) == sorted([a, b]), health
        assert {client.get(f"/api/runs/{r}").json()["state"] for r in (a, b)} == {"running"}
        pid_a = next(s["pid"] for s in health["solvers"] if s["run"] == a)
        os.kill(pid_a, signal.SIGKILL)
        st = wait_state(client, a, ENDED)
        assert st["state"] == "failed" and "solver process died" in st["reason"], st
        assert wait_state(client, third["id"], ENDED)["state"] == "finished"
        at = client.get(f"/api/runs/{b}").json()["step"]
        st = wait_step(client, b, at + 2)  # b went on through all this
        assert st["state"] == "running", st
        client.post(f"/api/runs/{b}/stop")
        assert wait_state(client, b, ENDED)["state"] == "stopped"
        queue_ends_empty(client)


def test_queued_runs_do_not_start_after_a_restart(tmp_path):
    """A shutdown cancels the queued runs before it stops the active one (none starts
    meanwhile); a run.json still saying queued (the server died) is marked not run by the next
    server, unless a solver had begun it."""
    with served(tmp_path, solvers=1) as (client, settings):
        active = start(client, "long")["id"]
        wait_step(client, active, 1)
        queued, begun = start(client)["id"], start(client)["id"]
    runs = {r: json.loads((settings.runs_dir / r / "run.json").read_text())
            for r in (active, queued, begun)}
    assert runs[active]["state"] == "stopped" and runs[active]["reason"] == "server shut down"
    for r in (queued, begun):
        assert runs[r]["state"] == "cancelled", runs[r]
        assert runs[r]["reason"] == "not run: the server shut down before its turn"
        assert not (settings.runs_dir / r / "result.json").exists()
    # as if the server had died with both queued, and a solver had begun the second
    for r in (queued, begun):
        path = settings.runs_dir / r / "run.json"
        path.write_text(json.dumps({**runs[r], "state": "queued", "place": 1,
                                    "reason": None, "ended": None}))
    (settings.runs_dir / active / "result.json").rename(settings.runs_dir / begun /
                                                         "result.json")
    with served(tmp_path, solvers=1) as (client, _):
        st = client.get(f"/api/runs/{queued}").json()
        assert st["state"] == "cancelled" and st["reason"] == NOT_RUN, st
        assert st["place"] is None and st["progress"]["elapsed_s"] is None
        st = client.get(f"/api/runs/{begun}").json()
        assert st["state"] != "cancelled" and st["step"] > 0, st  # recovered from its result
        assert client.get("/api/health").json()["queued"] == []


def test_the_viewer_draws_the_selected_one_of_two_live_runs(tmp_path):
    """--solvers 2 with the viewer: both runs stay live (their frames kept), the selected
    one is drawn, and selecting the other draws that one from then on."""
    pytest.importorskip("viser")
    with served(tmp_path, solvers=2, viewer=True, viewer_port=free_port()) as (client, _), \
            attached(client.app.state.manager.viewer) as shown:  # a browser's (default) view
        viewer = client.app.state.manager.viewer
        a, b = start(client, "long")["id"], start(client, "long")["id"]  # b: selected
        for run in (a, b):
            wait_step(client, run, 2)
        until(lambda: set(viewer.lives) == {a, b}, "both runs are not live")
        drawn, draw = [], shown.canvas.draw

        def drawing(frame: dict, colour: bool) -> None:
            drawn.append(frame.get("run"))
            draw(frame, colour)

        shown.canvas.draw = drawing
        until(lambda: len(drawn) >= 3, "no frame of the selected run drawn")
        assert set(drawn) == {b}
        assert client.put("/api/view", json={"run": a}).status_code == 200
        mark = len(drawn)
        until(lambda: len(drawn) >= mark + 3, "no frame drawn after selecting the other run")
        assert set(drawn[mark:]) == {a}
        assert shown.mode == "live" and viewer.lives[b].frame["step"] >= 2  # b kept
        for run in (a, b):
            client.post(f"/api/runs/{run}/stop")
            assert wait_state(client, run, ENDED)["state"] == "stopped"


def test_the_command_line_sets_solvers_and_the_bound(capsys):
    import argparse

    from server.cli import add_parser, serve_settings

    parser = argparse.ArgumentParser(prog="q3t")
    add_parser(parser.add_subparsers())
    args = parser.parse_args(["serve", "--solvers", "2", "--queue", "3"])
    settings = serve_settings(args, token=None)
    assert settings.solvers == 2 and settings.queue_limit == 3
    assert serve_settings(parser.parse_args(["serve"]), None).solvers == 1  # the default
    for bad, why in ((["--solvers", "0"], "argument --solvers: must be at least 1, not 0"),
                     (["--queue", "-1"], "argument --queue: must be at least 0, not -1"),
                     (["--solvers", "two"], "argument --solvers: 'two' is not a whole")):
        with pytest.raises(SystemExit) as exc:
            parser.parse_args(["serve", *bad])
        assert exc.value.code == 2 and why in capsys.readouterr().err


def test_the_list_says_what_each_run_changed(tmp_path):
    """GET /api/runs carries what the Runs table shows: each run's changes of its scene (the
    overrides, the live parameters given at the start and those changed as it ran) and, once
    it has ended, the headline values of its result."""
    with served(tmp_path, solvers=1) as (client, _):
        run = start(client, "long", paused=True, parameters={"load_scale": 2.0},
                    overrides={"material.nu": 0.25})["id"]
        r = client.put(f"/api/runs/{run}/parameters/friction_scale", json={"value": 0.5})
        assert r.status_code == 202 and r.json()["applied"], r.text
        step = r.json()["applies_from_step"]
        listed = {r["id"]: r for r in client.get("/api/runs").json()}[run]
        assert listed["changes"] == ["material.nu = 0.25", "Load × 2 from step 1",
                                     f"Friction × 0.5 from step {step}"]
        assert listed["results"] == {}  # not ended: no result yet
        client.post(f"/api/runs/{run}/stop")
        wait_state(client, run, ENDED)
        listed = {r["id"]: r for r in client.get("/api/runs").json()}[run]
        # the cantilever: no punch, its thickness as written (7 mm, no thinning)
        # (no forming limit in its material card: nothing flagged)
        assert listed["results"] == {"min_thickness": {"value": pytest.approx(7.0),
                                                       "unit": "mm", "flag": None},
                                     "max_thinning": {"value": pytest.approx(0.0, abs=1e-9),
                                                      "unit": "%", "flag": None}}

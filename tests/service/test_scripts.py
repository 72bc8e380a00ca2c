"""For scripts: a run's events as server-sent events, the wait for its end, the OpenAPI
description of every route, and docs/service.md's client example run against a server."""

from __future__ import annotations

import json
import os
import queue
import re
import subprocess
import sys
import threading
from collections.abc import Iterable, Iterator

import pytest

pytest.importorskip("fastapi")

from tests.support.browser import ROOT, serve  # noqa: E402
from tests.support.scenes import tiny_toml  # noqa: E402
from tests.support.service import HANG, wait_state  # noqa: E402

FINAL = {"finished", "failed", "stopped"}


def parse_lines(lines: Iterable[str]) -> Iterator[tuple[str, dict, str | None]]:
    """(event, data, id) of each event of a text/event-stream's lines; comments skipped."""
    fields: dict[str, str] = {}
    for line in lines:
        if not line:
            if fields:
                yield fields["event"], json.loads(fields["data"]), fields.get("id")
            fields = {}
        elif not line.startswith(":"):
            key, value = line.split(": ", 1)
            fields[key] = value


def parse_sse(text: str) -> list[tuple[str, dict, str | None]]:
    return list(parse_lines(text.split("\n")))


def finished_run(client, **body) -> str:
    r = client.post("/api/runs", json={"scene": "tiny", "element": "linear", **body})
    assert r.status_code == 201, r.text
    run_id = r.json()["id"]
    wait_state(client, run_id, FINAL)
    return run_id


def test_events_of_an_ended_run_are_its_state_records_and_end(env):
    """A run that has ended streams at once: its state, every step record (the same as the
    status holds, each with its step as event id) and `end` with the final summary."""
    client, _ = env
    run_id = finished_run(client)
    r = client.get(f"/api/runs/{run_id}/events")
    assert r.status_code == 200
    assert r.headers["content-type"].startswith("text/event-stream")
    events = parse_sse(r.text)
    status = client.get(f"/api/runs/{run_id}").json()
    kinds = [e[0] for e in events]
    assert kinds == ["state"] + ["step"] * len(status["records"]) + ["end"], kinds
    assert [e[1] for e in events if e[0] == "step"] == status["records"]
    assert [e[2] for e in events if e[0] == "step"] == [str(r["step"]) for r in status["records"]]
    assert events[-1][1]["state"] == "finished" and events[-1][1]["id"] == run_id

    # from a step on (a query, or a reconnecting EventSource's Last-Event-ID): the rest only
    later = parse_sse(client.get(f"/api/runs/{run_id}/events?since=2").text)
    assert [e[1]["step"] for e in later if e[0] == "step"] == [
        r["step"] for r in status["records"] if r["step"] > 2]
    resumed = parse_sse(client.get(f"/api/runs/{run_id}/events",
                                   headers={"Last-Event-ID": "3"}).text)
    assert [e[1]["step"] for e in resumed if e[0] == "step"] == [
        r["step"] for r in status["records"] if r["step"] > 3]


def test_wait_returns_the_ended_run_and_a_paused_one_after_its_timeout(env):
    client, _ = env
    run_id = finished_run(client)
    r = client.get(f"/api/runs/{run_id}/wait", params={"timeout": 5})
    assert r.status_code == 200 and r.json()["state"] == "finished"

    r = client.post("/api/runs", json={"scene": "tiny", "element": "linear", "paused": True})
    paused = r.json()["id"]
    wait_state(client, paused, {"paused"})
    # a paused run does not end by itself: the wait answers after its timeout, state as it is
    r = client.get(f"/api/runs/{paused}/wait", params={"timeout": 0.3})
    assert r.status_code == 200 and r.json()["state"] == "paused"
    client.post(f"/api/runs/{paused}/stop")
    assert client.get(f"/api/runs/{paused}/wait", params={"timeout": HANG}).json()["state"] in FINAL


@pytest.mark.parametrize("url, field", [
    ("/api/runs/no-such-run/events", None), ("/api/runs/no-such-run/wait", None),
    ("/api/runs/x/wait?timeout=0", "timeout"), ("/api/runs/x/wait?timeout=601", "timeout"),
    ("/api/runs/x/wait?timeout=nan", "timeout: Input should be a finite number"),
    ("/api/runs/x/events?since=-1", "since"), ("/api/runs/..%5Csecret/events", "run id")])
def test_bad_event_and_wait_requests_name_the_problem(env, url, field):
    client, _ = env
    r = client.get(url)
    if field is None:
        assert r.status_code == 404 and "no run" in r.json()["detail"]
    else:
        assert r.status_code == 422 and field in r.json()["detail"], r.text


def test_every_route_is_described_and_says_what_it_answers(env):
    """`/openapi.json` documents each operation: a description, and for each success a
    schema (a typed model) or a declared media type that is not JSON (a file, a stream)."""
    client, _ = env
    spec = client.get("/openapi.json").json()
    missing = []
    for path, ops in spec["paths"].items():
        for method, op in ops.items():
            if not op.get("description"):
                missing.append(f"{method.upper()} {path}: no description")
            for code, answer in op["responses"].items():
                if not code.startswith("2") or code == "204":
                    continue
                content = answer.get("content", {})
                schema = content.get("application/json", {}).get("schema")
                if schema == {} or (schema is None and not content):
                    missing.append(f"{method.upper()} {path} {code}: untyped answer")
    assert not missing, "\n".join(missing)


def test_the_docs_client_example_runs_against_a_server(tmp_path):
    """docs/service.md's Python example, verbatim, against `q3t serve` on the tiny scene:
    it streams every step of the run and sees its end."""
    text = (ROOT / "docs/service.md").read_text()
    block = re.search(r"<!-- client example: run by tests/service/test_scripts.py -->\n"
                      r"```python\n(.*?)```", text, re.S)
    assert block, "docs/service.md lost its client example"
    (tmp_path / "example.py").write_text(block.group(1))
    with serve(tmp_path, {"tiny": tiny_toml(steps=6)}, "tiny", "--no-viewer") as (url, _):
        out = subprocess.run([sys.executable, str(tmp_path / "example.py")], text=True,
                             capture_output=True, timeout=HANG,
                             env={**os.environ, "Q3T_URL": url})
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0].startswith("started tiny-")
    assert [ln.split(":")[0] for ln in lines if ln.startswith("step ")] == [
        f"step {i}" for i in range(1, 7)], out.stdout
    assert "ended: finished" in out.stdout and lines[-1].startswith("finished {")


def test_events_arrive_as_the_run_steps(tmp_path):
    """Against `q3t serve` (a real HTTP stream, not the test client's buffered one): a paused
    run's stream says paused; a step asked for arrives as a `step` event while the run is
    still paused, a live parameter change as `parameters`, a stop as `end`."""
    import httpx

    events: queue.Queue = queue.Queue()

    def read(url: str, run_id: str) -> None:
        with httpx.Client(base_url=url, timeout=HANG) as api:
            with api.stream("GET", f"/api/runs/{run_id}/events") as r:
                for kind, data, _ in parse_lines(r.iter_lines()):
                    events.put((kind, data))
                    if kind == "end":
                        return

    def next_event(kinds: set[str]) -> dict:
        """The next event of one of ``kinds``, skipping others (a hang guard, no clock)."""
        while True:
            kind, data = events.get(timeout=HANG)
            if kind in kinds:
                return {"kind": kind, **data}

    with serve(tmp_path, {"tiny": tiny_toml(steps=50)}, "tiny", "--no-viewer") as (url, _):
        with httpx.Client(base_url=url, timeout=HANG) as api:
            run_id = api.post("/api/runs", json={"scene": "tiny", "element": "linear",
                                                 "paused": True}).json()["id"]
            threading.Thread(target=read, args=(url, run_id), daemon=True).start()
            until_state = next_event({"state"})
            while until_state["state"] != "paused":
                until_state = next_event({"state"})
            assert api.post(f"/api/runs/{run_id}/step").status_code == 200
            step = next_event({"step", "end"})
            assert step["kind"] == "step" and step["step"] == 1, step
            r = api.put(f"/api/runs/{run_id}/parameters/load_scale", json={"value": 1.5})
            assert r.status_code == 202, r.text
            # first maybe a state event (the change pending), then the solver's answer
            changed = next_event({"parameters", "state", "end"})
            while changed["kind"] != "end" and changed["parameters"]["load_scale"] != 1.5:
                changed = next_event({"parameters", "state", "end"})
            assert changed["kind"] in {"parameters", "state"}, changed
            assert api.post(f"/api/runs/{run_id}/stop").status_code == 200
            end = next_event({"end"})
            assert end["state"] == "stopped" and end["id"] == run_id

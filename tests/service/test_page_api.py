"""What the page's results panel reads, through the API (TestClient, no viewer, no browser;
tests/service/test_page_browser.py drives the page itself):

- a run's ``progress``: steps done of all, elapsed and remaining time, in the status and list;
- ``/api/runs/{id}/plots``: each punch's force (kN) against its stroke (mm), agreeing with the
  run summary's peak and with the step records; probes in their units; the sections'
  thickness (mm) at their steps; the live-parameter changes;
- plotly.js served by the app itself (``/static/vendor``), so the page needs no CDN.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from server.plots import thinned
from sim.frames.probes import PROBES
from sim.frames.units import DISPLAY
from tests.support.scenes import tiny_cup_toml
from tests.support.service import HANG, in_process, until, wait_state

ENDED = {"finished", "failed", "stopped"}
# the plots' numbers are the records' scaled to kN / mm: equal up to the scaling's rounding
SCALED = 1e-12


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("page-api")
    with in_process(tmp, {"tiny_cup": tiny_cup_toml()}) as (client, settings):
        yield client, settings


@pytest.fixture(scope="module")
def finished(env):
    """A finished run of tiny_cup, with friction doubled from its second step (set to 1.5,
    then 2, while paused after the first: one change, the last)."""
    client, settings = env
    run = client.post("/api/runs", json={"scene": "tiny_cup", "paused": True}).json()["id"]
    wait_state(client, run, {"paused"})
    client.post(f"/api/runs/{run}/step")
    until(lambda: client.get(f"/api/runs/{run}").json()["step"] >= 1, "no first step")
    for value in (1.5, 2.0):
        r = client.put(f"/api/runs/{run}/parameters/friction_scale", json={"value": value})
        assert r.status_code == 202 and r.json()["applied"], r.text
    client.post(f"/api/runs/{run}/resume")
    st = wait_state(client, run, ENDED)
    assert st["state"] == "finished", st["reason"]
    result = json.loads((settings.runs_dir / run / "result.json").read_text())
    return run, st, result


def test_progress_of_a_finished_run(env, finished):
    client, _ = env
    run, st, _ = finished
    p = st["progress"]
    assert (p["step"], p["steps"], p["fraction"], p["remaining_s"]) == (4, 4, 1.0, 0.0)
    assert p["elapsed_s"] > 0
    listed = next(r for r in client.get("/api/runs").json() if r["id"] == run)
    assert listed["progress"]["fraction"] == 1.0
    assert listed["progress"]["elapsed_s"] == p["elapsed_s"]  # it ended: elapsed stands still


def test_progress_while_running(env):
    """Before the first step nothing is known of the remaining time; after it, the steps left
    at the mean cost of those done."""
    client, _ = env
    run = client.post("/api/runs", json={"scene": "tiny_cup", "paused": True}).json()["id"]
    try:
        st = wait_state(client, run, {"paused"})
        assert st["progress"]["remaining_s"] is None and st["progress"]["fraction"] == 0.0
        client.post(f"/api/runs/{run}/step")
        st = until(lambda: (s := client.get(f"/api/runs/{run}").json())["step"] >= 1 and s,
                   "no first step")
        p = st["progress"]
        assert p["step"] == 1 and p["fraction"] == 0.25
        assert p["remaining_s"] > 0 and p["elapsed_s"] > 0
    finally:
        client.post(f"/api/runs/{run}/stop")
        st = wait_state(client, run, ENDED)
    assert st["progress"]["remaining_s"] is None  # stopped: it will not go on


def test_the_remaining_time_counts_the_pause_between_steps(tmp_path):
    """``q3t serve --step-delay``: the solver pauses after each step, and the steps left take
    that pause too (the solver's own time alone promised a run done long before it was); a
    Stop during the pause acts at once, and the next run does not wait out the last one's."""
    pause = 10 * HANG  # longer than any hang guard: a Stop or a start that waited it out fails
    with in_process(tmp_path, {"tiny_cup": tiny_cup_toml()}, step_delay=pause) as (client, _):
        first = client.post("/api/runs", json={"scene": "tiny_cup"}).json()["id"]
        st = until(lambda: (s := client.get(f"/api/runs/{first}").json())["step"] >= 1 and s,
                   "no first step")
        p = st["progress"]
        # one step done, three left, each with its pause: the pauses alone give 3 x pause
        assert p["step"] == 1 and 3 * pause <= p["remaining_s"], p
        client.post(f"/api/runs/{first}/stop")
        st = wait_state(client, first, ENDED)
        assert (st["state"], st["step"]) == ("stopped", 1), st
        second = client.post("/api/runs", json={"scene": "tiny_cup"}).json()["id"]
        until(lambda: client.get(f"/api/runs/{second}").json()["step"] >= 1,
              "the next run waited out the stopped run's pause")
        client.post(f"/api/runs/{second}/stop")
        wait_state(client, second, ENDED)


def test_force_against_stroke_agrees_with_summary_and_records(env, finished):
    client, _ = env
    run, _, result = finished
    plots = client.get(f"/api/runs/{run}/plots").json()
    (punch,) = plots["punches"]
    assert punch["tool"] == "punch"
    assert (punch["force"]["unit"], punch["stroke"]["unit"]) == ("kN", "mm")
    # the punch moves down (-z) by 2 mm over 4 steps from where it started: force resisting
    # it is the sheet's push up on it, +fz
    fz = np.array([s["tools"]["punch"]["fz"] for s in result["steps"]])
    assert punch["force"]["values"] == pytest.approx(fz / 1e3, rel=SCALED)
    assert punch["stroke"]["values"] == pytest.approx([0.5, 1.0, 1.5, 2.0], rel=1e-9)
    peak = next(e for e in result["summary"] if e["name"] == "peak_punch_force")
    k = int(np.argmax(punch["force"]["values"]))
    assert punch["force"]["values"][k] == pytest.approx(peak["display"]["value"], rel=SCALED)
    assert punch["stroke"]["values"][k] == pytest.approx(peak["at"]["stroke"]["display"]["value"],
                                                         rel=SCALED)
    assert punch["steps"][k] == peak["at"]["step"]


def test_probes_in_their_units(env, finished):
    client, _ = env
    run, _, result = finished
    probes = {p["name"]: p for p in client.get(f"/api/runs/{run}/plots").json()["probes"]}
    assert {n: (p["kind"], p["unit"], p["si_unit"]) for n, p in probes.items()} == {
        "punch_force": ("tool_force", "kN", "N"), "min_thickness": ("thickness", "mm", "m"),
        "centre_dz": ("displacement", "mm", "m")}
    h = [s["probes"]["min_thickness"] for s in result["steps"]]
    assert probes["min_thickness"]["values"] == pytest.approx(np.array(h) * 1e3, rel=SCALED)
    assert probes["min_thickness"]["steps"] == [1, 2, 3, 4]


def test_every_probe_kind_has_a_display_unit():
    assert {k: p.unit for k, p in PROBES.items() if p.unit not in DISPLAY} == {}


def test_sections_and_parameter_marks(env, finished):
    client, _ = env
    run, _, result = finished
    plots = client.get(f"/api/runs/{run}/plots").json()
    (sec,) = plots["sections"]
    assert sec["name"] == "radial" and [s["step"] for s in sec["steps"]] == [0, 2, 4]
    assert sec["angle"] == pytest.approx(result["sections"]["radial"][0]["angle_deg"])
    for got, want in zip(sec["steps"], result["sections"]["radial"], strict=True):
        assert (got["position"]["unit"], got["thickness"]["unit"]) == ("mm", "mm")
        assert got["thickness"]["values"] == pytest.approx(np.array(want["thickness"]) * 1e3,
                                                           rel=SCALED)
        assert got["position"]["values"] == pytest.approx(np.array(want["rest_radius"]) * 1e3,
                                                          rel=SCALED)
    assert sec["steps"][0]["thickness"]["values"] == pytest.approx([0.5] * 5, rel=1e-9)
    # the solver's log, each change with the label the page's slider has
    assert result["parameters"] == [{"step": 2, "name": "friction_scale", "value": 2.0}]
    assert plots["parameter_log"] == [{**result["parameters"][0], "label": "Friction ×"}]


def test_plots_of_an_unknown_run(env):
    client, _ = env
    r = client.get("/api/runs/nope-q3t-20260101-000000-abcd/plots")
    assert r.status_code == 404 and "nope" in r.json()["detail"]


def test_plotly_is_served_by_the_app(env):
    client, _ = env
    r = client.get("/static/vendor/plotly.min.js")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/javascript")
    assert b"plotly.js" in r.content[:2000]
    missing = client.get("/static/vendor/d3.js")
    assert missing.status_code == 404 and "d3.js" in missing.json()["detail"]


def test_a_long_run_is_thinned_for_the_plots():
    """Every k-th step and the last: a browser is not handed 10^5 points per curve."""
    records = [{"step": k} for k in range(1, 10_002)]
    kept, k = thinned(records, 2000)
    assert k == 6 and kept[0]["step"] == 6 and kept[-1]["step"] == 10_001
    assert all(b["step"] - a["step"] == 6 for a, b in zip(kept[:-2], kept[1:-1], strict=True))
    assert thinned(records[:2000], 2000) == (records[:2000], 1)


def test_recording_of_an_active_run_is_refused(env):
    """A recording still being written would be sent shorter than the length promised (the
    server broke the connection mid-answer): it is a 409 until the run ends."""
    client, _ = env
    run = client.post("/api/runs", json={"scene": "tiny_cup", "paused": True}).json()["id"]
    try:
        wait_state(client, run, {"paused"})
        r = client.get(f"/api/runs/{run}/recording")
        assert r.status_code == 409 and "complete when it ends" in r.json()["detail"]
    finally:
        client.post(f"/api/runs/{run}/stop")
        wait_state(client, run, ENDED)
    r = client.get(f"/api/runs/{run}/recording")
    assert r.status_code == 200 and len(r.content) > 0

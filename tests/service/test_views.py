"""Each browser has its own view (TestClient, viser viewer on; a browser's viewer is a websocket
client naming its view in its path, as the page's iframe does; tests/service/
test_views_browser.py drives the same in two chromium contexts):

- ``/api/view`` with the ``X-Q3T-View`` header selects for that view only; without one, the
  default view; a new run is selected in the view that started it, not in another that shows
  a run; a bad view id is a 422 naming the header.
- Two viewers in two views show their own run, colour mode and time-slider step; the step a
  viewer was scrubbed to is in its view (the page marks it in its plots); a run one browser
  shows stays scrubbable (from its recording) when another's run takes the solver.
- Who started a run is kept; a stop, parameter change or delete from another view is done
  (200 / 204 for scripts), says so in the answer, is noted on the run and told to the
  starter's view; one's own run says nothing.
- The viewer's live-parameter sliders show the result beside each multiplier.
"""

from __future__ import annotations

import pytest

pytest.importorskip("viser")

from server.clientview import scaled_text  # noqa: E402
from tests.support.scenes import tiny_toml  # noqa: E402
from tests.support.service import (  # noqa: E402
    ENDED,
    free_port,
    in_process,
    stop_all,
    until,
    wait_state,
    wait_step,
)
from tests.support.viewer import attached  # noqa: E402

A, B = {"X-Q3T-View": "browser-a"}, {"X-Q3T-View": "browser-b"}


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    scenes = {"tiny": tiny_toml(), "long": tiny_toml(steps=4000)}
    with in_process(tmp_path_factory.mktemp("views"), scenes, viewer=True,
                    viewer_port=free_port(), record_every=1) as (c, _):
        yield c
        stop_all(c)


def run_to_end(client, headers: dict | None = None) -> str:
    r = client.post("/api/runs", json={"scene": "tiny", "element": "linear"},
                    headers=headers or {})
    assert r.status_code == 201, r.text
    assert wait_state(client, r.json()["id"], ENDED)["state"] == "finished"
    return r.json()["id"]


def shown(client, headers: dict) -> str | None:
    return client.get("/api/view", headers=headers).json()["run"]


def test_each_view_selects_its_own_run(client):
    first = run_to_end(client, A)
    assert shown(client, A) == first and shown(client, B) == first  # B: new, on the newest
    second = run_to_end(client, B)
    assert client.get(f"/api/runs/{second}").json()["started_by"] == "browser-b"
    assert shown(client, B) == second
    assert shown(client, A) == first  # A's run stays: a run B started is not A's selection
    assert client.put("/api/view", json={"run": second}, headers=A).json()["run"] == second
    assert client.put("/api/view", json={"run": first}, headers=B).json()["run"] == first
    assert (shown(client, A), shown(client, B)) == (second, first)
    default = shown(client, {})
    assert client.put("/api/view", json={"run": first}).json()["view"] == "default"
    assert shown(client, A) == second and default is not None
    r = client.get("/api/view", headers={"X-Q3T-View": "../x"})
    assert r.status_code == 422 and "X-Q3T-View" in r.text, r.text


def test_two_viewers_show_their_own_run_colours_and_step(client):
    m = client.app.state.manager
    first, second = run_to_end(client, A), run_to_end(client, B)
    with attached(m.viewer, "browser-a") as a, attached(m.viewer, "browser-b") as b:
        until(lambda: a.selected == first and b.selected == second, "not each its own run")
        until(lambda: a.mode == "replay" and b.mode == "live", "the runs are not drawn")
        assert a.gui.run.value == first and b.gui.run.value == second
        a.canvas.field.value = "von Mises stress (MPa)"  # a user's choice in browser A
        assert "MPa" in a.canvas.legend.content
        assert b.canvas.field.value.startswith("Thickness")
        assert "MPa" not in b.canvas.legend.content
        until(lambda: a.gui.time.max == 4, "the recording is not loaded")
        a.gui.time.value = 2  # a user scrubbing A's recording (every step recorded)
        assert client.get("/api/view", headers=A).json()["step"] == 2
        assert client.get("/api/view", headers=B).json()["step"] is None
        assert b.gui.time.value == 4  # B's slider stays at its run's end
        b.gui.run.value = first  # B's own dropdown: B's view, not A's
        assert shown(client, B) == first and shown(client, A) == first
        assert client.get("/api/view", headers=A).json()["step"] == 2
        client.put("/api/view", json={"run": second}, headers=A)
        until(lambda: a.selected == second and a.mode == "live", "A did not follow its view")
        assert b.selected == first
        assert client.get("/api/view", headers=A).json()["step"] is None  # a new selection


def test_the_png_is_of_the_asking_browsers_view(client):
    """Two browsers show the same run: the PNG export renders the one whose view asks (its
    camera and colours), and the exports list gives the page that URL."""
    from server.routers.exports import _viewer_client

    m = client.app.state.manager
    run = run_to_end(client, A)
    client.put("/api/view", json={"run": run}, headers=B)
    with attached(m.viewer, "browser-a") as a, attached(m.viewer, "browser-b") as b:
        until(lambda: a.mode == b.mode == "live", "the run is not shown in both")
        assert _viewer_client(m, run, "browser-a") is a
        assert _viewer_client(m, run, "browser-b") is b
    formats = client.get(f"/api/runs/{run}/exports", headers=B).json()["formats"]
    assert formats[-1]["url"] == f"/api/runs/{run}/export/png?view=browser-b"
    assert client.get(f"/api/runs/{run}/export/png?view=../x").status_code == 422


def test_a_run_shown_after_it_left_the_live_runs_comes_from_its_recording(client):
    """A browser still shows its ended run when another browser's run takes the solver (and
    the kept frames) from it: it is shown from its recording, and scrubs it."""
    m = client.app.state.manager
    run = run_to_end(client, A)
    with attached(m.viewer, "browser-a") as a:
        until(lambda: a.selected == run and a.mode == "live", "A's run is not shown live")
        run_to_end(client, B)
        until(lambda: a.mode == "replay", "A's run did not switch to its recording")
        assert a.selected == run and run not in m.viewer.lives
        a.gui.time.value = 1
        assert a.gui.status.content.endswith("showing recorded step 1")


def test_acting_on_another_views_run_says_so(client):
    m = client.app.state.manager
    run = client.post("/api/runs", json={"scene": "long", "element": "linear"},
                      headers=A).json()["id"]
    try:
        wait_step(client, run, 1)
        since = max([0, *(n["seq"] for n in client.get("/api/view", headers=A).json()
                          ["notices"])])
        own = client.post(f"/api/runs/{run}/pause", headers=A)
        assert own.status_code == 200 and own.json()["notice"] is None
        r = client.put(f"/api/runs/{run}/parameters/friction_scale", json={"value": 2.0},
                       headers=B)
        assert r.status_code == 202 and "started by another page" in r.json()["notice"]
        r = client.post(f"/api/runs/{run}/stop", headers=B)
        assert r.status_code == 200, r.text
        assert r.json()["notice"] == (f"run {run} was started by another page: stopped "
                                      "all the same")
        st = wait_state(client, run, ENDED)
        assert st["state"] == "stopped"
        assert [t["action"] for t in st["touched"]] == ["set friction_scale", "stop"]
        assert {t["by"] for t in st["touched"]} == {"another page"}
        notices = client.get(f"/api/view?since={since}", headers=A).json()["notices"]
        assert [n["action"] for n in notices] == ["set friction_scale", "stop"]
        assert notices[-1]["text"].startswith(f"Run {run} stopped by another page")
        assert client.get(f"/api/view?since={notices[-1]['seq']}",
                          headers=A).json()["notices"] == []
        assert client.get("/api/view", headers=B).json()["notices"] == []  # not B's run
        r = client.delete(f"/api/runs/{run}")  # a script deletes it
        assert r.status_code == 204 and "started by another page" in \
            r.headers["X-Q3T-Notice"]
        last = client.get("/api/view", headers=A).json()["notices"][-1]
        assert last["text"].startswith(f"Run {run} deleted by a script")
        assert run not in m.runs
    finally:
        stop_all(client)
    script = client.post("/api/runs", json={"scene": "long", "element": "linear"}).json()["id"]
    r = client.post(f"/api/runs/{script}/stop", headers=B)
    assert "started by a script" in r.json()["notice"]
    wait_state(client, script, ENDED)


def test_a_viewers_button_on_another_views_run_says_so(client):
    m = client.app.state.manager
    run = client.post("/api/runs", json={"scene": "long", "element": "linear"},
                      headers=A).json()["id"]
    with attached(m.viewer, "browser-b") as b:
        client.put("/api/view", json={"run": run}, headers=B)
        until(lambda: not b.gui.buttons["Stop"].disabled, "B's buttons stayed disabled")
        b.gui.buttons["Stop"].value = True  # pressed in browser B
        assert "started by another page" in b.gui.status.content, b.gui.status.content
    assert wait_state(client, run, ENDED)["state"] == "stopped"
    assert client.get("/api/view", headers=A).json()["notices"][-1]["action"] == "stop"


def test_the_sliders_show_what_each_multiplier_makes():
    items = [{"what": "punch", "unit": "1", "value": 0.1},
             {"what": "holder", "unit": "1", "value": 0.05}]
    assert scaled_text(items, 2.0, {}) == "punch 0.1 × 2 = 0.2; holder 0.05 × 2 = 0.1"
    force = [{"what": "holder", "unit": "N", "value": 20e3}]
    assert scaled_text(force, 1.5, {}) == "holder 20 × 1.5 = 30 kN"
    assert scaled_text([], 2.0, {}) == ""
    # a tool's friction under the run-wide and its own multiplier: both, as the page writes it
    die = [{"what": "die", "unit": "1", "value": 0.1, "also": ["friction_scale.die"]}]
    assert scaled_text(die, 2.0, {"friction_scale.die": 1.5}) == "die 0.1 × 2 × 1.5 = 0.3"
    assert scaled_text(die, 2.0, {"friction_scale.die": 1.0}) == "die 0.1 × 2 = 0.2"

"""Friction per tool through the API: the run's ``friction_scale.<tool>`` are checked by the
server (an unknown tool is a 422 naming it), start at 1, change live, and are logged; the 3-D
viewer's panel has a slider each for the run it shows, as the page does."""

from __future__ import annotations

import pytest

from tests.support.scenes import tiny_cup_toml, tiny_toml
from tests.support.service import free_port, in_process, stop_all, until
from tests.support.viewer import attached

pytest.importorskip("fastapi")


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("tool-friction")
    with in_process(tmp, {"cup": tiny_cup_toml(steps=400), "plate": tiny_toml(steps=400)},
                    viewer=True, viewer_port=free_port()) as (c, _):
        yield c
        stop_all(c)


def test_config_names_the_per_tool_parameters(client):
    cfg = client.get("/api/config").json()
    assert cfg["tool_parameters"]["friction_scale"]["max"] == cfg["parameters"][
        "friction_scale"]["max"]
    assert "friction_scale.die" not in cfg["parameters"]  # a run's, not the server's


def test_an_unknown_tool_is_a_422_naming_it(client):
    r = client.post("/api/runs", json={"scene": "cup", "parameters": {"friction_scale.dye": 2}})
    assert r.status_code == 422
    assert "friction_scale.dye: unknown tool 'dye'" in r.text and "die, punch" in r.text
    r = client.post("/api/runs", json={"scene": "cup", "parameters": {"friction_scale.die": 20}})
    assert r.status_code == 422 and "friction_scale.die: 20.0 out of range" in r.text
    assert client.get("/api/runs").json() == []  # refused before anything was written


def test_a_tools_friction_starts_given_and_changes_live(client):
    run = client.post("/api/runs", json={"scene": "cup", "paused": True,
                                         "parameters": {"friction_scale.die": 2.0}}).json()["id"]
    st = client.get(f"/api/runs/{run}").json()
    assert st["parameters"]["friction_scale.die"] == 2.0
    assert st["parameters"]["friction_scale.punch"] == 1.0
    r = client.put(f"/api/runs/{run}/parameters/friction_scale.nope", json={"value": 2.0})
    assert r.status_code == 422 and "unknown tool 'nope'" in r.text, r.text
    r = client.put(f"/api/runs/{run}/parameters/friction_scale.punch", json={"value": 0.5})
    assert r.status_code == 202 and r.json()["applied"], r.text
    st = until(lambda: (s := client.get(f"/api/runs/{run}").json())["scaled"]
               and not s["pending"] and s, "the solver never built the run")
    assert st["parameters"]["friction_scale.punch"] == 0.5
    assert st["parameter_log"][-1]["name"] == "friction_scale.punch"
    # what the page shows beside the slider: the die's 0.1, times the run-wide multiplier
    assert st["scaled"]["friction_scale.die"] == [
        {"what": "die", "unit": "1", "value": 0.1, "also": ["friction_scale"]}]


def test_the_viewers_panel_has_the_shown_runs_tools(client):
    """A slider per tool with friction while a cup run is shown, labelled as on the page, its
    result under both multipliers; none for a run without tools."""
    stop_all(client)
    viewer = client.app.state.manager.viewer
    with attached(viewer) as cv:
        run = client.post("/api/runs", json={"scene": "cup", "paused": True, "parameters": {
            "friction_scale": 2.0, "friction_scale.die": 1.5}}).json()["id"]
        tools = {"friction_scale.die", "friction_scale.punch"}
        until(lambda: tools <= set(cv.gui.sliders), f"no tool sliders: {set(cv.gui.sliders)}")
        die = cv.gui.sliders["friction_scale.die"]
        assert die.label == "Friction × die" and die.value == 1.5
        # its own multiplier first, as the page writes it
        until(lambda: "die 0.1 × 1.5 × 2 = 0.3" in cv.gui.results["friction_scale.die"].content,
              "the die's friction under both multipliers")
        assert "die 0.1 × 2 × 1.5 = 0.3" in cv.gui.results["friction_scale"].content
        # moved in the viewer: the run's value changes, as from the page
        die.value = 0.5
        until(lambda: client.get(f"/api/runs/{run}").json()["parameters"][
            "friction_scale.die"] == 0.5, "the viewer's slider did not reach the run")
        stop_all(client)
        plate = client.post("/api/runs", json={"scene": "plate", "paused": True}).json()["id"]
        until(lambda: cv.selected == plate and not set(cv.gui.sliders) & tools,
              f"the cup's tool sliders stayed: {set(cv.gui.sliders)}")
        client.put("/api/view", json={"run": run})  # the cup again: its sliders, its values
        until(lambda: tools <= set(cv.gui.sliders), "the cup's tool sliders did not come back")
        assert cv.gui.sliders["friction_scale.die"].value == 0.5
        stop_all(client)

"""What the page shows is what runs, through the API (TestClient, viser viewer on, no browser;
tests/test_trust_browser.py drives the same in chromium):

- Start with the page's unsaved edits runs the edited scene, kept as the run's scene.toml and
  marked ``edited``; an unchanged scene re-rendered by the form is no edit; a bad edit is a 422
  naming the field, and nothing is written.
- One selected run per view, held by the server (``/api/view``; here the default view, which
  requests without a view id and a viewer opened without one share): a new run is selected, a
  selection moves the viewer (live or its recording) and the viewer's "Run" dropdown moves it
  back (other browsers' views: tests/service/test_views.py).
- A run's status holds every live parameter's value from its start; the viewer's sliders
  follow the selected run's values (after a change, on a new run, on selecting an older run).
"""

from __future__ import annotations

import json
import os
import tomllib

import pytest

pytest.importorskip("viser")
from fastapi.testclient import TestClient  # noqa: E402

from server import sceneform, tomlout  # noqa: E402
from server.app import create_app  # noqa: E402
from server.settings import Settings  # noqa: E402
from tests.support.scenes import EDITED_EDGE, tiny_toml, vertices  # noqa: E402
from tests.support.service import (  # noqa: E402
    HANG,
    free_port,
    stop_all,
    until,
    wait_ready,
    wait_state,
    wait_step,
)
from tests.support.viewer import attached, default_view  # noqa: E402

ENDED = {"finished", "failed", "stopped"}


def edited_toml() -> str:
    text = tiny_toml()
    assert "edge_length = 0.035\n" in text
    return text.replace("edge_length = 0.035\n",
                        f"edge_length = {EDITED_EDGE}  # edited in the form, not saved\n")



@pytest.fixture(scope="module")
def env(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("trust")
    os.environ.setdefault("XDG_CONFIG_HOME", str(tmp / "config"))
    os.environ.setdefault("XDG_DATA_HOME", str(tmp / "data"))
    (tmp / "scenes").mkdir()
    (tmp / "scenes" / "tiny.toml").write_text(tiny_toml())
    (tmp / "scenes" / "long.toml").write_text(tiny_toml(steps=4000))
    # a parameter change waits for the solver's answer between two steps: a hang guard here
    settings = Settings(scenes_dir=tmp / "scenes", runs_dir=tmp / "runs", viewer=True,
                        viewer_port=free_port(), ack_timeout=HANG)
    with TestClient(create_app(settings)) as client:
        wait_ready(client)
        yield client, settings


@pytest.fixture(scope="module")
def viewer(env):
    """A browser's view with no view id: the default view."""
    with attached(env[0].app.state.manager.viewer) as cv:
        yield cv


def stop_active(client) -> None:
    stop_all(client)


def run_to_end(client, **body) -> dict:
    r = client.post("/api/runs", json={"element": "linear", **body})
    assert r.status_code == 201, r.text
    return wait_state(client, r.json()["id"], ENDED)


def test_start_runs_the_edited_scene(env):
    client, settings = env
    saved = (settings.scenes_dir / "tiny.toml").read_text()
    text = edited_toml()
    assert vertices(text) > vertices(saved)
    st = run_to_end(client, scene="tiny", toml=text)
    assert st["state"] == "finished", st["reason"]
    assert st["edited"] is True
    assert st["counts"]["vertices"] == vertices(text)  # the edited mesh, not the saved one
    # what ran: the edited text with the run's element (linear, the file's q3t) under a head
    # that says so (its comments are the saved file's): it runs again as it ran
    kept = (settings.runs_dir / st["id"] / "scene.toml").read_text()
    assert client.get(f"/api/runs/{st['id']}/scene").text == kept
    head, rest = kept.split("\n\n", 1)
    assert rest == tomlout.with_element(text, "linear")
    ran = tomllib.loads(text)
    ran["shell"]["element"] = "linear"
    assert tomllib.loads(kept) == ran
    assert " ".join(line.removeprefix("# ") for line in head.splitlines()) == (
        f"Run {st['id']}, the scene as it ran. It ran the page's unsaved edits of tiny: "
        f"mesh.edge_length 35 → {EDITED_EDGE * 1e3:.4g} mm. The comments below are the saved "
        "file's: they may describe its values. It ran element linear, not the file's q3t: "
        "[shell] below says what ran.")
    assert (settings.scenes_dir / "tiny.toml").read_text() == saved  # nothing saved
    listed = {r["id"]: r for r in client.get("/api/runs").json()}
    assert listed[st["id"]]["edited"] is True
    # the Runs table tells such runs apart by what the edits changed, in the form's units
    edit = f"mesh.edge_length 35 → {EDITED_EDGE * 1e3:.4g} mm"
    element = "element linear (the scene's q3t)"  # a column of its own, and a change too
    assert st["edits"] == [edit] and st["changes"] == [edit, element]
    # with an override beside them, read twice: each read says each once
    other = run_to_end(client, scene="tiny", toml=text, overrides={"stepping.steps": 4})
    for _ in range(2):
        again = client.get(f"/api/runs/{other['id']}").json()
        assert again["edits"] == [edit]
        assert again["changes"] == [edit, element, "stepping.steps = 4"]
    kept = (settings.runs_dir / other["id"] / "scene.toml").read_text()
    assert "Overrides on top of this file (run.json): stepping.steps = 4." in \
        kept.replace("\n# ", " ")
    given = run_to_end(client, scene="tiny", parameters={"friction_scale": 2.0}, element="q3t")
    kept = (settings.runs_dir / given["id"] / "scene.toml").read_text().replace("\n# ", " ")
    assert "Live parameters from its start: friction_scale ×2 (changes while it ran: " \
        "run.json's parameter log)." in kept, kept
    # an element other than the file's, alone: said too
    linear = run_to_end(client, scene="tiny")
    kept = (settings.runs_dir / linear["id"] / "scene.toml").read_text()
    head, rest = kept.split("\n\n", 1)
    assert rest == tomlout.with_element(saved, "linear")
    assert 'element = "linear"' in rest and 'element = "q3t"' not in rest
    assert " ".join(line.removeprefix("# ") for line in head.splitlines()) == (
        f"Run {linear['id']}, the scene as it ran. It ran element linear, not the file's q3t: "
        "[shell] below says what ran.")


def test_the_saved_scene_rerendered_by_the_form_is_no_edit(env):
    """The form's TOML of an unchanged scene loses the file's comments: it runs the saved file,
    comments kept, and is not marked edited."""
    client, settings = env
    saved = (settings.scenes_dir / "tiny.toml").read_text()
    rendered = sceneform.render(sceneform.parse(saved)["scene"])["toml"]
    assert rendered != saved and tomllib.loads(rendered)["mesh"]["edge_length"] == 0.035
    st = run_to_end(client, scene="tiny", toml=rendered, element="q3t")
    assert st["state"] == "finished" and st["edited"] is False, st
    assert st["counts"]["vertices"] == vertices(saved)
    # the saved file with its own element: as saved, no head
    assert (settings.runs_dir / st["id"] / "scene.toml").read_text() == saved
    plain = run_to_end(client, scene="tiny")  # no text sent: the saved file, as before
    assert plain["edited"] is False


def test_a_bad_edit_is_refused_naming_the_field(env):
    client, settings = env
    before = sorted(p.name for p in settings.runs_dir.iterdir())
    bad = tiny_toml().replace("edge_length = 0.035", "edge_length = -0.01")
    r = client.post("/api/runs", json={"scene": "tiny", "toml": bad})
    assert r.status_code == 422 and "mesh.edge_length" in r.json()["detail"], r.text
    r = client.post("/api/runs", json={"scene": "tiny", "toml": "name = ["})
    assert r.status_code == 422, r.text
    r = client.post("/api/runs", json={"scene": "tiny", "toml": 5})
    assert r.status_code == 422 and "toml" in r.json()["detail"], r.text
    assert sorted(p.name for p in settings.runs_dir.iterdir()) == before
    assert client.get("/api/health").json()["active"] == []


def test_one_selected_run_for_page_and_viewer(env, viewer):
    client, settings = env
    older = run_to_end(client, scene="tiny")["id"]
    newer = run_to_end(client, scene="tiny")["id"]
    assert client.get("/api/view").json() == default_view(newer)  # a new run is selected
    assert viewer.selected == viewer.gui.run.value == newer
    until(lambda: viewer.mode == "live", "the latest run is not shown live")
    # the page selects the older run: the viewer shows its recording
    assert client.put("/api/view", json={"run": older}).json() == default_view(older)
    assert client.get("/api/view").json() == default_view(older)
    assert viewer.selected == viewer.gui.run.value == older
    until(lambda: viewer.mode == "replay", "the older run's recording is not shown")
    assert f"`{older}`" in viewer.gui.status.content
    # the viewer's dropdown selects for the page too
    viewer.gui.run.value = newer
    assert client.get("/api/view").json() == default_view(newer) and viewer.mode == "live"
    # refused selections change nothing
    assert client.put("/api/view", json={"run": "nope-linear-1"}).status_code == 404
    assert client.put("/api/view", json={"run": "../x"}).status_code == 422
    assert client.put("/api/view", json={}).status_code == 422
    assert client.get("/api/view").json() == default_view(newer)
    # the selected run deleted: the newest left is selected
    client.put("/api/view", json={"run": older})
    assert client.delete(f"/api/runs/{older}").status_code == 204
    newest = client.get("/api/runs").json()[0]["id"]
    assert client.get("/api/view").json() == default_view(newest)
    until(lambda: viewer.selected == newest and older not in viewer.gui.run.options,
          "the viewer kept the deleted run")


def enabled(viewer) -> set[str]:
    return {label for label, b in viewer.gui.buttons.items() if not b.disabled}


def test_run_buttons_follow_its_state_on_the_page_and_in_the_viewer(env, viewer):
    """One rule (``Run.controls``) for the page's buttons and the viewer's: Pause while it
    runs, Resume while it is paused or a pause is on its way, Step and Stop while active;
    none once it has ended (the viewer's were all enabled while active)."""
    client, _ = env
    stop_active(client)
    run = client.post("/api/runs", json={"scene": "long", "element": "linear"}).json()["id"]
    try:
        assert wait_step(client, run, 1)["controls"] == ["pause", "step", "stop"]
        client.put("/api/view", json={"run": run})
        until(lambda: enabled(viewer) == {"Pause", "Step", "Stop"},
              f"viewer's buttons while running: {enabled(viewer)}")
        # the answer to Pause offers Resume at once: the pause is on its way (pending) or done
        r = client.post(f"/api/runs/{run}/pause").json()
        assert r["controls"] == ["resume", "step", "stop"], r
        wait_state(client, run, {"paused"})
        until(lambda: enabled(viewer) == {"Resume", "Step", "Stop"},
              f"viewer's buttons while paused: {enabled(viewer)}")
        assert client.post(f"/api/runs/{run}/resume").json()["controls"] == \
            ["pause", "step", "stop"]
    finally:
        stop_active(client)
    assert client.get(f"/api/runs/{run}").json()["controls"] == []
    until(lambda: not enabled(viewer), f"viewer's buttons of an ended run: {enabled(viewer)}")


def sliders(viewer) -> dict:
    return {k: s.value for k, s in viewer.gui.sliders.items()}


def test_controls_show_the_selected_runs_values(env, viewer):
    client, _ = env
    names = set(client.get("/api/config").json()["parameters"])
    until(lambda: set(viewer.gui.sliders) == names, "the viewer has no parameter sliders")
    stop_active(client)
    first = client.post("/api/runs", json={"scene": "long", "element": "linear",
                                           "parameters": {"tool_speed": 2.0}}).json()["id"]
    try:
        st = client.get(f"/api/runs/{first}").json()
        assert st["parameters"] == {**dict.fromkeys(names, 1.0), "tool_speed": 2.0}
        wait_step(client, first, 1)
        r = client.put(f"/api/runs/{first}/parameters/friction_scale", json={"value": 2.0})
        assert r.status_code == 202 and r.json()["applied"], r.text
        changed = {**dict.fromkeys(names, 1.0), "tool_speed": 2.0, "friction_scale": 2.0}
        assert client.get(f"/api/runs/{first}").json()["parameters"] == changed
        until(lambda: sliders(viewer) == changed, f"viewer sliders {sliders(viewer)}")
        assert not viewer.gui.sliders["friction_scale"].disabled
    finally:
        stop_active(client)
    until(lambda: viewer.gui.sliders["friction_scale"].disabled,
          "the sliders of an ended run stayed enabled")
    # a new run starts as written: the sliders show its values, not the last run's
    second = client.post("/api/runs", json={"scene": "long", "element": "linear"}).json()["id"]
    try:
        assert client.get(f"/api/runs/{second}").json()["parameters"] == \
            dict.fromkeys(names, 1.0)
        until(lambda: sliders(viewer) == dict.fromkeys(names, 1.0),
              f"viewer sliders {sliders(viewer)} after a new run")
    finally:
        stop_active(client)
    # the older run selected: its values, as it ended
    client.put("/api/view", json={"run": first})
    assert sliders(viewer) == changed
    assert all(s.disabled for s in viewer.gui.sliders.values())


def test_a_finished_runs_record_holds_its_fields_ranges_over_every_step(env):
    """The solver frames every step for the viewer; the recording keeps every N-th. The run's
    record (run.json) takes each field's range over every step from the solver's end, as
    result.json has it, and a replay of the run colours over it (server.clientview)."""
    client, settings = env
    st = run_to_end(client, scene="tiny")
    assert st["state"] == "finished", st["reason"]
    result = json.loads((settings.runs_dir / st["id"] / "result.json").read_text())
    ranges = result["field_ranges"]
    assert ranges and all(lo <= hi for lo, hi in ranges.values())
    m = client.app.state.manager
    assert {k: list(v) for k, v in m.runs[st["id"]].field_ranges.items()} == ranges
    rep, why = m.viewer.actions.recording(st["id"])  # the env's server has its viewer on
    assert rep is not None, why
    assert {k: list(v) for k, v in rep.ranges.items()} == ranges

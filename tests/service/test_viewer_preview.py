"""Choosing a scene previews it in the viewer before any run (``PUT /api/view/scene``): the
solver process builds the scene's model and the viewer shows its blank (the display surface of
the built model, at rest) and its tools at their start positions. No run is made; bad input is
refused naming the field; an edited, unsaved scene previews as shown; a run, once selected or
started, shows again."""

from __future__ import annotations

import os

import numpy as np
import pytest

pytest.importorskip("viser")
from fastapi.testclient import TestClient  # noqa: E402

from server.app import create_app  # noqa: E402
from server.settings import Settings  # noqa: E402
from sim.scene.load import scene_from_toml  # noqa: E402
from sim.stepping.simulation import Simulation  # noqa: E402
from tests.support.scenes import PRESS_TOML, tiny_toml  # noqa: E402
from tests.support.service import free_port, until, wait_state  # noqa: E402
from tests.support.viewer import attached, default_view  # noqa: E402


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("preview")
    os.environ.setdefault("XDG_CONFIG_HOME", str(tmp / "config"))
    os.environ.setdefault("XDG_DATA_HOME", str(tmp / "data"))
    (tmp / "scenes").mkdir()
    (tmp / "scenes" / "press.toml").write_text(PRESS_TOML)
    (tmp / "scenes" / "tiny.toml").write_text(tiny_toml())
    settings = Settings(scenes_dir=tmp / "scenes", runs_dir=tmp / "runs", viewer=True,
                        viewer_port=free_port())
    with TestClient(create_app(settings)) as c:
        yield c


@pytest.fixture(scope="module")
def viewer(client):
    """A browser's view (no view id: the default view, which the API selects for)."""
    with attached(client.app.state.manager.viewer) as cv:
        yield cv


def shown(client: TestClient, scene: str) -> dict:
    """The view once the preview of ``scene`` is built (or failed)."""
    return until(lambda: (v := client.get("/api/view").json())["scene"] == scene
                 and v["preview"] != "building" and v, f"the preview of {scene} never came")


def showing(viewer, mode: str, subject: str, legend: str) -> None:  # noqa: ANN001
    """Wait until ``viewer`` shows ``mode`` with that ``subject`` and a legend saying
    ``legend``."""
    until(lambda: viewer.mode == mode and viewer.subject.content == subject
          and legend in viewer.canvas.legend.content,
          f"the viewer never showed {mode} with {subject!r} and {legend!r}")


def rest(text: str) -> Simulation:
    return Simulation.from_scene(scene_from_toml(text))


def test_a_scene_previews_its_blank_and_tools_before_any_run(client, viewer):
    assert client.get("/api/runs").json() == [] and viewer.mode == "none"
    r = client.put("/api/view/scene", json={"scene": "press"})
    assert r.status_code == 200, r.text
    assert r.json()["scene"] == "press"
    view = shown(client, "press")
    assert view["preview"] == "shown", view
    assert view["run"] is None  # no run was made for it
    until(lambda: viewer.mode == "preview", "the viewer did not show the preview")
    sim = rest(PRESS_TOML)
    np.testing.assert_array_equal(viewer.canvas.faces, sim.display.faces)
    np.testing.assert_allclose(viewer.canvas.frame["positions"], sim.display.positions(sim.x))
    assert viewer.canvas.frame["step"] == 0
    assert sorted(viewer.canvas.tools) == ["ground", "punch"]
    # the tools where the scene puts them at the start (the punch above the plate)
    np.testing.assert_allclose(viewer.canvas.tools["punch"].position, [0.0, 0.0, 0.00025],
                               atol=1e-9)
    np.testing.assert_allclose(viewer.canvas.tools["ground"].position, [0.0, 0.0, -0.00025],
                               atol=1e-9)
    assert "Preview of scene `press`" in viewer.gui.status.content
    assert "Thickness" in viewer.canvas.legend.content  # coloured, with its legend
    # its range is the blank's at rest, not a run's (there is none)
    assert "range of the blank of scene press at rest (no run)" in viewer.canvas.legend.content
    assert client.get("/api/runs").json() == []


def test_an_edited_scene_previews_as_shown(client, viewer):
    edited = PRESS_TOML.replace("edge_length = 0.005", "edge_length = 0.0025")
    r = client.put("/api/view/scene", json={"scene": "press", "toml": edited})
    assert r.status_code == 200, r.text
    assert shown(client, "press")["preview"] == "shown"
    until(lambda: len(viewer.canvas.faces) == len(rest(edited).display.faces),
          "the preview is not the edited mesh")
    assert len(viewer.canvas.faces) > len(rest(PRESS_TOML).display.faces)


@pytest.mark.parametrize(("body", "status", "names"), [
    ({"scene": "nope"}, 404, "nope"),
    ({"scene": "press", "toml": PRESS_TOML.replace("nu = 0.33", "nu = 0.7")}, 422,
     "material.nu"),
    ({"scene": "press", "extra": 1}, 422, "extra"),
    ({"scene": 3}, 422, "scene"),
])
def test_bad_preview_requests_name_the_field(client, body, status, names):
    r = client.put("/api/view/scene", json=body)
    assert r.status_code == status, r.text
    assert names in r.json()["detail"]


def test_a_refused_preview_clears_the_view_under_its_reason(client, viewer):
    """Edits the server refuses to preview (a 422): the view no longer shows the previous
    preview under words that claim it is these edits' (a browser review)."""
    assert client.put("/api/view/scene", json={"scene": "press"}).status_code == 200
    until(lambda: viewer.mode == "preview", "no preview of press")
    bad = PRESS_TOML.replace("nu = 0.33", "nu = 0.7")
    r = client.put("/api/view/scene", json={"scene": "press", "toml": bad})
    assert r.status_code == 422, r.text
    assert viewer.mode == "none" and viewer.previewed is None
    view = client.get("/api/view").json()  # still the scene's preview: its edits go on to show
    assert (view["scene"], view["preview"]) == ("press", "failed")
    assert view["preview_error"].startswith("material.nu"), view
    assert viewer.gui.status.content.startswith(
        "Preview of scene `press` with its unsaved edits refused: material.nu"), \
        viewer.gui.status.content


def test_a_run_shows_again_once_started_or_selected(client, viewer):
    run = client.post("/api/runs", json={"scene": "tiny", "element": "linear"}).json()["id"]
    assert client.get("/api/view").json() == default_view(run)
    assert wait_state(client, run, {"finished", "failed", "stopped"})["state"] == "finished"
    # the live parameters under the preview still act on the run: they say which (the
    # viewer draws on its own thread: mode, subject and legend are waited for together)
    live = f"<small>of run `{run}`</small>"
    showing(viewer, "live", live, "range of this run")
    client.put("/api/view/scene", json={"scene": "press"})
    assert shown(client, "press")["run"] == run  # still the selected run
    showing(viewer, "preview", f"<small>of run `{run}`, not of the scene `press` previewed"
            "</small>", "range of the blank of scene press at rest (no run)")
    assert client.put("/api/view", json={"run": run}).status_code == 200
    showing(viewer, "live", live, "range of this run")
    assert client.get("/api/view").json()["scene"] is None


def test_a_preview_that_cannot_be_built_says_why(client, viewer):
    """The solver process answers a scene it cannot build with the reason (its reply is still
    ok: the active run is never marked by a preview); the view and the viewer say why."""
    import queue

    from server.worker import Solver

    events: queue.Queue = queue.Queue()
    solver = Solver(events, queue.Queue(), record_every=1, step_delay=0.0)
    solver.handle({"cmd": "preview", "id": 7, "scene": "broken", "scene_toml": "name = ["})
    ev, reply = events.get_nowait(), events.get_nowait()
    assert ev["kind"] == "preview" and ev["request"] == 7 and "error" in ev
    assert reply["kind"] == "reply" and reply["ok"]
    m = client.app.state.manager
    with m.lock:
        m.views.views["default"].preview = {"scene": "broken", "request": 7,
                                            "state": "building"}
    m.views.show_preview(ev)
    view = client.get("/api/view").json()
    assert view["preview"] == "failed" and view["preview_error"] == ev["error"]
    assert "Preview of scene `broken` failed" in viewer.gui.status.content
    # nothing drawn under those words: not the geometry the view showed before
    assert viewer.mode == "none" and viewer.previewed is None
    m.views.show_preview({**ev, "request": 6})  # an earlier request answered late: ignored
    assert client.get("/api/view").json() == view


def test_a_viewer_connecting_while_its_preview_builds_shows_it_when_built(client, viewer):
    """A page asks for its preview, and its viewer connects while the solver builds it (a
    page's first look, on a loaded machine): the viewer says it is building, and shows the
    preview when it comes, instead of taking the run and dropping the preview."""
    import queue

    from server.worker import Solver

    events: queue.Queue = queue.Queue()
    solver = Solver(events, queue.Queue(), record_every=1, step_delay=0.0)
    m = client.app.state.manager
    with m.lock:
        m.views.views["default"].preview = {"scene": "press", "request": 9,
                                            "state": "building"}
    m.views.connected("default")  # what a viewer connecting now does
    assert client.get("/api/view").json()["preview"] == "building"
    assert "Preview of scene `press`: building its model" in viewer.gui.status.content
    solver.handle({"cmd": "preview", "id": 9, "scene": "press", "scene_toml": PRESS_TOML})
    ev = events.get_nowait()
    assert ev["kind"] == "preview" and "error" not in ev, ev
    m.views.show_preview(ev)
    assert client.get("/api/view").json()["preview"] == "shown"
    assert viewer.mode == "preview"
    assert "Preview of scene `press`: its blank and tools" in viewer.gui.status.content
    # a viewer connecting once it is built draws it too; with no preview, the run
    m.views.connected("default")
    assert viewer.mode == "preview" and client.get("/api/view").json()["preview"] == "shown"

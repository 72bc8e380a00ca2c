"""A tool's surface uploaded from the scene form in Debian's chromium (Playwright), against the
real server in a subprocess: a punch's shape switched to kind ``mesh`` offers the scenes
folder's mesh files and an Upload button; a closed surface uploaded there is chosen, saved and
run (it presses the plate); an open one says why in the form. With $Q3T_SHOTS
set, screenshots go to `$Q3T_SHOTS/tool-files/`."""

from __future__ import annotations

import os
from pathlib import Path

import httpx
import pytest
import trimesh

from tests.support.browser import serve, shot, shots_dir
from tests.support.scenes import PRESS_TOML
from tests.support.service import until

SHOTS = shots_dir("tool-files")
pytestmark = pytest.mark.browser
sync_api = pytest.importorskip("playwright.sync_api", reason="playwright not installed")
FIELD = "tools.1.shape.path"  # the press's punch


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("tool-files-browser")
    os.environ["Q3T_CACHE"] = str(tmp / "cache")  # the server inherits it: no user's cache
    try:
        with serve(tmp, {"press": PRESS_TOML}, "press", "--no-viewer") as (url, _):
            yield url, tmp
    finally:
        del os.environ["Q3T_CACHE"]


@pytest.fixture
def page(open_page, served):
    return open_page(served[0], "#scenes li.sel", "[name='tools.1.shape.kind']")


def status(page) -> str:
    return page.inner_text(f"[data-path='{FIELD}'] .upload-status")


def upload(page, path: Path) -> None:
    with page.expect_file_chooser() as chooser:
        page.click(f"[data-path='{FIELD}'] button.upload")
    chooser.value.set_files(str(path))


def left_column(page, name: str) -> None:
    """The left column, scrolled to the tool's field."""
    if SHOTS is not None:
        page.locator(f"[data-path='{FIELD}']").scroll_into_view_if_needed()
    shot(page, SHOTS, name, where="#left")


def punch_mesh() -> trimesh.Trimesh:
    """The press's punch as a closed surface: a cylinder of radius 4 mm, nose at z = 0."""
    return trimesh.creation.cylinder(radius=0.004, height=0.01, sections=48).apply_translation(
        [0.0, 0.0, 0.005])


def test_a_tool_surface_uploaded_from_the_form_runs(page, served):
    url, tmp = served
    mine = tmp / "mine"
    mine.mkdir()
    punch_mesh().export(mine / "Punch v1.stl")
    two = mine / "two.stl"  # two punches through each other
    trimesh.util.concatenate([punch_mesh(), punch_mesh().apply_translation([0.002, 0, 0])]
                             ).export(two)
    open_one = mine / "open.stl"  # the working faces, its top left open, as CAD gives a die's
    m = punch_mesh()
    trimesh.Trimesh(m.vertices, m.faces[m.triangles_center[:, 2] < 0.0099]).export(open_one)

    page.select_option("[name='tools.1.shape.kind']", "mesh")
    page.wait_for_selector(f"[data-path='{FIELD}'] select.file-select")
    left_column(page, "1-mesh-kind.png")
    upload(page, two)  # refused: the form says why, nothing is kept
    until(lambda: "self-intersecting" in status(page), "no refusal shown", 300)
    assert status(page).startswith("two.stl: self-intersecting: ")
    assert not (tmp / "scenes" / "two.stl").exists()
    left_column(page, "2-refused.png")
    # a file chosen by hand: the refusal goes (it stood under a valid choice, a review)
    page.select_option(f"[name='{FIELD}']", index=0)
    assert status(page) == ""
    upload(page, open_one)  # kept, and the form says what the scene must say of it
    until(lambda: status(page).startswith("uploaded"), "no upload", 300)
    assert status(page) == ("uploaded open.stl: tool mesh: 97 vertices, 144 triangles, open "
                            "(set open: the tool behind its faces); 0.008 × 0.008 × 0.01 "
                            "across in the file's units (scale: metres per unit)")
    left_column(page, "2-open-kept.png")

    upload(page, mine / "Punch v1.stl")
    until(lambda: status(page).startswith("uploaded"), "no upload", 300)
    assert status(page) == ("uploaded Punch_v1.stl: tool mesh: 98 vertices, 192 triangles; "
                            "0.008 × 0.008 × 0.01 across in the file's units (scale: metres "
                            "per unit)")
    assert page.input_value(f"[name='{FIELD}']") == "Punch_v1.stl"
    page.wait_for_function("""() => document.getElementById('toml').value
        .includes('path = "Punch_v1.stl"')""")
    assert page.inner_text("#sync") == "valid"
    left_column(page, "3-uploaded.png")

    page.fill("#scene-name", "meshpress")
    page.click("#save")
    # a new name: saved as a new scene (the one opened stays as it was)
    page.wait_for_function("document.getElementById('msg').textContent"
                           ".startsWith('saved as meshpress (')")
    page.click("#start")
    run = until(lambda: httpx.get(url + "/api/runs").json(), "no run")[0]["id"]
    done = until(lambda: (st := httpx.get(f"{url}/api/runs/{run}").json())["state"]
                 in ("finished", "failed", "stopped") and st, "the run never ended")
    assert done["state"] == "finished", done["reason"]
    result = httpx.get(f"{url}/api/runs/{run}/result").json()
    assert result["steps"][-1]["probes"]["punch_force"] > 0  # the uploaded punch pressed
    files = {f["name"]: f for f in httpx.get(url + "/api/files").json()["files"]}
    assert files["Punch_v1.stl"]["used_by"] == ["meshpress"]
    shot(page, SHOTS, "4-run.png", settle_ms=1500)  # the run's plots settle first

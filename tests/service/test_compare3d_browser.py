"""Two runs side by side in 3-D at the same punch stroke, in Debian's chromium (Playwright),
against the real server saving every step's frame, with two finished runs of a small cup
(tests.support.scenes.tiny_cup_toml): A as written (0.5 mm a step), B at half the tool speed
(0.25 mm a step), so they reach a stroke at other steps.

- the Compare view opens at the deepest stroke both reached (2 mm: A's step 4, B's step 8),
  the slider spans the strokes both saved (0 to 2 mm) and the line under it says which frame
  (step, stroke in mm) each view shows;
- moving the slider (the keyboard's Home, then a stroke between two frames) redraws both views
  and the A - B map with each run's nearest frame, coloured by the thickness the API gives
  on one scale, in the same box (mm, true proportions) at every stroke;
- turning one view turns the others with it, and a new stroke keeps the camera (plotly's
  layout camera);
- a third run on another mesh: no A - B map, the reason in its place; once its frames are
  gone (as a sweep case written without them), no views, the reason instead.

With Q3T_SHOTS set, screenshots go to `$Q3T_SHOTS/compare3d/`."""

from __future__ import annotations

import shutil

import httpx
import pytest

from tests.support.browser import new_page, serve, shot, shots_dir
from tests.support.scenes import tiny_cup_toml
from tests.support.service import finished_run

SHOTS = shots_dir("compare3d")
VIEWS = ("#compare-3d-a", "#compare-3d-b", "#compare-3d-diff")
pytestmark = pytest.mark.browser
sync_api = pytest.importorskip("playwright.sync_api", reason="playwright not installed")


def _finished(url: str, **body) -> str:
    return finished_run(httpx.Client(base_url=url), **body)


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """The server's url and three finished runs of tiny_cup: as written, at half the tool
    speed, and on a finer mesh."""
    tmp = tmp_path_factory.mktemp("compare3d-browser")
    with serve(tmp, {"tiny_cup": tiny_cup_toml()}, "tiny_cup", "--no-viewer",
               "--record-every", "1") as (url, _):
        yield url, [_finished(url), _finished(url, parameters={"tool_speed": 0.5}),
                    _finished(url, overrides={"mesh.edge_length": 0.002})], tmp / "runs"


def shots(page, name: str) -> None:
    """The window, and the views at a stroke alone."""
    shot(page, SHOTS, name, settle_ms=1500)  # plotly's WebGL in software draws in about a second
    shot(page, SHOTS, f"{name}-views", where="#compare-stroke")


def open_compare(browser, url: str, a: str, b: str):
    page, errors = new_page(browser, url, "#compare-box")
    page.click("#compare-box > summary")
    for run in (a, b):
        page.check(f"#compare-runs input[value='{run}']")
    page.wait_for_function("document.querySelector('#compare-open').textContent"
                           ".includes('2 runs')")
    page.click("#compare-open")
    return page, errors


def shown_steps(page) -> list[str]:
    return page.eval_on_selector_all(",".join(VIEWS[:2]), "ds => ds.map(d => d.dataset.step)")


def wait_steps(page, a: int, b: int) -> None:
    page.wait_for_function(
        f"['#compare-3d-a', '#compare-3d-b'].map(s => document.querySelector(s).dataset.step)"
        f".join() === '{a},{b}' && document.querySelector('#compare-3d-diff').dataset.step "
        f"=== '{a}'")


def intensities(page, selector: str) -> list[float]:
    return page.eval_on_selector(selector, "d => Array.from(d.data[0].intensity)")


def scene_box(page) -> list:
    """Each view's axis ranges (mm) and aspect ratio."""
    return page.eval_on_selector_all(",".join(VIEWS), "ds => ds.map(d => { const s = "
                                     "d.layout.scene; return [s.xaxis.range, s.yaxis.range, "
                                     "s.zaxis.range, s.aspectratio]; })")


def camera_eye(page, selector: str) -> dict:
    return page.eval_on_selector(selector, "d => d.layout.scene.camera.eye")


def test_two_views_follow_the_stroke_slider(served, browser):
    url, (a, b, _), _ = served
    page, errors = open_compare(browser, url, a, b)
    wait_steps(page, 4, 8)  # the deepest stroke both reached: A's last step, B's
    page.locator("#compare-stroke").scroll_into_view_if_needed()
    slider = page.locator("#compare-stroke-slider")
    assert (slider.get_attribute("min"), slider.get_attribute("max")) == ("0", "2")
    text = page.text_content("#compare-stroke-shown")
    assert "A: frame of step 4 at 2.000 mm" in text and "B: frame of step 8 at 2.000 mm" in text
    assert page.text_content("#compare-stroke-value") == "2.000 mm"
    box = scene_box(page)
    shots(page, "compare3d-deepest")

    slider.focus()
    page.keyboard.press("Home")  # a user's key: the slider's input and change events
    wait_steps(page, 0, 0)
    assert page.text_content("#compare-stroke-value") == "0.000 mm"
    # the two rest states are equal: the map's range is +-1 um, not +-1e-9 mm
    assert page.eval_on_selector("#compare-3d-diff", "d => [d.data[0].cmin, d.data[0].cmax]"
                                 ) == [-0.001, 0.001]

    # let go between two frames: A saved 1 and 1.5 mm, B 1 and 1.25 mm; the thumb goes to the
    # nearest stroke either saved, 1.25 mm (a stroke of 1.2 mm showed frames of others, a
    # review), and each view shows its run's frame nearest that
    slider.evaluate("s => { s.value = '1.2'; s.dispatchEvent(new Event('input')); "
                    "s.dispatchEvent(new Event('change')); }")
    assert page.text_content("#compare-stroke-value") == "1.250 mm"
    assert slider.input_value() == "1.25"
    api = httpx.get(f"{url}/api/compare/frames?runs={a},{b}&stroke_mm=1.25").json()
    assert api["b"]["step"] == 5 and api["a"]["step"] in (2, 3)
    wait_steps(page, api["a"]["step"], 5)
    text = page.text_content("#compare-stroke-shown")
    assert "B: frame of step 5 at 1.250 mm" in text
    assert intensities(page, "#compare-3d-a") == pytest.approx(api["a"]["thickness"])
    assert intensities(page, "#compare-3d-b") == pytest.approx(api["b"]["thickness"])
    assert intensities(page, "#compare-3d-diff") == pytest.approx(api["difference"]["values"])
    # one colour scale for A and B, its legend in mm
    scales = [page.eval_on_selector(s, "d => [d.data[0].cmin, d.data[0].cmax]")
              for s in VIEWS[:2]]
    assert scales[0] == scales[1]
    for s in VIEWS:
        assert "thickness (mm)" in page.eval_on_selector(
            s, "d => d.data[0].colorbar.title.text")
    # drawn in the same box at every stroke, in true proportions: sliding keeps the scale
    assert scene_box(page) == box
    shots(page, "compare3d-between-frames")

    # turn A's view as a drag ends (plotly's relayout of its camera; a mouse drag does not
    # register in headless software WebGL): B's and the map's cameras follow
    turned = {"x": -1.2, "y": -1.4, "z": 1.1}
    page.eval_on_selector("#compare-3d-a",
                          "(d, eye) => Plotly.relayout(d, {'scene.camera.eye': eye})", turned)
    for s in VIEWS[1:]:
        page.wait_for_function(
            "([s, b]) => { const e = document.querySelector(s).layout.scene.camera.eye; "
            "return Math.abs(e.x - b.x) + Math.abs(e.y - b.y) + Math.abs(e.z - b.z) < 1e-9; }",
            arg=[s, turned])
    # and the next stroke keeps the camera where it was left
    slider.focus()
    page.keyboard.press("End")
    wait_steps(page, 4, 8)
    assert camera_eye(page, "#compare-3d-b") == pytest.approx(turned)
    shots(page, "compare3d-turned")
    assert not errors, errors


def test_another_mesh_has_no_difference_map_and_no_frames_no_views(served, browser):
    url, (a, _, c), runs_dir = served
    page, errors = open_compare(browser, url, a, c)
    page.wait_for_function("document.querySelector('#compare-3d-b').dataset.step === '4'")
    page.wait_for_function("document.querySelector('#compare-3d-diff').textContent"
                           ".includes('the meshes differ')")
    page.locator("#compare-stroke").scroll_into_view_if_needed()
    shots(page, "compare3d-other-mesh")
    # a run without saved frames (as a sweep case written without them): the reason, no views
    page.keyboard.press("Escape")
    shutil.rmtree(runs_dir / c / "frames")
    page.click("#compare-open")
    page.wait_for_function("document.querySelector('#compare-stroke-msg').textContent"
                           ".includes('no saved frames')")
    assert page.is_hidden("#compare-stroke-views") and page.is_hidden("#compare-stroke-slider")
    assert c in page.text_content("#compare-stroke-msg")
    shots(page, "compare3d-no-frames")
    assert not errors, errors

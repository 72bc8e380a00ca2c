"""The 3-D viewer in Debian's chromium (Playwright), embedded in the page and on its own, against
the real server in a subprocess, on a coarse cup (punch, die and blank holder; a forming limit
curve):

- a scene is previewed before any run: the blank and the three tools; the page's first look
  previews the scene it has chosen, rather than an empty box;
- the legend is in the window wherever the viewer is shown (its box inside the viewport and
  inside the embedded viewer's frame) and never over the drawing (beside its canvas), and
  stays so when the colour changes to thinning bands or FLD zones, on a 1280 x 720 page too;
- the tools are translucent (the blank shows through the blank holder) and the section plane
  cuts them.

With Q3T_SHOTS set, screenshots of each step go to `$Q3T_SHOTS/viewer/`: look at them."""

from __future__ import annotations

import httpx
import pytest

from tests.support import ROOT
from tests.support.browser import WAIT_MS, page_url, serve, shot, shots_dir
from tests.support.service import until

SHOTS = shots_dir("viewer")
pytestmark = pytest.mark.browser
sync_api = pytest.importorskip("playwright.sync_api", reason="playwright not installed")


def cup_toml() -> str:
    """cup_drawing at a 4 mm edge, 8 mm of its stroke in 4 steps: a few seconds a step."""
    text = (ROOT / "scenes" / "cup_drawing.toml").read_text()
    for old, new in (('name = "cup_drawing"', 'name = "cup"'),
                     ("edge_length = 0.002", "edge_length = 0.004"),
                     ("steps = 50", "steps = 4"),
                     ("velocity = [0.0, 0.0, -0.025]", "velocity = [0.0, 0.0, -0.008]")):
        assert old in text, old
        text = text.replace(old, new)
    return text


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """The server's url and the viewer's own url, serving the coarse cup."""
    tmp = tmp_path_factory.mktemp("viewer-browser")
    with serve(tmp, {"cup": cup_toml()}, "cup") as (url, vport):
        yield url, f"http://127.0.0.1:{vport}/"


def viewer_shot(page, name: str, frame=None) -> None:
    """A screenshot once the viewer has had time to draw (software WebGL: 2-3 frames/s), the
    browser's notice of software WebGL closed (it covers the view's top-left corner)."""
    if SHOTS is None:
        return
    notice = (frame or page).locator(".mantine-Notification-closeButton")
    if notice.count():
        notice.first.click()
    shot(page, SHOTS, name, settle_ms=3000)


def inside(box: dict, outer: dict) -> bool:
    return (box["x"] >= outer["x"] - 0.5 and box["y"] >= outer["y"] - 0.5
            and box["x"] + box["width"] <= outer["x"] + outer["width"] + 0.5
            and box["y"] + box["height"] <= outer["y"] + outer["height"] + 0.5)


def legend_in_view(page, frame, within: str | None = None) -> dict:
    """The legend's box, checked to lie in the window (and in the box of the element
    ``within``, the viewer's frame, measured now: the page's lines above it come and go)."""
    # the viewer may draw its legend again between the wait and the measure (the box is then
    # None for a moment): measure the legend that is shown, a few times if need be
    for _ in range(20):
        legend = frame.locator(".q3t-legend").first
        legend.wait_for()
        box = legend.bounding_box()
        if box is not None:
            break
        page.wait_for_timeout(250)
    window = {"x": 0, "y": 0, **page.viewport_size}
    assert box is not None and box["width"] > 100 and box["height"] > 20, box
    assert inside(box, window), f"legend {box} outside the window {window}"
    if within is not None:
        outer = page.locator(within).bounding_box()
        assert inside(box, outer), f"legend {box} outside the viewer {outer}"
    drawn = frame.locator("canvas").first.bounding_box()
    assert drawn["width"] > 200 and not overlap(box, drawn), f"legend {box} over the part {drawn}"
    return box


def overlap(a: dict, b: dict) -> bool:
    return (a["x"] < b["x"] + b["width"] - 0.5 and b["x"] < a["x"] + a["width"] - 0.5
            and a["y"] < b["y"] + b["height"] - 0.5 and b["y"] < a["y"] + a["height"] - 0.5)


def choose(frame, name: str, option: str) -> None:
    """Pick ``option`` in the viewer's dropdown ``name`` (viser's Mantine select)."""
    frame.get_by_role("combobox", name=name).click()
    frame.get_by_role("option", name=option).click()


def preview(url: str, scene: str, page=None) -> None:
    """Preview ``scene`` in ``page``'s view (its embedded viewer), else the default view."""
    own = {"X-Q3T-View": page.evaluate("VIEW")} if page else {}
    r = httpx.put(f"{url}/api/view/scene", json={"scene": scene}, headers=own)
    assert r.status_code == 200, r.text
    until(lambda: httpx.get(f"{url}/api/view", headers=own).json()["preview"] == "shown",
          f"the preview of {scene} was not shown")


def embedded(browser, url: str, width: int, height: int) -> tuple:
    """The page at ``width`` x ``height``, its viewer's frame once the viewer has drawn its
    panel."""
    page = browser.new_page(viewport={"width": width, "height": height})
    page.set_default_timeout(WAIT_MS)
    page.goto(page_url(url))
    frame = page.frame_locator("#viewer")
    frame.get_by_text("Colour by").first.wait_for()
    return page, frame


def test_embedded_viewer_legend_preview_zones_and_section(served, browser):
    url, _ = served
    page, frame = embedded(browser, url, 1400, 1000)
    # no run yet: the page previews the scene it chose (the server's default), by itself
    frame.get_by_text("Preview of scene").first.wait_for()
    own = {"X-Q3T-View": page.evaluate("VIEW")}
    assert httpx.get(f"{url}/api/view", headers=own).json()["scene"] == "cup"
    preview(url, "cup", page)
    legend_in_view(page, frame, "#viewer")
    assert "Thickness" in frame.locator(".q3t-legend").first.inner_text()
    viewer_shot(page, "01-embedded-preview", frame)

    run = httpx.post(f"{url}/api/runs", json={"scene": "cup"}).json()["id"]
    until(lambda: httpx.get(f"{url}/api/runs/{run}").json()["state"] in
          ("finished", "failed", "stopped"), "the run did not end")
    assert httpx.get(f"{url}/api/runs/{run}").json()["state"] == "finished"
    frame.get_by_text("finished").first.wait_for()
    viewer_shot(page, "02-embedded-run-thickness", frame)

    choose(frame, "Colour by", "Thinning (%)")
    frame.get_by_text("failure ≥ 20 %").first.wait_for()
    legend_in_view(page, frame, "#viewer")
    viewer_shot(page, "03-embedded-thinning", frame)

    choose(frame, "Colour by", "FLD zone")
    frame.get_by_text("wrinkling tendency").first.wait_for()
    legend_in_view(page, frame, "#viewer")
    viewer_shot(page, "04-embedded-fld-zones", frame)

    choose(frame, "Section", "y plane (keep y ≥ at)")
    viewer_shot(page, "05-embedded-section", frame)
    # a scene previewed while a run is selected: the headline (the run's) says the 3-D view
    # is not the run's part, until the run is clicked again
    preview(url, "cup", page)
    page.wait_for_selector("#previewing:not([hidden])")
    assert "preview of scene cup, not this run" in page.text_content("#previewing")
    page.click(f'#runs tbody tr[data-id="{run}"] td.col-scene')
    page.wait_for_selector("#previewing[hidden]", state="attached")
    page.close()


def test_viewer_alone_legend_in_view(served, browser):
    url, viewer_url = served
    page = browser.new_page(viewport={"width": 1100, "height": 700})
    page.set_default_timeout(WAIT_MS)
    page.goto(viewer_url)
    page.get_by_text("Colour by").first.wait_for()
    legend_in_view(page, page)
    viewer_shot(page, "06-viewer-alone")
    preview(url, "cup")  # a viewer opened on its own shows the default view
    page.get_by_text("Preview of scene").first.wait_for()
    legend_in_view(page, page)
    viewer_shot(page, "07-viewer-alone-preview")
    page.close()


def test_a_small_window_keeps_the_part_clear(served, browser):
    """At 1280 x 720 the page's 3-D view is 420 px tall: the legend (FLD zones, the tallest)
    sits beside the drawing, which keeps most of the view's width."""
    url, _ = served
    page, frame = embedded(browser, url, 1280, 720)
    preview(url, "cup", page)
    choose(frame, "Colour by", "FLD zone")
    frame.get_by_text("wrinkling tendency").first.wait_for()
    legend_in_view(page, frame, "#viewer")
    drawn = frame.locator("canvas").first.bounding_box()
    view = page.locator("#viewer").bounding_box()
    assert drawn["width"] >= 0.55 * view["width"] and drawn["height"] >= view["height"] - 4, \
        (drawn, view)
    viewer_shot(page, "08-small-window", frame)
    # shorter still (or more runs in the table): the page scrolls to the Runs table rather
    # than the view running over it (a review saw it cover the table's header at 1280 x 720)
    page.set_viewport_size({"width": 1280, "height": 560})
    page.wait_for_timeout(500)
    view, table = (page.locator(s).bounding_box() for s in ("#viewer-box", "#runs-box"))
    assert view["height"] >= 420 and view["y"] + view["height"] <= table["y"] + 0.5, \
        (view, table)
    page.close()

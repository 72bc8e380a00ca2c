"""The run's download links on the page (web/results.js) in Debian's chromium, against the real
server in a subprocess: a running run says its downloads come when it ends; an ended one offers
each format, and a click downloads the file the API serves; with the viewer on, the PNG of the
3-D view is rendered by the page's viewer. With Q3T_SHOTS set, screenshots go to its folder
exports."""

from __future__ import annotations

import csv
import io

import httpx
import imageio.v3 as iio
import numpy as np
import pytest

from server.colormap import VIRIDIS
from server.routers.exports import PNG_HEIGHT
from sim.frames import export
from tests.support.browser import WAIT_MS, page_url, serve, shot, shots_dir
from tests.support.scenes import tiny_cup_toml
from tests.support.service import until

SHOTS = shots_dir("exports")
pytestmark = pytest.mark.browser
sync_api = pytest.importorskip("playwright.sync_api", reason="playwright not installed")
ENDED = {"finished", "failed", "stopped"}


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("exports-browser")
    with serve(tmp, {"tiny_cup": tiny_cup_toml()}, "tiny_cup", "--no-viewer") as (url, _):
        yield url


def start(url: str, **body) -> str:
    r = httpx.post(f"{url}/api/runs", json={"scene": "tiny_cup", **body})
    assert r.status_code == 201, r.text
    return r.json()["id"]


def ended(url: str, run: str) -> dict:
    return until(lambda: (st := httpx.get(f"{url}/api/runs/{run}").json())["state"] in ENDED
                 and st, f"run {run} never ended")


def downloads(page, run: str, ready: str) -> None:
    page.wait_for_function(f"(d => d.run === {run!r} && d.ready === {ready!r})"
                           "(document.getElementById('downloads').dataset)")


def test_an_ended_run_offers_each_format_and_a_click_downloads_it(served, browser, tmp_path):
    url = served
    run = start(url)
    assert ended(url, run)["state"] == "finished"
    page = browser.new_page(viewport={"width": 1400, "height": 1000}, accept_downloads=True)
    page.set_default_timeout(WAIT_MS)
    errors = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(page_url(url))
    downloads(page, run, "true")
    links = page.locator("#downloads a")
    assert [links.nth(i).get_attribute("data-format") for i in range(links.count())] == \
        list(export.FORMATS)
    # no viewer here: the PNG is offered greyed out, saying why
    png = page.locator("#downloads .unavailable[data-format=png]")
    assert png.get_attribute("title").startswith("the viewer is off")
    assert page.locator("#downloads").inner_text().startswith("Download:")
    shot(page, SHOTS, "downloads-ended.png", settle_ms=1500)  # the plots drawn
    with page.expect_download() as d:
        page.click("#downloads a[data-format=csv]")
    path = tmp_path / d.value.suggested_filename
    d.value.save_as(path)
    assert path.name == f"{run}.csv"
    assert path.read_text() == httpx.get(f"{url}/api/runs/{run}/export/csv").text
    rows = list(csv.reader(path.open()))
    assert "punch force [kN]" in rows[0] and len(rows) == 1 + 4
    with page.expect_download() as d:
        page.click("#downloads a[data-format=vtu]")
    assert d.value.suggested_filename == f"{run}_vtu.zip"
    assert not errors


def test_a_running_run_says_its_downloads_come_when_it_ends(served, browser):
    url = served
    run = start(url, paused=True)
    page = browser.new_page(viewport={"width": 1400, "height": 1000})
    page.set_default_timeout(WAIT_MS)
    try:
        page.goto(page_url(url))
        downloads(page, run, "false")
        assert "when the run ends" in page.inner_text("#downloads")
        assert page.locator("#downloads a").count() == 0
        shot(page, SHOTS, "downloads-running.png")
    finally:
        httpx.post(f"{url}/api/runs/{run}/stop")
    ended(url, run)
    downloads(page, run, "true")  # the page follows the run's end
    # stopped paused before its first step: its rest state to download, no table of steps
    assert page.locator("#downloads a").count() == len(export.FORMATS) - 1
    assert page.locator("#downloads a", has_text="CSV").count() == 0


@pytest.fixture(scope="module")
def viewed(tmp_path_factory):
    """A server with its viewer on, and a finished run of the tiny cup."""
    tmp = tmp_path_factory.mktemp("exports-viewer")
    with serve(tmp, {"tiny_cup": tiny_cup_toml()}, "tiny_cup") as (url, _):
        run = start(url)
        assert ended(url, run)["state"] == "finished"
        yield url, run


def test_png_needs_a_browser_showing_the_run(viewed):
    url, run = viewed
    r = httpx.get(f"{url}/api/runs/{run}/export/png")
    assert r.status_code == 409 and "no browser has the 3-D view open" in r.json()["detail"]


def test_png_of_the_3d_view_is_rendered_by_the_pages_viewer(viewed, browser, tmp_path):
    url, run = viewed
    page = browser.new_page(viewport={"width": 1400, "height": 1000}, accept_downloads=True)
    page.set_default_timeout(WAIT_MS)
    page.goto(url + "/?viewer_dpr=0.5")  # a canvas of half the pixels: the PNG is not
    downloads(page, run, "true")
    viewer = page.frame_locator("#viewer")
    # connected is not showing: the view loads the run's recording after it connects, and a
    # PNG asked before that is refused (no browser shows the run)
    viewer.locator("code", has_text=run).first.wait_for()
    viewer.get_by_text("range of this run").first.wait_for()  # its frame is in the canvas
    page.wait_for_timeout(3000)  # and drawn (software WebGL: 2-3 frames/s), for the PNG below
    shot(page, SHOTS, "downloads-viewer.png")
    with page.expect_download() as d:
        page.click("#downloads a[data-format=png]")
    assert d.value.suggested_filename == f"{run}.png"
    path = (SHOTS or tmp_path) / "downloaded-view.png"  # kept with the shots, to be looked at
    d.value.save_as(path)
    image = iio.imread(path)
    assert image.ndim == 3 and image.shape[0] >= PNG_HEIGHT and image.shape[1] >= PNG_HEIGHT
    # the sheet is drawn: a part of the image above the legend (its bottom-left corner) is
    # neither the background nor transparent
    rgb = image[: image.shape[0] * 3 // 5, :, :3].reshape(-1, 3)
    background = np.all(rgb == rgb[0], axis=1)
    assert (~background).mean() > 0.01
    # the thickness scale drawn in, at the bottom left: its bar's end colours, its caption
    corner = image[-image.shape[0] // 5:, : image.shape[1] // 2, :3].reshape(-1, 3)
    for end in (VIRIDIS[0], VIRIDIS[-1]):
        assert np.all(corner == end, axis=1).any(), end
    # the API answers the same way while the page is open
    r = httpx.get(f"{url}/api/runs/{run}/export/png", timeout=120)
    assert r.status_code == 200 and r.headers["content-type"] == "image/png"
    assert iio.imread(io.BytesIO(r.content)).shape == image.shape
    assert page.inner_text("#downloads .note") == ""

"""The split ring on the page (web/rings.js) in Debian's chromium, against the real server in a
subprocess: a cup run started from the page and finished shows a "Split ring" section with
heights its wall holds; heights above the part are refused next to the heights, a cut angle
that is no number next to the angle; a ring cut shows busy, then its column in the table, the
numbers the API lists. A plate run has no such section. With Q3T_SHOTS set, screenshots go to
its folder split-ring."""

from __future__ import annotations

import httpx
import pytest

from tests.support.browser import VIEWER_FOR_SHOTS, click_row, open_scene, serve, shot, shots_dir
from tests.support.scenes import RING_BAND, ring_cup_toml, tiny_cup_toml
from tests.support.service import until

SHOTS = shots_dir("split-ring")
pytestmark = pytest.mark.browser
sync_api = pytest.importorskip("playwright.sync_api", reason="playwright not installed")


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("split-ring-browser")
    with serve(tmp, {"ring_cup": ring_cup_toml(), "tiny_cup": tiny_cup_toml()}, "ring_cup",
               *VIEWER_FOR_SHOTS) as (url, _):
        yield url


def finished(page, url: str) -> str:
    """Start the scene on screen from the page; its run's id once it has finished."""
    page.click("#start")
    page.wait_for_function("document.getElementById('status').dataset.state === 'finished'")
    run = page.get_attribute("#status", "data-run")
    assert httpx.get(f"{url}/api/runs/{run}").json()["state"] == "finished"
    return run


def test_a_ring_is_cut_from_the_page_and_tabled(served, open_page):
    url = served
    page = open_scene(open_page, url, "ring_cup", "[name='mesh.kind']")
    run = finished(page, url)
    page.wait_for_selector(f"#split-ring[data-run='{run}'][data-ready='true']")
    assert page.is_visible("#split-ring")
    # the wall ends below the command line's 8-13 mm: the wall's extent is offered
    assert page.input_value("#ring-z1") == str(RING_BAND[0])
    assert page.input_value("#ring-z2") == str(RING_BAND[1])
    assert page.input_value("#ring-angle") == "0"
    wall = page.inner_text("#ring-wall")
    assert wall.startswith("The steep wall (over 60° from the horizontal) runs 1.62 to 6.16 mm")
    assert page.inner_text("#ring-list") == "No ring cut from this run yet."
    shot(page, SHOTS, "ready.png", settle_ms=1500)
    # heights above the part: the server's reason, next to the heights
    page.fill("#ring-z1", "8")
    page.fill("#ring-z2", "13")
    page.click("#ring-cut")
    page.wait_for_function("document.getElementById('ring-heights-error').textContent !== ''")
    assert page.inner_text("#ring-heights-error").startswith(
        "heights: 13 mm is above the part (its top is 8.83 mm above the bottom)")
    assert "has-error" in page.get_attribute("#ring-z2", "class")
    assert page.inner_text("#ring-angle-error") == "" and page.inner_text("#ring-error") == ""
    shot(page, SHOTS, "heights-refused.png", where="#split-ring")
    # an angle that is no number: said next to the angle, nothing sent
    page.fill("#ring-z1", "1,6")  # a decimal comma reads as a point
    page.fill("#ring-z2", str(RING_BAND[1]))
    page.fill("#ring-angle", "north")
    page.click("#ring-cut")
    assert page.inner_text("#ring-angle-error") == "cut_angle: a number of degrees"
    assert page.inner_text("#ring-heights-error") == ""
    # the ring: busy while it is cut (the button disabled at the click, before any answer)
    page.fill("#ring-angle", "0")
    page.evaluate("""() => { const b = document.getElementById('ring-cut');
        window.sawBusy = [];
        new MutationObserver(() => window.sawBusy.push([b.disabled, b.textContent]))
          .observe(b, { attributes: true, childList: true }); }""")
    page.click("#ring-cut")
    shot(page, SHOTS, "cutting.png", where="#split-ring")
    page.wait_for_selector("#split-ring[data-count='1']")
    assert [True, "Cutting…"] in page.evaluate("window.sawBusy")
    assert not page.is_disabled("#ring-cut") and page.inner_text("#ring-cut") == "Cut ring"
    assert page.inner_text("#ring-heights-error") == ""
    (ring,) = httpx.get(f"{url}/api/runs/{run}/split_ring").json()["rings"]
    assert ring["heights_mm"] == RING_BAND
    head = page.locator("#ring-table thead th").all_inner_texts()
    assert head == ["Ring (mm above the bottom)", "1.6–6.2"]
    rows = {r.locator("th").inner_text(): r.locator("td").inner_text()
            for r in page.locator("#ring-table tbody tr").all()}
    num = lambda v, digits=3: page.evaluate("([v, d]) => Units.num(v, d)", [v, digits])  # noqa: E731
    o, d = ring["opening_mm"], ring["diameters_mm"]
    want = {"Cut angle (deg)": "0", "Elements": str(ring["elements"]),
            "Opening at mid-height (mm)": num(o["at_mid_height"]),
            "Opening along the cut, min (mm)": num(o["min"]),
            "Opening along the cut, max (mm)": num(o["max"]),
            **{f"D {s}, {name} (mm)": num(d[s][k]) for s in ("formed", "released", "split")
               for k, name in (("mean", "mean"), ("d0", "0°"), ("d90", "90°"))},
            "Re-yield on release, closed (%)": num(ring["reyield_pct"]["closed"], 2),
            "Re-yield on release, split (%)": num(ring["reyield_pct"]["split"], 2)}
    assert rows == want
    assert float(rows["Opening at mid-height (mm)"]) > 0  # this ring opens
    shot(page, SHOTS, "ring-tabled.png", settle_ms=1000)
    shot(page, SHOTS, "ring-tabled-section.png", where="#split-ring")
    # a second ring, at 90 degrees: a column of its own
    page.fill("#ring-angle", "90")
    page.click("#ring-cut")
    page.wait_for_selector("#split-ring[data-count='2']")
    assert page.locator("#ring-table tbody tr").nth(0).locator("td").all_inner_texts() == \
        ["0", "90"]
    shot(page, SHOTS, "two-rings.png", where="#split-ring")


def test_a_run_without_a_wall_has_no_split_ring_section(served, open_page):
    url = served
    run = httpx.post(f"{url}/api/runs", json={"scene": "tiny_cup"}).json()["id"]
    until(lambda: httpx.get(f"{url}/api/runs/{run}").json()["state"] == "finished",
          f"run {run} never finished")
    page = open_page(url, "#runs tbody tr")
    click_row(page, run)
    page.wait_for_function(f"document.getElementById('status').dataset.run === {run!r}")
    page.wait_for_selector(f"#summary[data-run='{run}'][data-ready='true']")
    page.wait_for_function(f"document.getElementById('split-ring').dataset.run === {run!r}")
    assert not page.is_visible("#split-ring")

"""The split ring on the page (web/rings.js) in Debian's chromium, against the real server in a
subprocess: a cup run started from the page and finished shows a "Split ring" section with
heights its wall holds; heights the wrong way round are said as typed, heights past the wall
and an angle past a turn get a note; heights above the part are refused next to the heights, a
cut angle that is no number next to the angle; a ring cut shows busy, then its column in the
table, the numbers the API lists, and links to its files that download them as saved; while a
ring is cut, the stage the server lists and the time so far, Newton's progress in a release. A
plate run has no such section. With Q3T_SHOTS set, screenshots go to its folder split-ring."""

from __future__ import annotations

import io
import zipfile

import httpx
import numpy as np
import pytest

from sim.stepping.split_ring import STAGES
from tests.support.browser import VIEWER_FOR_SHOTS, click_row, open_scene, serve, shot, shots_dir
from tests.support.scenes import RING_BAND, ring_cup_toml, tiny_cup_toml
from tests.support.service import (
    HANG,
    finished_run,
    hold_ring_at,
    in_thread,
    until,
    until_exists,
)

SHOTS = shots_dir("split-ring")
pytestmark = pytest.mark.browser
sync_api = pytest.importorskip("playwright.sync_api", reason="playwright not installed")


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("split-ring-browser")
    # the ring cup with seven points through the thickness, which springback needs
    seven = (ring_cup_toml().replace('name = "ring_cup"', 'name = "ring_cup_7"')
             .replace('element = "q3t"', 'element = "q3t"\nthickness_points = 7'))
    assert "thickness_points = 7" in seven
    with serve(tmp, {"ring_cup": ring_cup_toml(), "ring_cup_7": seven,
                     "tiny_cup": tiny_cup_toml()}, "ring_cup", *VIEWER_FOR_SHOTS) as (url, _):
        yield url, tmp / "runs"


def finished(page, url: str) -> str:
    """Start the scene on screen from the page; its run's id once it has finished."""
    page.click("#start")
    page.wait_for_function("document.getElementById('status').dataset.state === 'finished'")
    run = page.get_attribute("#status", "data-run")
    assert httpx.get(f"{url}/api/runs/{run}").json()["state"] == "finished"
    return run


def test_a_ring_is_cut_from_the_page_and_tabled(served, open_page, tmp_path):
    url, runs = served
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
    assert page.inner_text("#split-ring .field-note") == ""  # the defaults: on the wall
    # as typed: heights the wrong way round are said at once, by the server's rule
    page.fill("#ring-z2", "1")
    assert page.inner_text("#ring-heights-error") == (
        "heights: 1.6, 1 mm: need 0 <= z1 < z2 (mm above the cup's bottom)")
    # ... an angle past a turn gets the meridian it is
    page.fill("#ring-angle", "400")
    assert page.inner_text("#ring-angle-note") == "400° is the meridian at 40° (taken modulo 360°)"
    page.fill("#ring-angle", "0")
    assert page.inner_text("#ring-angle-note") == ""
    # heights above the part: a note as typed, then the server's reason, next to the heights
    page.fill("#ring-z1", "8")
    page.fill("#ring-z2", "13")
    assert page.inner_text("#ring-heights-error") == ""
    assert page.inner_text("#ring-heights-note") == (
        "8–13 mm reaches past the steep wall (1.62–6.16 mm): the cut is refused if a flatter "
        "element lies in the band")
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
    # lengths to the µm, as the command line's table: the formed, released and split
    # diameters differ by less than 3 significant digits show
    want = {"Cut angle (deg)": "0", "Section points through the thickness": "3",
            "Elements": str(ring["elements"]),
            "Opening at mid-height (mm)": f"{o['at_mid_height']:.3f}",
            "Opening along the cut, min (mm)": f"{o['min']:.3f}",
            "Opening along the cut, max (mm)": f"{o['max']:.3f}",
            **{f"D {s}, {name} (mm)": f"{d[s][k]:.3f}" for s in ("formed", "released", "split")
               for k, name in (("mean", "mean"), ("d0", "0° from the cut"),
                               ("d90", "90° from the cut"))},
            "Re-yield on release, closed (% of points)": num(ring["reyield_pct"]["closed"], 2),
            "Re-yield on release, split (% of points)": num(ring["reyield_pct"]["split"], 2)}
    assert rows == want
    assert float(rows["Opening at mid-height (mm)"]) > 0  # this ring opens
    # the cup has Q3T's own three points through the thickness: the opening is flagged
    assert page.locator("#ring-list p.caution").all_inner_texts() == [ring["caution"]]
    assert ring["caution"].startswith("3 section points through the thickness are too few")
    shot(page, SHOTS, "ring-tabled.png", settle_ms=1000)
    shot(page, SHOTS, "ring-tabled-section.png", where="#split-ring")
    downloads_as_saved(page, ring, runs / run, tmp_path)
    # a second ring, at 90 degrees: a column of its own
    page.fill("#ring-angle", "90")
    page.click("#ring-cut")
    page.wait_for_selector("#split-ring[data-count='2']")
    assert page.locator("#ring-table tbody tr").nth(0).locator("td").all_inner_texts() == \
        ["0", "90"]
    # each column's links are its own ring's
    listed = httpx.get(f"{url}/api/runs/{run}/split_ring").json()["rings"]
    hrefs = page.locator("#ring-table tfoot a").evaluate_all(
        "links => links.map((a) => a.getAttribute('href'))")
    assert hrefs == [f["url"] for fmt in ("vtu", "npz") for r in listed
                     for f in r["downloads"] if f["format"] == fmt]
    assert hrefs[1].endswith("-90deg/vtu")
    assert page.locator("#ring-list p.caution").count() == 1  # said once for both rings
    shot(page, SHOTS, "two-rings.png", where="#split-ring")


def downloads_as_saved(page, ring: dict, folder, tmp_path) -> None:
    """The ring's column ends in its files' links, a row each, which save them as they are
    in the run's ``folder``: its npz, its VTU files zipped with their PVD."""
    rows = page.locator("#ring-table tfoot tr")
    assert rows.locator("th").all_inner_texts() == ["Download VTU (ParaView)",
                                                    "Download npz (NumPy)"]
    assert rows.locator("td").all_inner_texts() == ["VTU", "npz"]
    stem = f"{folder.name}_{ring['name']}"
    with page.expect_download() as d:
        page.click("#ring-table tfoot a[data-format=npz]")
    path = tmp_path / d.value.suggested_filename
    d.value.save_as(path)
    assert path.name == f"{stem}.npz"
    assert path.read_bytes() == (folder / f"{ring['name']}.npz").read_bytes()
    with np.load(path) as z:
        assert len(z["elements"]) == ring["elements"] and z["split"].shape == z["rest"].shape
    with page.expect_download() as d:
        page.click("#ring-table tfoot a[data-format=vtu]")
    assert d.value.suggested_filename == f"{stem}_vtu.zip"
    with zipfile.ZipFile(io.BytesIO(d.value.path().read_bytes())) as z:
        assert z.read(f"{stem}/ring_split.vtu") == \
            (folder / ring["name"] / "ring_split.vtu").read_bytes()
        assert f"{stem}.pvd" in z.namelist()


def test_a_cut_belongs_to_its_run_and_rings_cut_elsewhere_show(served, open_page):
    """Two finished cups A and B. A ring cut from A by another client shows on the page
    showing A without selecting it again. The page's cut on A (its request held in the
    browser until the test lets it go) shows A busy, not B when B is selected; its answer,
    come while B is shown, shows when A is shown again: the error next to the heights typed,
    or the ring in A's table."""
    url, _ = served
    with httpx.Client(base_url=url, timeout=HANG) as client:
        a, b = finished_run(client, "ring_cup"), finished_run(client, "ring_cup")
    page = open_page(url, "#runs tbody tr")
    click_row(page, a)
    page.wait_for_selector(f"#split-ring[data-run='{a}'][data-count='0'][data-ready='true']")
    r = httpx.post(f"{url}/api/runs/{a}/split_ring", json={"heights": RING_BAND},
                   timeout=HANG)
    assert r.status_code == 200, r.text
    page.wait_for_selector(f"#split-ring[data-run='{a}'][data-count='1']")
    held = []
    page.route("**/api/runs/*/split_ring",
               lambda route: held.append(route) if route.request.method == "POST"
               else route.continue_())

    def cut_then_show_b(z1: str, z2: str, angle: str) -> None:
        page.fill("#ring-z1", z1)
        page.fill("#ring-z2", z2)
        page.fill("#ring-angle", angle)
        page.click("#ring-cut")
        page.wait_for_function("document.getElementById('ring-cut').disabled")
        # Playwright calls the route's handler inside its own calls: evaluate lets it run
        until(lambda: page.evaluate("true") and held, "the cut's request never left")
        click_row(page, b)
        page.wait_for_selector(f"#split-ring[data-run='{b}'][data-ready='true']")
        assert not page.is_disabled("#ring-cut") and page.inner_text("#ring-cut") == "Cut ring"
        assert not page.is_visible("#ring-busy")
        assert page.get_attribute("#split-ring", "aria-busy") == "false"
        assert page.input_value("#ring-z1") == str(RING_BAND[0])  # B's own defaults

    # heights above the part: refused while B is shown
    cut_then_show_b("8", "13", "0")
    shot(page, SHOTS, "other-run-while-cutting.png", where="#split-ring")
    with page.expect_response(lambda r: r.request.method == "POST"):
        held.pop().continue_()
    click_row(page, a)
    page.wait_for_function("document.getElementById('ring-heights-error').textContent !== ''")
    assert page.inner_text("#ring-heights-error").startswith("heights: 13 mm is above the part")
    assert [page.input_value(f"#ring-{f}") for f in ("z1", "z2", "angle")] == ["8", "13", "0"]
    assert not page.is_disabled("#ring-cut")
    shot(page, SHOTS, "late-error-back-on-a.png", where="#split-ring")
    # a ring at 90 deg: done while B is shown, in A's table when A is shown again
    cut_then_show_b(*map(str, RING_BAND), "90")
    with page.expect_response(lambda r: r.request.method == "POST") as answer:
        held.pop().continue_()
    assert answer.value.status == 200
    click_row(page, a)
    page.wait_for_selector(f"#split-ring[data-run='{a}'][data-count='2']")
    assert page.locator("#ring-table tbody tr").nth(0).locator("td").all_inner_texts() == \
        ["0", "90"]
    assert not page.is_disabled("#ring-cut") and page.inner_text("#ring-heights-error") == ""
    shot(page, SHOTS, "late-ring-back-on-a.png", where="#split-ring")


def test_a_ring_from_a_cup_with_seven_section_points_carries_no_caution(served, open_page):
    """The cup formed with seven points through the thickness: its ring's column says 7 and
    no caution shows under the table."""
    url, _ = served
    with httpx.Client(base_url=url, timeout=HANG) as client:
        run = finished_run(client, "ring_cup_7")
        r = client.post(f"/api/runs/{run}/split_ring", json={"heights": RING_BAND})
    assert r.status_code == 200, r.text
    assert r.json()["section_points"] == 7 and r.json()["caution"] is None
    page = open_page(url, "#runs tbody tr")
    click_row(page, run)
    page.wait_for_selector(f"#split-ring[data-run='{run}'][data-count='1'][data-ready='true']")
    rows = {r.locator("th").inner_text(): r.locator("td").inner_text()
            for r in page.locator("#ring-table tbody tr").all()}
    assert rows["Section points through the thickness"] == "7"
    assert page.locator("#ring-list p.caution").count() == 0


@pytest.fixture(scope="module")
def here(tmp_path_factory):
    """The service in this process, on uvicorn in a thread: a test holds its process that
    cuts rings (app.state.rings) at a stage for as long as it needs. Its url and app."""
    tmp = tmp_path_factory.mktemp("split-ring-here")
    with in_thread(tmp, {"ring_cup": ring_cup_toml()}) as out:
        yield out


def busy_lines(page) -> list[str]:
    """The lines beside the busy button, their no-break spaces (a time kept on one line)
    as spaces."""
    return [t.replace("\xa0", " ") for t in page.locator("#ring-busy > span").all_inner_texts()]


def test_a_ring_being_cut_shows_its_stage_and_time(here, open_page, tmp_path):
    """Beside the busy button, while a ring is cut: the ring, then what it waits for while
    the process that cuts rings is busy (held here), the time so far moving on; then, the
    child held as the closed ring's release makes its first Newton iteration, that stage and
    Newton's iteration and out-of-balance force against its target, in N, as the server lists
    them. Let go: the ring is tabled and the busy line is gone."""
    url, app = here
    with httpx.Client(base_url=url, timeout=HANG) as client:
        run = finished_run(client, "ring_cup")
    page = open_page(url, "#runs tbody tr")
    click_row(page, run)
    page.wait_for_selector(f"#split-ring[data-run='{run}'][data-count='0'][data-ready='true']")
    pool = app.state.rings.executor()
    release, busy = tmp_path / "release", tmp_path / "busy"
    pool.submit(hold_ring_at, STAGES["closed"], str(release), 1).result()
    held = pool.submit(until_exists, str(busy))
    try:
        page.click("#ring-cut")
        page.wait_for_function("document.getElementById('ring-busy').dataset.stage === "
                               "'waiting for the process that cuts rings'")
        lines = busy_lines(page)
        assert lines[0] == f"Cutting the ring {RING_BAND[0]}–{RING_BAND[1]} mm at 0°:"
        assert lines[1].startswith("Waiting for the process that cuts rings · ")
        assert lines[1].endswith(" elapsed") and len(lines) == 2
        page.wait_for_function("(t) => document.querySelector('#ring-busy .stage')"
                               ".textContent !== t",  # the time moves on
                               arg=page.text_content("#ring-busy .stage"))
        shot(page, SHOTS, "cutting-waiting.png", where="#split-ring")
        busy.touch()
        # held at the first iteration: the page shows the iterate before it, then this one
        page.wait_for_function("(document.querySelector('#ring-busy .newton') || {})"
                               ".textContent?.startsWith('Newton iteration 1:')")
        listed = httpx.get(f"{url}/api/runs/{run}/split_ring").json()["cutting"]
        newton = listed["newton"]
        assert listed["stage"] == STAGES["closed"] and newton["iteration"] == 1
        lines = busy_lines(page)
        assert lines[1].startswith("Releasing the closed ring · ")
        force = lambda v: page.evaluate("(v) => Units.withUnit(v, 'N', 2)", v)  # noqa: E731
        assert lines[2] == (f"Newton iteration 1: out-of-balance force "
                            f"{force(newton['residual_N'])}, converged once below "
                            f"{force(newton['target_N'])}")
        assert page.inner_text("#ring-cut") == "Cutting…" and page.is_disabled("#ring-cut")
        shot(page, SHOTS, "cutting-progress.png", where="#split-ring")
        shot(page, SHOTS, "cutting-progress-page.png", settle_ms=500)
    finally:
        busy.touch()
        release.touch()
        held.result()
    page.wait_for_selector("#split-ring[data-count='1']")
    assert not page.is_visible("#ring-busy") and page.inner_text("#ring-cut") == "Cut ring"
    assert page.get_attribute("#ring-busy", "data-stage") == ""


def test_a_run_without_a_wall_has_no_split_ring_section(served, open_page):
    url, _ = served
    run = httpx.post(f"{url}/api/runs", json={"scene": "tiny_cup"}).json()["id"]
    until(lambda: httpx.get(f"{url}/api/runs/{run}").json()["state"] == "finished",
          f"run {run} never finished")
    page = open_page(url, "#runs tbody tr")
    click_row(page, run)
    page.wait_for_function(f"document.getElementById('status').dataset.run === {run!r}")
    page.wait_for_selector(f"#summary[data-run='{run}'][data-ready='true']")
    page.wait_for_function(f"document.getElementById('split-ring').dataset.run === {run!r}")
    assert not page.is_visible("#split-ring")

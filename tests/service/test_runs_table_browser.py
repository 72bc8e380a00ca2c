"""The page's Runs table in Debian's chromium: runs waiting in the queue show their place and
can be cancelled; ended runs show what they changed of the scene, their solver time (the wall
time in its title) and the headline values of their result in labelled units; a click on a
header sorts by it (again: the other way round); Delete asks first and does nothing when the
user says no.

With Q3T_SHOTS set, screenshots go to `$Q3T_SHOTS/runs-table/`."""

from __future__ import annotations

import httpx
import pytest

from tests.support.browser import js_duration, new_page, serve, shot, shots_dir
from tests.support.scenes import tiny_cup_toml, tiny_toml
from tests.support.service import ENDED, until

SHOTS = shots_dir("runs-table")
pytestmark = pytest.mark.browser
sync_api = pytest.importorskip("playwright.sync_api", reason="playwright not installed")
# the cup three ways: as saved, a softer material, friction halved from the start
CUPS = [{}, {"overrides": {"material.yield_stress": 60.0e6}},
        {"parameters": {"friction_scale": 0.5}}]


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("runs-table")
    scenes = {"tiny_cup": tiny_cup_toml(),
              "long": tiny_toml(steps=4000).replace('name = "tiny"', 'name = "long"')}
    with serve(tmp, scenes, "tiny_cup", "--no-viewer", "--queue", "4") as (url, _):
        yield url


def open_page(browser, url: str):
    page, errors = new_page(browser, url, "#scenes li.sel", width=1500, height=950)
    return page, errors


def start(url: str, scene: str, **body: object) -> dict:
    r = httpx.post(f"{url}/api/runs", json={"scene": scene, **body})
    assert r.status_code == 201, r.text
    return r.json()


def shown_ids(page) -> list[str]:
    return page.eval_on_selector_all("#runs tbody tr", "rows => rows.map(r => r.dataset.id)")


def cell(page, run: str, col: str) -> str:
    return page.text_content(f'#runs tbody tr[data-id="{run}"] td.col-{col}').strip()


def wait_cell(page, run: str, col: str, text: str) -> None:
    page.wait_for_function(
        f"(document.querySelector('#runs tbody tr[data-id=\"{run}\"] td.col-{col}')"
        f"?.textContent || '').includes({text!r})")


def test_the_queue_in_the_table(served, browser):
    """A paused run holds the one solver; three cups wait behind it, numbered; the third is
    cancelled from its row; then all run in order and show their results."""
    url = served
    holder = start(url, "long", paused=True)["id"]
    cups = [start(url, "tiny_cup", **body)["id"] for body in CUPS]
    page, errors = open_page(browser, url)
    for place, run in enumerate(cups, 1):
        wait_cell(page, run, "state", f"queued #{place}")
    # in the unit the scene form shows it in, labelled (the scene holds 6e7 Pa)
    assert cell(page, cups[1], "changes") == "material.yield_stress = 60 MPa"
    assert cell(page, cups[0], "changes") == "as saved"
    assert cell(page, cups[2], "changes") == "Friction × 0.5 from step 1"
    # the id without its scene and element, which have columns of their own
    assert cups[0].endswith(cell(page, cups[0], "run"))
    assert cell(page, cups[0], "scene") == "tiny_cup" and cell(page, cups[0], "element") == "q3t"
    assert cell(page, cups[0], "wall") == "–"  # not started: no wall time yet
    # a queued run has its scene and nothing else to link to (no recording, no result)
    links = page.locator(f'#runs tbody tr[data-id="{cups[0]}"] a').all_text_contents()
    assert links == ["scene"], links
    shot(page, SHOTS, "01-queued.png")
    page.click(f'#runs tbody tr[data-id="{cups[2]}"] button.cancel')
    wait_cell(page, cups[2], "state", "cancelled")
    assert "cancelled before it started" in cell(page, cups[2], "state")
    httpx.post(f"{url}/api/runs/{holder}/stop")
    for run in cups[:2]:
        until(lambda r=run: httpx.get(f"{url}/api/runs/{r}").json()["state"] in ENDED,
              f"{run} never ended")
    for run in cups[:2]:
        wait_cell(page, run, "state", "finished")
        page.wait_for_function(  # a number, from its result
            f"(document.querySelector('#runs tbody tr[data-id=\"{run}\"] "
            f"td.col-peak_punch_force')?.textContent || '–') !== '–'")
    for run in cups[:2]:  # the solver's time in the cell, the wall time in its title
        st = httpx.get(f"{url}/api/runs/{run}").json()
        assert cell(page, run, "wall") == js_duration(st["stepping_s"])
        title = page.get_attribute(f'#runs tbody tr[data-id="{run}"] td.col-wall span', "title")
        assert title == (f"wall time {js_duration(st['progress']['elapsed_s'])} from its start "
                         "on a solver process (build, pauses and pacing included)"), title
    headers = page.eval_on_selector_all("#runs thead th", "ths => ths.map(t => t.textContent)")
    assert headers[7:10] == ["peak force (kN)", "min. thickness (mm)", "max. thinning (%)"]
    for run in cups[:2]:  # the values of the run's summary, in the headers' units
        summary = {e["name"]: e["display"] for e in
                   httpx.get(f"{url}/api/runs/{run}/summary").json()["summary"]}
        for col in ("peak_punch_force", "min_thickness", "max_thinning"):
            assert summary[col]["unit"] == {"peak_punch_force": "kN", "min_thickness": "mm",
                                            "max_thinning": "%"}[col]
            # shown to 3 significant digits (Units.num)
            assert float(cell(page, run, col)) == pytest.approx(summary[col]["value"],
                                                                rel=5e-3)
    shot(page, SHOTS, "02-ended.png")
    assert not [e for e in errors if "/static/" in e], errors
    page.close()


def test_sorting_by_a_header(served, browser):
    url = served
    page, errors = open_page(browser, url)
    runs = httpx.get(f"{url}/api/runs").json()
    page.wait_for_function(f"document.querySelectorAll('#runs tbody tr').length === {len(runs)}")
    assert shown_ids(page) == [r["id"] for r in runs]  # newest first, as the server lists
    force = {r["id"]: r["results"]["peak_punch_force"]["value"] for r in runs
             if "peak_punch_force" in r["results"]}
    assert len(force) == 2 and len(set(force.values())) == 2, force
    without = [r["id"] for r in runs if r["id"] not in force]

    page.click("#runs thead th[data-key=peak_punch_force]")
    assert page.get_attribute("#runs thead th[data-key=peak_punch_force]",
                              "aria-sort") == "ascending"
    ids = shown_ids(page)
    assert ids[:2] == sorted(force, key=force.get)  # smaller force first
    assert sorted(ids[2:]) == sorted(without)  # runs without a result last
    shot(page, SHOTS, "03-sorted-by-force.png")

    page.click("#runs thead th[data-key=peak_punch_force]")
    assert page.get_attribute("#runs thead th[data-key=peak_punch_force]",
                              "aria-sort") == "descending"
    ids = shown_ids(page)
    assert ids[:2] == sorted(force, key=force.get, reverse=True)
    assert sorted(ids[2:]) == sorted(without)  # still last

    page.click("#runs thead th[data-key=scene]")  # long before tiny_cup
    scenes = {r["id"]: r["scene"] for r in runs}
    assert [scenes[r] for r in shown_ids(page)] == sorted(scenes.values())
    page.wait_for_timeout(1500)  # polls redraw the rows: the order holds
    assert [scenes[r] for r in shown_ids(page)] == sorted(scenes.values())
    # with the keyboard: the header pressed keeps the focus (the row of headers is drawn
    # anew; the focus fell to the page), Space sorts as Enter does
    page.focus("#runs thead th[data-key=scene]")
    page.keyboard.press("Enter")
    assert page.evaluate("document.activeElement.dataset.key") == "scene"
    assert page.get_attribute("#runs thead th[data-key=scene]", "aria-sort") == "descending"
    page.keyboard.press(" ")
    assert page.get_attribute("#runs thead th[data-key=scene]", "aria-sort") == "ascending"
    # Tab on from the headers reaches a row, and Enter selects its run
    page.keyboard.press("Tab")
    first = page.evaluate("document.activeElement.dataset.key")
    while first is not None:  # the headers after it
        page.keyboard.press("Tab")
        first = page.evaluate("document.activeElement.dataset.key")
    row = page.evaluate("document.activeElement.dataset.id")
    assert row == shown_ids(page)[0], row
    page.keyboard.press("Enter")
    page.wait_for_function("r => document.getElementById('status').dataset.run === r", arg=row)
    assert not [e for e in errors if "/static/" in e], errors
    page.close()


def test_delete_asks_first(served, browser):
    url = served
    page, errors = open_page(browser, url)
    runs = httpx.get(f"{url}/api/runs").json()
    victim = next(r["id"] for r in runs if r["state"] == "finished")
    row = f'#runs tbody tr[data-id="{victim}"]'
    page.wait_for_selector(row)
    asked = []

    def answer(dialog, accept: bool) -> None:
        asked.append(dialog.message)
        dialog.accept() if accept else dialog.dismiss()

    page.once("dialog", lambda d: answer(d, False))
    page.click(f"{row} button.delete")
    until(lambda: asked, "no confirmation was asked")
    assert victim in asked[0] and "recording and result are deleted" in asked[0]
    page.wait_for_timeout(1500)  # a poll or two: the run is still there
    assert page.locator(row).count() == 1
    assert httpx.get(f"{url}/api/runs/{victim}").status_code == 200

    page.once("dialog", lambda d: answer(d, True))
    page.click(f"{row} button.delete")
    page.wait_for_selector(row, state="detached")
    assert httpx.get(f"{url}/api/runs/{victim}").status_code == 404
    assert f"deleted {victim}" in page.text_content("#msg")
    shot(page, SHOTS, "04-deleted.png")
    assert not [e for e in errors if "/static/" in e], errors
    page.close()


def test_a_part_over_its_forming_limit_is_marked(served, browser):
    """The cup against a forming limit curve far below its strains (Keeler-Brazier with a
    hardening exponent of 0.001: FLC0 0.0015): elements over the curve; its FLD margin is
    negative and marked as failure in the Runs table. Runs last: the sorting test counts two
    results. Run with unsaved edits (its description), at 1400 px: the table fits the window,
    the badge under the run's id."""
    url = served
    edited = tiny_cup_toml().replace("(page tests)", "(edited)")
    run = start(url, "tiny_cup", toml=edited, overrides={"material.flc.n": 0.001})["id"]
    until(lambda: httpx.get(f"{url}/api/runs/{run}").json()["state"] in ENDED, f"{run} never ended")
    page, errors = new_page(browser, url, "#scenes li.sel", width=1400, height=950)
    wait_cell(page, run, "state", "finished")
    page.wait_for_function(
        f"(document.querySelector('#runs tbody tr[data-id=\"{run}\"] "
        f"td.col-forming_limit_margin')?.textContent || '–') !== '–'")
    headers = page.eval_on_selector_all("#runs thead th", "ths => ths.map(t => t.textContent)")
    assert headers[10] == "FLD margin (% true strain)"
    margin = {e["name"]: e for e in
              httpx.get(f"{url}/api/runs/{run}/summary").json()["summary"]}[
        "forming_limit_margin"]
    assert margin["flag"] == "failure" and margin["value"] < 0
    assert margin["at"]["zone_counts"]["failure"] > 0
    shown = page.locator(f'#runs tbody tr[data-id="{run}"] td.col-forming_limit_margin span')
    assert "flag-failure" in shown.get_attribute("class")
    assert float(shown.text_content()) == pytest.approx(margin["display"]["value"], rel=5e-3)
    # the cups as saved stay under their curve: no mark
    for r in httpx.get(f"{url}/api/runs").json():
        if r["id"] != run and "forming_limit_margin" in r["results"]:
            assert r["results"]["forming_limit_margin"].get("flag") is None, r
    assert "unsaved edits" in cell(page, run, "run")
    shot(page, SHOTS, "05-over-the-forming-limit.png")
    widths = page.evaluate("(e => [e.scrollWidth, e.clientWidth])"
                           "(document.querySelector('#runs-box .runs-scroll'))")
    assert widths[0] <= widths[1], widths
    # a long reason (a stop during a build, a solver's failure) stays within the window: on
    # one line it pushed the table 86 px past it (a run stopped while it built, on a loaded
    # machine); drawn and measured at once, before the next poll redraws the table
    widths = page.evaluate("""async () => {
        const runs = await (await fetch('/api/runs')).json();
        runs[0].state = 'failed';
        runs[0].reason = 'step 7 failed at t = 0.35 after 10 cut-backs: ' + 'residual '.repeat(40);
        RunsTable.show(runs, null);
        const e = document.querySelector('#runs-box .runs-scroll');
        return [e.scrollWidth, e.clientWidth]; }""")
    assert widths[0] <= widths[1], widths
    assert not [e for e in errors if "/static/" in e], errors
    page.close()

"""What a run changed of its scene, in the Runs table in the engineer's units, and the forming
limit curve's warning under the FLD, in Debian's chromium (Playwright) against the real server
in a subprocess:

- overrides in the units the scene form shows (an edge length of 0.004 m as 4 mm, E in
  MPa, a thickness in mm), labelled; dimensionless ones as plain numbers;
- a Keeler-Brazier curve outside its correlation's range (n = 0.25) says so under the FLD.

With Q3T_SHOTS set, screenshots go to `$Q3T_SHOTS/runs-units/`."""

from __future__ import annotations

import httpx
import pytest

from tests.support.browser import new_page, serve, shot, shots_dir
from tests.support.scenes import tiny_cup_toml
from tests.support.service import ENDED, until

SHOTS = shots_dir("runs-units")
pytestmark = pytest.mark.browser
sync_api = pytest.importorskip("playwright.sync_api", reason="playwright not installed")
OVERRIDES = {"mesh.edge_length": 0.004, "material.E": 7.0e10, "shell.thickness": 0.0005,
             "tools.0.friction": 0.15, "material.flc.n": 0.25}


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("runs-units")
    with serve(tmp, {"tiny_cup": tiny_cup_toml()}, "tiny_cup", "--no-viewer") as (url, _):
        yield url


def test_overrides_in_engineers_units_and_the_flc_warning(served, browser):
    url = served
    r = httpx.post(f"{url}/api/runs", json={"scene": "tiny_cup", "overrides": OVERRIDES,
                                            "parameters": {"friction_scale": 0.5}})
    assert r.status_code == 201, r.text
    run = r.json()["id"]
    until(lambda: httpx.get(f"{url}/api/runs/{run}").json()["state"] in ENDED,
          f"{run} never ended")
    assert httpx.get(f"{url}/api/runs/{run}").json()["state"] == "finished"
    page, errors = new_page(browser, url, "#scenes li.sel", width=1500, height=950)
    row = f'#runs tbody tr[data-id="{run}"]'
    page.wait_for_selector(f"{row} td.col-changes")
    changes = page.text_content(f"{row} td.col-changes")
    assert changes == ("mesh.edge_length = 4 mm; material.E = 70000 MPa; "
                       "shell.thickness = 0.5 mm; tools.0.friction = 0.15; "
                       "material.flc.n = 0.25; Friction × 0.5 from step 1"), changes
    shot(page, SHOTS, "01-runs-table.png", where="#runs-box")
    # the run selected (it is: the newest), its FLD with the curve's warning under it
    page.click(f"{row} td.col-scene")
    page.wait_for_selector("#fld-fig:not([hidden]) #fld-warnings li")
    warning = page.text_content("#fld-warnings")
    assert "material.flc.n = 0.25 is above 0.21" in warning, warning
    shot(page, SHOTS, "02-fld-warning.png", settle_ms=500, where="#fld-fig")  # plotly's transition
    shot(page, SHOTS, "03-page.png")
    page.close()
    assert not errors, errors


def test_a_refused_start_names_values_in_the_forms_units(served, browser):
    """The server's refusal is SI ("greater than 0 m"); the message line and the error box say
    it as the field's box does (mm), not in a unit the form never shows."""
    page, errors = new_page(browser, served, "#scenes li.sel", width=1500, height=950)
    box = page.locator('[data-path="shell.thickness"] input').first
    box.fill("-0.5")
    box.press("Tab")
    page.wait_for_selector('[data-path="shell.thickness"].has-error')
    page.click("#start")
    page.wait_for_function("document.getElementById('msg').style.color == 'rgb(187, 0, 0)'")
    said = "shell.thickness: Input should be greater than 0 mm"
    for where in ("#msg", "#scene-error"):
        text = page.text_content(where)
        assert said in text and "0 m " not in f"{text} ", (where, text)
    shot(page, SHOTS, "04-refused-start.png", where="#msg")
    page.close()
    assert not errors, errors


def test_a_reload_asks_before_dropping_unsaved_edits(served, browser):
    """A review reloaded mid-run and lost the form's edits without a word: with edits not
    saved the browser asks first (beforeunload); a page without edits reloads as it is."""
    page, errors = new_page(browser, served, "#scenes li.sel", width=1500, height=950)
    asked = []
    page.on("dialog", lambda d: (asked.append(d.type), d.accept()))
    page.reload()
    page.wait_for_selector("#scenes li.sel")
    assert asked == []
    box = page.locator('[data-path="shell.thickness"] input').first
    box.fill("0.8")
    box.press("Tab")
    page.wait_for_function("() => state.unsaved")
    page.reload()
    page.wait_for_selector("#scenes li.sel")
    assert asked == ["beforeunload"], asked
    page.close()
    assert not errors, errors

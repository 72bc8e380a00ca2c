"""The Compare panel and view in Debian's chromium (Playwright) against the real server in a
subprocess, with three finished runs of a small cup (tests.support.scenes.tiny_cup_toml): as
written, with half the friction, and with linear elements; and a q3t sweep written into the
runs folder.

- ticking runs gives them letters in the order ticked (A the reference); Compare opens the
  view over the window; Esc closes it;
- the line says what differs; the summary table shows each run's value and its difference
  from A, as the API gives them;
- the force-stroke plot overlays one curve per run on axes in mm and kN;
- the thickness on the formed part toggles A / B / A − B, keeping the camera; with a run on
  another mesh the difference is disabled and the reason shown;
- a sweep's cases open as runs from the panel and compare.

With Q3T_SHOTS set, screenshots go to `$Q3T_SHOTS/compare/`."""

from __future__ import annotations

import os
import pathlib
import subprocess
import sys

import httpx
import pytest

from tests.support import ROOT
from tests.support.browser import js_number, new_page, serve, shot, shots_dir, stacked_rows
from tests.support.scenes import tiny_cup_toml
from tests.support.service import HANG, finished_run, until

SETTLE_MS = 1500  # plotly's WebGL in software draws in about a second
SHOTS = shots_dir("compare")
ENDED = {"finished", "failed", "stopped"}
pytestmark = pytest.mark.browser
sync_api = pytest.importorskip("playwright.sync_api", reason="playwright not installed")


def _finished(url: str, **body) -> str:
    return finished_run(httpx.Client(base_url=url), **body)


def _changed(url: str) -> str:
    """A finished run of tiny_cup whose friction was doubled from its third step."""
    run = httpx.post(f"{url}/api/runs", json={"scene": "tiny_cup", "paused": True}).json()["id"]
    for step in (1, 2):
        until(lambda: not httpx.get(f"{url}/api/runs/{run}").json()["pending"]
              and httpx.get(f"{url}/api/runs/{run}").json()["state"] == "paused", "not paused")
        httpx.post(f"{url}/api/runs/{run}/step")
        until(lambda s=step: httpx.get(f"{url}/api/runs/{run}").json()["step"] >= s, "no step")
    r = httpx.put(f"{url}/api/runs/{run}/parameters/friction_scale", json={"value": 2.0},
                  timeout=HANG)
    assert r.status_code == 202, r.text
    httpx.post(f"{url}/api/runs/{run}/resume")
    st = until(lambda: (s := httpx.get(f"{url}/api/runs/{run}").json())["state"] in ENDED
               and s, f"run {run} never ended")
    assert st["state"] == "finished", st["reason"]
    return run


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """The server's url and its runs folder, with three finished runs of tiny_cup: the second
    with its friction doubled from step 3, the third with half the friction (and a copy of
    the scene, tiny_cup_b, not run)."""
    tmp = tmp_path_factory.mktemp("compare-browser")
    scenes = {"tiny_cup": tiny_cup_toml(), "tiny_cup_b": tiny_cup_toml()}
    with serve(tmp, scenes, "tiny_cup", "--no-viewer") as (url, _):
        runs = [_changed(url),
                _finished(url, overrides={"tools.0.friction": 0.05, "tools.1.friction": 0.05}),
                _finished(url, element="linear")]
        yield url, tmp, runs


def open_page(browser, url: str):
    page, errors = new_page(browser, url, "#compare-box")
    page.click("#compare-box > summary")
    return page, errors


def tick(page, run: str) -> None:
    page.check(f"#compare-runs input[value='{run}']")


def test_compare_two_runs_and_toggle_the_thickness(served, browser):
    url, _, (a, b, c) = served
    page, errors = open_page(browser, url)
    page.wait_for_selector(f"#compare-runs input[value='{c}']")
    assert page.is_disabled("#compare-open")
    tick(page, c)
    tick(page, a)
    page.wait_for_function("document.querySelector('#compare-open').textContent"
                           ".includes('2 runs')")
    letters = page.eval_on_selector_all("#compare-runs tr.picked", "rows => rows.map(r => "
                                        "[r.querySelector('input').value, "
                                        "r.querySelector('.letter').textContent])")
    assert dict(letters) == {c: "A", a: "B"}  # the order ticked
    # each run says what it changed of the scene, as the Runs table does: the live parameter
    # from its step, the overrides in the form's units
    more = dict(page.eval_on_selector_all("#compare-runs tr", "rows => rows.map(r => "
                                          "[r.querySelector('input').value, "
                                          "r.querySelector('.more').textContent])"))
    assert more[a].startswith("Friction × 2 from step "), more
    assert more[b].startswith("tools.0.friction = 0.05 · tools.1.friction = 0.05 · "), more
    shot(page, SHOTS, "panel", settle_ms=SETTLE_MS)
    page.click("#compare-open")
    page.wait_for_selector("#compare-view:not([hidden])")
    page.wait_for_selector("#compare-thickness .main-svg")
    api = httpx.get(f"{url}/api/compare?runs={c},{a}").json()
    assert page.text_content("#compare-differs") == api["differs"]["line"]
    assert "shell.element linear | q3t" in api["differs"]["line"]
    assert "live changes B: Friction × 2 from step 3" in api["differs"]["line"]
    # the summary table: A's value, B's and B - A as the API gives them
    row = page.locator("#compare-summary tr[data-name='peak_punch_force']")
    values = row.locator("td .value").all_text_contents()
    peak = next(r for r in api["summary"] if r["name"] == "peak_punch_force")
    assert values == [js_number(v) for v in peak["values"]]
    delta = row.locator("td .delta").all_text_contents()
    assert delta == [f"{'+' if peak['delta'][1] > 0 else '−'}{js_number(abs(peak['delta'][1]))} "
                     f"kN ({'+' if peak['delta'][1] > 0 else '−'}"
                     f"{js_number(abs(peak['delta_pct'][1]), 2)} %)"]
    # the table as a file: the link downloads what /api/compare/summary.csv gives
    with page.expect_download() as dl:
        page.click("#compare-csv")
    saved = pathlib.Path(dl.value.path()).read_text()
    assert saved == httpx.get(f"{url}/api/compare/summary.csv?runs={c},{a}").text
    assert saved.splitlines()[0].startswith("quantity,unit,A: ")
    # the force-stroke plot: one curve per run, in mm and kN
    force = page.evaluate("() => { const d = document.getElementById('compare-force');"
                          " return {n: d.data.length, names: d.data.map(t => t.name), x: "
                          "d.layout.xaxis.title.text, y: d.layout.yaxis.title.text}; }")
    assert force == {"n": 2, "names": ["A", "B"], "x": "punch stroke (mm)",
                     "y": "punch force (kN)"}
    # B's friction change marked where its punch was at the end of step 2 (1 of 2 mm)
    marks = page.evaluate("() => { const l = document.getElementById('compare-force').layout;"
                          " return [l.shapes.map(s => s.x0), l.annotations.map(a => a.text)]; }")
    b_punch = next(p for p in api["punches"] if p["run"] == a)
    assert marks == [[b_punch["stroke"]["values"][b_punch["steps"].index(2)]],
                     ["B: Friction × 2"]]
    # the probes: a row per quantity, each with its legend of both runs' probes above it
    rows = stacked_rows(page, "compare-probes")
    assert [(r["title"], r["unit"]) for r in rows] == [
        ("<b>tool force</b> (kN)", "kN"), ("<b>thickness</b> (mm)", "mm"),
        ("<b>displacement</b> (mm)", "mm")], rows
    assert rows[0]["names"] == ["A: punch_force", "B: punch_force"], rows
    shot(page, SHOTS, "compare-diff", settle_ms=SETTLE_MS)
    # the toggle: A, then B, with the camera the user left
    shown = "() => document.getElementById('compare-thickness').dataset.show"
    assert page.evaluate(shown) == "diff"
    # the user turns the part with the mouse
    box = page.locator("#compare-thickness .gl-container").bounding_box()
    cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    page.mouse.move(cx, cy)
    page.mouse.down()
    for k in range(1, 11):
        page.mouse.move(cx + 12 * k, cy + 6 * k)
    page.mouse.up()
    camera = "() => document.getElementById('compare-thickness')._fullLayout.scene.camera.eye"
    page.wait_for_function(f"({camera})().x !== 0.7")
    turned = page.evaluate(camera)
    page.click("#compare-thickness-controls button[data-value='a']")
    page.wait_for_function(f"({shown})() === 'a'")
    shot(page, SHOTS, "compare-A", settle_ms=SETTLE_MS)
    page.click("#compare-thickness-controls button[data-value='b']")
    page.wait_for_function(f"({shown})() === 'b'")
    assert page.evaluate(camera) == pytest.approx(turned)
    colours = page.evaluate("() => { const t = document.getElementById('compare-thickness')"
                            ".data[0]; return [t.cmin, t.cmax, t.intensity.length]; }")
    th = httpx.get(f"{url}/api/compare/thickness?runs={c},{a}").json()
    assert colours == [*th["range"], len(th["b"]["thickness"])]  # one scale for A and B
    page.click("#compare-thickness-controls button[data-value='rest']")
    page.wait_for_function("document.getElementById('compare-thickness')"
                           ".dataset.shape === 'rest'")
    shot(page, SHOTS, "compare-B-rest", settle_ms=SETTLE_MS)
    page.keyboard.press("Escape")
    page.wait_for_selector("#compare-view", state="hidden")
    # on a laptop's window the summary still fits its column (no sideways scrolling)
    page.set_viewport_size({"width": 1280, "height": 800})
    page.click("#compare-open")
    page.wait_for_selector("#compare-thickness .main-svg")
    # a new comparison: the starting camera
    assert page.evaluate(camera) == {"x": 0.7, "y": -1.5, "z": 1.3}
    assert page.evaluate("() => { const s = document.getElementById('compare-summary');"
                         " return s.scrollWidth <= s.clientWidth; }")
    shot(page, SHOTS, "compare-1280", settle_ms=SETTLE_MS)
    assert not errors, errors


def test_sweep_cases_open_from_the_panel(served, browser):
    url, tmp, _ = served
    out = subprocess.run(
        [sys.executable, "-m", "sim.apps", "sweep", str(tmp / "scenes" / "tiny_cup.toml"),
         "--grid", "tools.0.friction=0.05,0.2", "--grid", "mesh.edge_length=0.003,0.0025",
         "--workers", "1", "--out", str(tmp / "runs" / "friction")],
        cwd=ROOT, capture_output=True, text=True, timeout=HANG,
        env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert out.returncode == 0, out.stderr
    page, errors = open_page(browser, url)
    page.wait_for_selector("#compare-sweeps:not([hidden])")
    page.click("#compare-import")
    page.wait_for_function("document.getElementById('compare-msg').textContent"
                           ".includes('opened as runs')")
    assert "4 case(s) opened as runs" in page.text_content("#compare-msg")
    page.wait_for_function("document.querySelectorAll('#compare-runs tr.picked').length === 4")
    shot(page, SHOTS, "sweep-panel", settle_ms=SETTLE_MS)
    page.click("#compare-open")
    page.wait_for_selector("#compare-thickness .main-svg")
    line = page.text_content("#compare-differs")
    assert line.startswith("A/B/C/D differ in:") and "tools.punch.friction" in line
    # the sweep's edge lengths in mm, labelled, on the line and in its tooltip (the file's m)
    edge = next(p for p in line.split("; ") if "mesh.edge_length" in p)
    assert edge.endswith(" mm") and "0.00" not in edge, edge
    tip = page.get_attribute("#compare-differs", "title").splitlines()
    assert next(t for t in tip if t.startswith("mesh.edge_length")).endswith(" mm"), tip
    shot(page, SHOTS, "sweep-compare", settle_ms=SETTLE_MS)
    # A and B are on other meshes (the sweep's edge lengths): no difference map, and why
    note = page.text_content("#compare-thickness-note")
    assert "no difference map: the meshes differ" in note
    assert page.is_disabled("#compare-thickness-controls button[data-value='diff']")
    page.select_option("#compare-thickness-controls select", "2")  # A against C: one mesh
    page.wait_for_function("!document.querySelector(\"#compare-thickness-controls "
                           "button[data-value='diff']\").disabled")
    page.wait_for_function("document.getElementById('compare-thickness').layout.title.text"
                           ".startsWith('Thickness difference A − C')")
    shot(page, SHOTS, "sweep-compare", settle_ms=SETTLE_MS)
    assert not errors, errors


def _failed(url: str, scene: str) -> str:
    """A run of ``scene`` that fails at its build: 20 mm thick is valid as read (the 24 mm
    blank is wider) and refused by the build (the punch's nose inside it)."""
    r = httpx.post(f"{url}/api/runs", json={"scene": scene,
                                            "overrides": {"shell.thickness": 0.02}})
    run = r.json()["id"]
    st = until(lambda: (s := httpx.get(f"{url}/api/runs/{run}").json())["state"] in ENDED
               and s, f"run {run} never ended")
    assert st["state"] == "failed" and "starts inside it" in st["reason"], st
    return run


def test_the_runs_of_one_scene_are_picked_from_a_filter(served, browser):
    """Runs of many scenes: the panel's filter lists each scene with its count of runs and
    shows one scene's runs alone; a run ticked from another scene stays in sight."""
    url, _, (a, _, _) = served
    other = _failed(url, "tiny_cup_b")
    page, errors = open_page(browser, url)
    page.wait_for_selector("#compare-filter:not([hidden])")
    runs = httpx.get(f"{url}/api/runs").json()
    mine = {r["id"] for r in runs if r["scene"] == "tiny_cup"}
    options = page.eval_on_selector_all("#compare-scene option", "os => os.map(o => o.text)")
    assert options == [f"all ({len(runs)} runs)", f"tiny_cup ({len(mine)} runs)",
                       "tiny_cup_b (1 run)"], options

    def listed() -> set[str]:
        return set(page.eval_on_selector_all("#compare-runs input", "bs => bs.map(b => b.value)"))

    assert listed() == {r["id"] for r in runs}
    page.select_option("#compare-scene", "tiny_cup_b")
    page.wait_for_function("document.querySelectorAll('#compare-runs tr').length === 1")
    assert listed() == {other}
    tick(page, other)
    page.select_option("#compare-scene", "tiny_cup")
    page.wait_for_function(f"document.querySelectorAll('#compare-runs tr').length === "
                           f"{len(mine) + 1}")
    assert listed() == mine | {other}  # the ticked run of the other scene stays
    assert page.is_checked(f"#compare-runs input[value='{other}']")
    tick(page, a)
    page.wait_for_function("document.getElementById('compare-open').textContent === "
                           "'Compare 2 runs'")
    shot(page, SHOTS, "scene-filter", settle_ms=0)
    page.select_option("#compare-scene", "")
    page.wait_for_function(f"document.querySelectorAll('#compare-runs tr').length === "
                           f"{len(runs)}")
    assert not errors, errors
    page.close()


def test_a_failed_run_as_a_says_no_difference_can_be_taken(served, browser):
    """Every difference is from A: a run that failed before any summary, ticked first, left
    the table all "–" without a word (a browser review); the page says why, and what to do."""
    url, _, (a, _, _) = served
    failed = _failed(url, "tiny_cup")  # before any step
    page, errors = open_page(browser, url)
    page.wait_for_selector(f"#compare-runs input[value='{failed}']")
    tick(page, failed)
    tick(page, a)
    page.click("#compare-open")
    page.wait_for_selector("#compare-summary p.caution")
    assert page.text_content("#compare-summary p.caution") == (
        "A has no summary, so no difference from it can be taken: tick a run with a result "
        "first to compare the others against it.")
    # its column says where it ended; the finished run's says nothing
    heads = page.locator("#compare-summary thead th .sub.ended").all_inner_texts()
    assert heads == ["failed at step 0"], heads  # before its build said its steps
    shot(page, SHOTS, "failed-a", settle_ms=SETTLE_MS)
    assert not errors, errors
    page.close()


def test_a_run_that_stopped_early_takes_no_difference_from_a_formed_part(served, browser):
    """A browser review compared a finished cup with one that failed halfway: "punch force
    at the end of the stroke +11.2 kN (+290 %)", in bold. The run stopped early shows its
    values (the part where it ended), no difference from A's but the mesh's size, and a
    note says why."""
    url, _, (a, _, _) = served
    run = httpx.post(f"{url}/api/runs", json={"scene": "tiny_cup", "paused": True}).json()["id"]
    until(lambda: httpx.get(f"{url}/api/runs/{run}").json()["state"] == "paused", "not paused")
    httpx.post(f"{url}/api/runs/{run}/step")
    until(lambda: httpx.get(f"{url}/api/runs/{run}").json()["step"] >= 1, "no step")
    httpx.post(f"{url}/api/runs/{run}/stop")
    st = until(lambda: (s := httpx.get(f"{url}/api/runs/{run}").json())["state"] in ENDED
               and s, f"run {run} never ended")
    assert st["state"] == "stopped", st
    page, errors = open_page(browser, url)
    page.wait_for_selector(f"#compare-runs input[value='{run}']")
    tick(page, a)
    tick(page, run)
    page.click("#compare-open")
    page.wait_for_selector("#compare-unlike")
    assert page.text_content("#compare-unlike") == (
        f"A finished; B stopped at step {st['step']} of {st['n_steps']}: each value is the part "
        "where its run ended, so no difference from A is taken for B (–), except the mesh's "
        "size.")
    deltas = page.eval_on_selector_all(
        "#compare-summary tbody tr", "rs => rs.map(r => [r.dataset.name, "
        "r.cells[2].querySelector('.delta').textContent])")
    assert deltas and all((d == "–") == (n not in ("elements", "dofs")) for n, d in deltas), \
        deltas
    # nor a map of A - B: each run's thickness, and why not
    page.wait_for_selector("#compare-thickness-note")
    page.wait_for_function("document.getElementById('compare-thickness-note').textContent"
                           ".includes('its part is not the formed one')")
    shot(page, SHOTS, "stopped-b", settle_ms=SETTLE_MS)
    assert not errors, errors
    page.close()

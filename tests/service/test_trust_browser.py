"""The page and its embedded viewer in Debian's chromium (Playwright), against the real server
in a subprocess: what is on screen is what runs.

- Start with unsaved edits in the form runs the edit: the run's mesh is the edited one, and the
  page says the run used unsaved edits.
- Selecting a run moves the page and the viewer together, in both directions (the Runs table,
  the viewer's "Run" dropdown), while a second browser keeps its own (its own view:
  test_views_browser.py).
- The sliders (page and viewer) show the selected run's values after a change, after a reload
  while the run runs, and after a new run starts.

With Q3T_SHOTS set, screenshots of each step go to `$Q3T_SHOTS/trust/`."""

from __future__ import annotations

import httpx
import pytest

from server import tomlout
from sim.stepping.parameters import LABELS
from tests.support.browser import new_page, serve, settled, shot, shots_dir
from tests.support.scenes import EDITED_EDGE, tiny_toml, vertices
from tests.support.service import stop_all, until

SETTLE_MS = 2500  # software WebGL draws 2-3 frames/s
SHOTS = shots_dir("trust")
pytestmark = pytest.mark.browser
sync_api = pytest.importorskip("playwright.sync_api", reason="playwright not installed")


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """The server's url and its folder (scenes/, runs/): tiny (4 steps) and long (4000)."""
    tmp = tmp_path_factory.mktemp("trust-browser")
    scenes = {"tiny": tiny_toml(),
              "long": tiny_toml(steps=4000).replace('name = "tiny"', 'name = "long"')}
    with serve(tmp, scenes, "tiny", "--step-delay", "0.2") as (url, _):
        yield url, tmp


def open_page(browser, url: str):
    page, errors = new_page(browser, url, "#scenes li.sel")
    # the first poll has read the server's selection ("" when there is no run)
    page.wait_for_function("document.getElementById('status').dataset.run !== undefined")
    page.frame_locator("#viewer").get_by_text("Colour by").first.wait_for()
    return page, errors


def status(page, key: str) -> str | None:
    return page.get_attribute("#status", f"data-{key}")


def wait_status(page, **want: str) -> None:
    cond = " && ".join(f"document.getElementById('status').dataset.{k} === {v!r}"
                       for k, v in want.items())
    page.wait_for_function(cond)


def wait_run_started(page, before: str | None) -> str:
    page.wait_for_function(f"(d => d.run && d.run !== {before!r})"
                           "(document.getElementById('status').dataset)")
    return status(page, "run")


def active_stopped(url: str) -> None:
    with httpx.Client(base_url=url) as c:
        stop_all(c)


# ---- the viewer, in its iframe (viser's GUI: Mantine) ------------------------------------------
def viewer_run(page) -> str:
    """The value of the viewer's "Run" dropdown."""
    return page.frame_locator("#viewer").get_by_role("combobox", name="Run").input_value()


def wait_viewer_run(page, run: str) -> None:
    until(lambda: viewer_run(page) == run, f"the viewer's Run dropdown never showed {run}")


def viewer_slider(page, name: str) -> float:
    """The value of the viewer's live-parameter slider ``name`` (labelled in words)."""
    frame = page.frame_locator("#viewer").locator("body")
    return float(frame.evaluate("""(body, name) => {
        const label = [...body.querySelectorAll('label')].find(l => l.textContent === name);
        return document.getElementById(label.htmlFor).querySelector('[role=slider]')
            .getAttribute('aria-valuenow');
    }""", LABELS[name][0]))


def page_slider(page, name: str) -> float:
    return float(page.input_value(f"#param-{name}"))


def move_page_slider(page, name: str, value: float) -> None:
    """As a user drags it and lets go: input events, then one change."""
    page.eval_on_selector(f"#param-{name}", """(inp, v) => {
        inp.value = v;
        inp.dispatchEvent(new Event('input'));
        inp.dispatchEvent(new Event('change'));
    }""", value)


# ---- the workflows -----------------------------------------------------------------------------
def test_start_with_unsaved_edits_runs_the_edit(served, browser):
    url, tmp = served
    saved = (tmp / "scenes" / "tiny.toml").read_text()
    page, errors = open_page(browser, url)
    edge = page.locator('#scene-form [data-path="mesh.edge_length"] input.num')
    assert float(edge.input_value()) == 35.0  # the form shows mm (the file: 0.035 m)
    edge.fill(f"{EDITED_EDGE * 1e3:g}")
    page.wait_for_function(f"document.getElementById('toml').value.includes("
                           f"'edge_length = {EDITED_EDGE}')")
    page.wait_for_function("document.getElementById('sync').textContent === 'valid'")
    shot(page, SHOTS, "01-form-edited-not-saved", settle_ms=SETTLE_MS)
    edited = page.input_value("#toml")
    page.select_option("#element", "linear")
    page.click("#start")
    run = wait_run_started(page, "")
    wait_status(page, state="finished", edited="true")
    st = httpx.get(f"{url}/api/runs/{run}").json()
    # the edited mesh ran (the saved one has about a third of the vertices)
    assert st["counts"]["vertices"] == vertices(edited) != vertices(saved), st["counts"]
    # under a head that says what ran, with the element that ran (linear; the scene's q3t)
    ran = httpx.get(f"{url}/api/runs/{run}/scene").text
    assert ran.split("\n\n", 1)[1] == tomlout.with_element(edited, "linear")
    assert ran.startswith(f"# Run {run}, the scene as")
    assert (tmp / "scenes" / "tiny.toml").read_text() == saved  # nothing was saved
    assert "ran unsaved edits of tiny" in page.text_content("#status")
    row = page.locator(f'#runs tbody tr[data-id="{run}"]')
    assert row.locator(".edited").is_visible() and row.get_attribute("data-edited") == "true"
    wait_viewer_run(page, run)
    shot(page, SHOTS, "02-run-of-the-edit", settle_ms=SETTLE_MS)
    assert not [e for e in errors if "/static/" in e], errors
    page.close()


def test_selecting_a_run_moves_page_and_viewer(served, browser):
    url, _ = served
    page, errors = open_page(browser, url)  # tiny, as saved
    before = status(page, "run")
    page.select_option("#element", "linear")
    page.click("#start")
    newer = wait_run_started(page, before)
    wait_status(page, run=newer, state="finished", edited="false")
    older = before  # the run of the edit (previous test)
    other, _ = open_page(browser, url)  # a second browser window
    wait_status(other, run=newer)
    wait_viewer_run(page, newer)
    shot(page, SHOTS, "03-newer-run-selected", settle_ms=SETTLE_MS)

    page.click(f'#runs tbody tr[data-id="{older}"] td:first-child')
    wait_status(page, run=older)
    assert page.get_attribute("#runs tbody tr.sel", "data-id") == older
    wait_viewer_run(page, older)
    viewer = page.frame_locator("#viewer")
    viewer.get_by_text("showing recorded step").first.wait_for()  # its recording is shown
    viewer.locator("code", has_text=older).first.wait_for()
    assert status(other, "run") == newer  # the other browser keeps its own run
    shot(page, SHOTS, "04-older-run-selected-in-table", settle_ms=SETTLE_MS)

    # the viewer's own dropdown moves the page
    viewer.get_by_role("combobox", name="Run").click()
    viewer.get_by_role("option", name=newer).click()
    wait_status(page, run=newer)
    page.wait_for_function(f"document.querySelector('#runs tbody tr.sel')?.dataset.id "
                           f"=== {newer!r}")
    viewer.locator("code", has_text=newer).first.wait_for()
    shot(page, SHOTS, "05-newer-run-selected-in-viewer", settle_ms=SETTLE_MS)
    assert not [e for e in errors if "/static/" in e], errors
    other.close()
    page.close()


def test_sliders_show_the_runs_values(served, browser):
    url, _ = served
    active_stopped(url)
    page, errors = open_page(browser, url)
    page.click("#scenes li[data-name=long]")
    page.wait_for_function("document.getElementById('scene-name').value === 'long'")
    page.select_option("#element", "linear")
    before = status(page, "run")
    page.click("#start")
    run = wait_run_started(page, before)
    page.wait_for_function("+document.getElementById('status').dataset.step >= 1")
    assert page_slider(page, "friction_scale") == 1.0
    move_page_slider(page, "friction_scale", 2)
    until(lambda: httpx.get(f"{url}/api/runs/{run}").json()["parameters"]["friction_scale"]
          == 2.0, "the change never reached the run")
    step = int(status(page, "step"))
    page.wait_for_function(f"+document.getElementById('status').dataset.step > {step + 2}")
    assert page_slider(page, "friction_scale") == 2.0  # polls since have not reset it
    page.click("#pause")  # streaming stops: the viewer is slow in software WebGL
    settled(url, run)
    until(lambda: viewer_slider(page, "friction_scale") == 2.0, "viewer slider")
    assert page.input_value("#param-friction_scale-value") == "2"
    shot(page, SHOTS, "06-friction-2-page-and-viewer", settle_ms=SETTLE_MS)

    page.click("#resume")
    page.reload()  # while the run runs with friction 2
    page.wait_for_selector("#param-friction_scale:not([disabled])")
    wait_status(page, run=run, state="running")
    page.wait_for_function("document.getElementById('param-friction_scale').value === '2'")
    assert page_slider(page, "tool_speed") == 1.0
    page.click("#pause")
    settled(url, run)
    shot(page, SHOTS, "07-after-reload", settle_ms=SETTLE_MS)

    page.click("#stop")
    wait_status(page, run=run, state="stopped")
    page.wait_for_selector("#param-friction_scale[disabled]")  # an ended run's values
    assert page_slider(page, "friction_scale") == 2.0
    # the reload chose the default scene and element again: long and linear once more
    page.click("#scenes li[data-name=long]")
    page.wait_for_function("document.getElementById('scene-name').value === 'long'")
    page.select_option("#element", "linear")
    page.click("#start")
    new = wait_run_started(page, run)
    wait_status(page, run=new, state="running")
    page.wait_for_function("document.getElementById('param-friction_scale').value === '1'")
    page.click("#pause")
    settled(url, new)
    until(lambda: viewer_slider(page, "friction_scale") == 1.0, "viewer slider of the new run")
    wait_viewer_run(page, new)
    shot(page, SHOTS, "08-new-run-as-written", settle_ms=SETTLE_MS)
    page.click("#stop")
    wait_status(page, run=new, state="stopped")
    assert not [e for e in errors if "/static/" in e], errors
    page.close()


def test_the_viewer_starts_no_run(served, browser):
    """The viewer's buttons are the page's words; on an ended run they are disabled, and no
    control of the viewer starts a run."""
    url, _ = served
    active_stopped(url)
    page, _ = open_page(browser, url)
    viewer = page.frame_locator("#viewer")
    for word in ("Pause", "Resume", "Step", "Stop"):
        assert viewer.get_by_role("button", name=word, exact=True).is_disabled()
    for gone in ("Play", "Reset"):
        assert viewer.get_by_role("button", name=gone, exact=True).count() == 0
    assert viewer.get_by_role("combobox", name="Element").count() == 0
    page.close()

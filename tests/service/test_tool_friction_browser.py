"""Friction per tool on the page, in Debian's chromium (Playwright), against the real server
in a subprocess on a coarse copy of the shipped cup: the selected run has a slider per tool
with friction, moving it changes that tool's friction in the run, and the result beside each
slider multiplies the scene's coefficient by both multipliers (die 0.1 × 2 × 1.5 = 0.3).

With Q3T_SHOTS set, screenshots go to `$Q3T_SHOTS/tool-friction/`."""

from __future__ import annotations

import httpx
import pytest

from tests.support import ROOT
from tests.support.browser import VIEWER_FOR_SHOTS, new_page, serve, settled, shot, shots_dir
from tests.support.service import until

SHOTS = shots_dir("tool-friction")
pytestmark = pytest.mark.browser
sync_api = pytest.importorskip("playwright.sync_api", reason="playwright not installed")
# the cup at a 6 mm edge: a run builds and steps in about a second
COARSE = (ROOT / "scenes" / "cup_drawing.toml").read_text().replace(
    "edge_length = 0.002", "edge_length = 0.006").replace('name = "cup_drawing"', 'name = "cup"')


@pytest.fixture(scope="module")
def url(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("tool-friction-browser")
    with serve(tmp, {"cup": COARSE}, "cup", "--step-delay", "0.3",
               *VIEWER_FOR_SHOTS) as (url, _):
        yield url


def slide(page, name: str, value: float) -> None:
    """Move the slider of ``name`` to ``value`` as a user's drag ends (input, then change)."""
    page.eval_on_selector(f"[id='param-{name}']", """(inp, v) => {
        inp.value = v;
        inp.dispatchEvent(new Event('input'));
        inp.dispatchEvent(new Event('change'));
    }""", value)


def text(page, selector: str) -> str:
    """The element's text, or a box's value (a live parameter's value is a box to type in)."""
    return page.eval_on_selector(f"[id='{selector}']", "e => e.value ?? e.textContent") or ""


def test_a_slider_per_tool_changes_that_tools_friction(browser, url):
    page, errors = new_page(browser, url, "#scenes li.sel", "#param-friction_scale")
    # paused: a paused run takes changes, and the coarse cup cannot end meanwhile
    run = httpx.post(f"{url}/api/runs", json={"scene": "cup", "paused": True}).json()["id"]
    try:
        settled(url, run)
        page.wait_for_function(f"document.getElementById('status').dataset.run === {run!r}")
        for tool in ("punch", "die", "blank_holder"):
            page.wait_for_selector(f"[id='param-friction_scale.{tool}']:not([disabled])")
        labels = page.locator("#sliders").inner_text()
        assert "Friction × die" in labels and "Friction × blank_holder" in labels, labels
        # the run was started by a script: the page asks once before acting on it
        asked = []
        page.on("dialog", lambda d: (asked.append(d.message), d.accept()))
        slide(page, "friction_scale.die", 2)
        until(lambda: httpx.get(f"{url}/api/runs/{run}").json()["parameters"]
              ["friction_scale.die"] == 2, "the die's friction never reached the run")
        until(lambda: text(page, "param-friction_scale.die-result") == "die 0.1 × 2 = 0.2",
              f"die result {text(page, 'param-friction_scale.die-result')!r}")
        slide(page, "friction_scale", 1.5)
        until(lambda: text(page, "param-friction_scale.die-result") ==
              "die 0.1 × 2 × 1.5 = 0.3",
              f"die result {text(page, 'param-friction_scale.die-result')!r}")
        # the run-wide line is redrawn from the next status the page reads (not from the
        # one its own slider's change was sent with)
        until(lambda: "punch 0.1 × 1.5 = 0.15" in (whole := text(
            page, "param-friction_scale-result")) and "die 0.1 × 1.5 × 2 = 0.3" in whole,
              f"run-wide result {text(page, 'param-friction_scale-result')!r}")
        assert len(asked) == 1 and "started by a script" in asked[0], asked
        log = settled(url, run)["parameter_log"]
        assert [e["name"] for e in log] == ["friction_scale.die", "friction_scale"], log
        assert text(page, "param-friction_scale.punch-value") == "1"
        # the viewer draws in software WebGL
        shot(page, SHOTS, "01-tool-friction.png", settle_ms=1500, where="#sliders")
        shot(page, SHOTS, "02-page.png")
    finally:
        httpx.post(f"{url}/api/runs/{run}/stop")
    # an ended run's sliders, its values as it ended, disabled
    page.wait_for_selector("[id='param-friction_scale.die'][disabled]")
    assert text(page, "param-friction_scale.die-value") == "2"
    page.close()
    assert not errors, errors

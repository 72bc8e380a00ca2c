"""Two browsers (two Playwright contexts of Debian's chromium) on one server, each with its own
view: its selected run, its viewer's colour mode and time slider (the step it was scrubbed to
is marked on that page's plots only), and an action on a run the other started asks first,
says so, and shows on the starter's page.

With Q3T_SHOTS set, screenshots of each step go to `$Q3T_SHOTS/views/`."""

from __future__ import annotations

import pytest

from tests.support.browser import VIEWER_FOR_SHOTS, WAIT_MS, page_url, serve, shot, shots_dir
from tests.support.scenes import tiny_toml
from tests.support.service import until

SHOTS = shots_dir("views")
pytestmark = pytest.mark.browser
sync_api = pytest.importorskip("playwright.sync_api", reason="playwright not installed")
# tiny (4 steps) and long (4000)
SCENES = {"tiny": tiny_toml(),
          "long": tiny_toml(steps=4000).replace('name = "tiny"', 'name = "long"')}


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """The server's url: SCENES, every step recorded."""
    tmp = tmp_path_factory.mktemp("views-browser")
    with serve(tmp, SCENES, "tiny", "--step-delay", "0.2", "--record-every", "1") as (url, _):
        yield url


@pytest.fixture(scope="module")
def plain(tmp_path_factory):
    """The same server for what the pages alone say: without the 3-D view unless screenshots
    are asked."""
    tmp = tmp_path_factory.mktemp("views-browser-plain")
    with serve(tmp, SCENES, "tiny", "--step-delay", "0.2", *VIEWER_FOR_SHOTS) as (url, _):
        yield url


class Browser:
    """A browser of its own (a Playwright context: its own tabs' storage), with the page
    open; its confirmation dialogs are accepted and kept."""

    def __init__(self, browser, url: str):
        self.context = browser.new_context(viewport={"width": 1400, "height": 1000})
        self.page = self.context.new_page()
        self.page.set_default_timeout(WAIT_MS)
        self.errors: list[str] = []
        self.dialogs: list[str] = []
        self.page.on("pageerror", lambda e: self.errors.append(str(e)))
        self.page.on("dialog", self._accept)
        self.page.goto(page_url(url))
        self.page.wait_for_selector("#scenes li.sel")
        self.page.wait_for_function(
            "document.getElementById('status').dataset.run !== undefined")
        self.viewer = self.page.frame_locator("#viewer")
        # the page has asked for its config by now: a server without the viewer has no frame
        if self.page.locator("#viewer").count():
            self.viewer.get_by_text("Colour by").first.wait_for()

    def _accept(self, dialog) -> None:
        self.dialogs.append(dialog.message)
        dialog.accept()

    def run(self) -> str | None:
        return self.page.get_attribute("#status", "data-run")

    def start(self, scene: str) -> str:
        before = self.run()
        self.page.click(f"#scenes li[data-name={scene}]")
        self.page.wait_for_function(
            f"document.getElementById('scene-name').value === {scene!r}")
        self.page.select_option("#element", "linear")
        self.page.click("#start")
        self.page.wait_for_function(f"(d => d.run && d.run !== {before!r})"
                                    "(document.getElementById('status').dataset)")
        return self.run()

    def wait_status(self, **want: str) -> None:
        self.page.wait_for_function(" && ".join(
            f"document.getElementById('status').dataset.{k} === {v!r}"
            for k, v in want.items()))

    def viewer_run(self) -> str:
        return self.viewer.get_by_role("combobox", name="Run").input_value()

    def legend(self) -> str:
        return self.viewer.locator(".q3t-legend").first.inner_text()

    def choose(self, name: str, option: str) -> None:
        self.viewer.get_by_role("combobox", name=name).click()
        self.viewer.get_by_role("option", name=option).click()

    def time_slider_home(self) -> None:
        """A user moves the viewer's time slider to its start (the keyboard's Home)."""
        body = self.viewer.locator("body")
        body.evaluate("""body => {
            const label = [...body.querySelectorAll('label')].find(l => l.textContent === 'Step');
            document.getElementById(label.htmlFor).querySelector('[role=slider]').focus();
        }""")
        self.page.keyboard.press("Home")

    def shot(self, name: str) -> None:
        shot(self.page, SHOTS, name, settle_ms=2500)  # software WebGL: 2-3 frames/s

    def close(self) -> None:
        assert not [e for e in self.errors if "/static/" in e], self.errors
        self.context.close()


def test_two_browsers_show_their_own_run_colours_and_step(served, browser):
    a = Browser(browser, served)
    run_a = a.start("tiny")
    a.wait_status(run=run_a, state="finished")
    b = Browser(browser, served)
    run_b = b.start("tiny")
    b.wait_status(run=run_b, state="finished")
    until(lambda: a.viewer_run() == run_a and b.viewer_run() == run_b,
          "each viewer does not show its own browser's run")
    assert a.run() == run_a  # B's new run is B's; A still shows its own
    a.viewer.locator("code", has_text=run_a).first.wait_for()

    a.choose("Colour by", "von Mises stress (MPa)")
    a.viewer.get_by_text("von Mises stress").first.wait_for()
    until(lambda: "MPa" in a.legend(), "A's legend did not follow its colour mode")
    assert "Thickness" in b.legend() and "MPa" not in b.legend()

    a.page.wait_for_selector("#probes-fig:not([hidden])")
    # A's run left the live runs when B's was built (one solver): its view switches to the
    # recording, read from disk; a slider moved before that is drawn over by the recording's
    # last step (a loaded machine took long enough for that, once)
    a.viewer.get_by_text("showing recorded step").first.wait_for()
    a.time_slider_home()
    a.viewer.get_by_text("showing recorded step 0").first.wait_for()
    a.page.wait_for_function("document.getElementById('probes-plot').dataset.scrub === '0'")
    assert "3-D view: step 0" in a.page.inner_text("#probes-plot")
    a.shot("01-browser-a-von-mises-scrubbed-to-0")
    b.page.wait_for_timeout(1500)  # a poll or two of B's: A's scrub must not reach it
    assert b.page.get_attribute("#probes-plot", "data-scrub") in (None, "")
    assert "3-D view" not in b.page.inner_text("#probes-plot")
    assert b.viewer_run() == run_b and a.run() == run_a
    b.shot("02-browser-b-own-run-thickness")
    a.close()
    b.close()


def test_stopping_another_browsers_run_says_so(plain, browser):
    a, b = Browser(browser, plain), Browser(browser, plain)
    run = a.start("long")
    a.wait_status(run=run, state="running")
    b.page.click(f'#runs tbody tr[data-id="{run}"] td:first-child')
    b.wait_status(run=run, state="running")
    b.page.click("#stop")
    b.wait_status(run=run, state="stopped")
    assert any("was started by another page" in d for d in b.dialogs), b.dialogs
    assert "started by another page" in b.page.inner_text("#msg")
    a.wait_status(run=run, state="stopped")
    a.page.wait_for_selector("#touched:not([hidden])")
    assert "stopped by another page" in a.page.inner_text("#touched")
    # the run shown: said once, under its status (the notice box is for runs not shown)
    assert a.page.is_hidden("#notice")
    assert a.dialogs == []  # its own run: nothing asked
    a.shot("03-browser-a-its-run-stopped-by-b")
    b.shot("04-browser-b-stopped-a-run-of-a")
    a.close()
    b.close()

"""The real server in a subprocess, driven by Playwright in Debian's chromium: open the page,
start a run on a tapered sheet, see the coloured shell in the viser viewer (pixel colours from
the colour map, several of its bins: the thickness varies along the sheet), pause and see the
step count stop; press the viewer's own Resume, Pause and Step; edit a scene in the schema form
(errors next to the field, lists, optional fields, the TOML view in sync both ways), save it,
run it and read the run's error estimate from a study report."""

from __future__ import annotations

import io
import json
import time
from pathlib import Path

import httpx
import numpy as np
import pytest

from server import sceneform
from server.colormap import VIRIDIS
from server.tomlout import drop_none
from tests.support import ROOT
from tests.support.browser import CHROMIUM, VIEWER_FOR_SHOTS, new_page, serve, settled, shots_dir
from tests.support.scenes import tiny_toml
from tests.support.service import HANG, stop_all

SHOTS = shots_dir("browser")
pytestmark = pytest.mark.browser
if not Path(CHROMIUM).exists():
    pytest.skip(f"{CHROMIUM} missing (apt-get install chromium)", allow_module_level=True)
sync_api = pytest.importorskip("playwright.sync_api", reason="playwright not installed")


# steps x step delay outlasts every wait of the test before its Stop (a few hang guards): the
# run cannot end by itself first, however loaded the machine (it ended first once, and Stop
# then found a finished run)
STEP_DELAY = 0.2
STEPS = int(4 * HANG / STEP_DELAY)


def tapered_toml(steps: int) -> str:
    """tiny with a thickness falling linearly from 7 mm at the clamp to 3.5 mm at the tip."""
    text = tiny_toml(steps=steps)
    assert "thickness = 0.007\n" in text
    return text.replace("thickness = 0.007\n",
                        "thickness = 0.007\nthickness_gradient = [-0.005, 0.0, 0.0]\n")


@pytest.fixture(scope="module")
def server(served):
    return served[0]


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """(url, folder with scenes/ and runs/)"""
    tmp = tmp_path_factory.mktemp("browser")
    scenes = {"tiny": tapered_toml(steps=STEPS)}
    with serve(tmp, scenes, "tiny", "--step-delay", str(STEP_DELAY)) as (url, _):
        yield url, tmp


@pytest.fixture(scope="module")
def plain(tmp_path_factory):
    """(url, folder) of the same server for the scene form, which needs no 3-D view: without
    it unless screenshots are asked."""
    tmp = tmp_path_factory.mktemp("browser-plain")
    scenes = {"tiny": tapered_toml(steps=STEPS)}
    with serve(tmp, scenes, "tiny", "--step-delay", str(STEP_DELAY),
               *VIEWER_FOR_SHOTS) as (url, _):
        yield url, tmp


def hue(rgb: np.ndarray) -> np.ndarray:
    """Shape: (n, 3) in 0..255 -> hue in degrees (n,)."""
    r, g, b = (rgb / 255.0).T
    return np.degrees(np.arctan2(np.sqrt(3) * (g - b), 2 * r - g - b)) % 360


BINS = 8  # the colour map split into this many equal ranges of the field


def colormap_pixels(png: bytes) -> tuple[int, float, np.ndarray]:
    """Chromatic pixels left of viser's GUI panel whose hue is that of a colour-map entry
    (lighting changes brightness and saturation, not hue; viridis' hue falls monotonically
    from purple to yellow, so the hue also tells where on the map a pixel is): their count,
    their fraction, and how many fall in each of BINS ranges of the map."""
    from PIL import Image

    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), np.float64)
    img = img[:, : int(0.6 * img.shape[1])].reshape(-1, 3)
    img = img[img.max(1) - img.min(1) > 25]  # not the grey background and grid
    t = np.linspace(0, len(VIRIDIS) - 1, 64)
    ref = np.array([np.interp(t, np.arange(len(VIRIDIS)), VIRIDIS[:, c]) for c in range(3)]).T
    d = np.abs(hue(img)[:, None] - hue(ref)[None, :])
    d = np.minimum(d, 360 - d)
    ok = d.min(1) < 8
    bins = np.bincount(d[ok].argmin(1) * BINS // len(ref), minlength=BINS)
    return int(ok.sum()), float(ok.sum()) / max(len(img), 1), bins


def spread(bins: np.ndarray) -> int:
    """Colour-map bins holding at least 5 % of the matching pixels."""
    return int((bins >= 0.05 * max(bins.sum(), 1)).sum())


def test_page_run_viewer_pause(server, browser, tmp_path):
    page, _ = new_page(browser, server, "#scenes li[data-name=tiny]")
    try:
        # the list is drawn before the chosen scene's text arrives: wait for that too
        page.wait_for_function("document.getElementById('toml').value"
                               ".includes('name = \"tiny\"')")
        page.select_option("#element", "linear")
        page.click("#start")
        page.wait_for_function("+document.getElementById('status').dataset.step >= 2")
        frame = page.frame_locator("#viewer")
        frame.locator("canvas").first.wait_for()
        frame.get_by_text("Colour by").first.wait_for()
        page.click("#pause")  # software WebGL is slow: pause before the screenshot
        page.wait_for_function("document.getElementById('status').dataset.state == 'paused'")
        run = page.get_attribute("#status", "data-run")
        step = settled(server, run)["step"]  # after the step under way when pause arrived
        # software WebGL draws 2-3 frames/s and, on a cold start, the coloured mesh can take a
        # while to arrive: look again for up to 2 minutes before calling the viewer empty
        deadline = time.time() + 120.0
        while True:
            time.sleep(2.0)
            png = page.locator("#viewer").screenshot()
            count, frac, bins = colormap_pixels(png)
            if (count > 1000 and frac > 0.5 and spread(bins) >= 3) or time.time() > deadline:
                break
        (tmp_path / "viewer.png").write_bytes(png)
        assert httpx.get(f"{server}/api/runs/{run}").json()["step"] == step, "pause ignored"
        assert int(page.get_attribute("#status", "data-step")) == step
        assert page.get_attribute("#status", "data-state") == "paused"
        assert count > 1000 and frac > 0.5, f"colour-map pixels {count} ({frac:.2f}): {tmp_path}"
        # the sheet tapers from 7 to 3.5 mm: its colours span the map, not one hue of it (a
        # one-colour mesh fills a single bin)
        assert spread(bins) >= 3, f"colour-map bins {bins.tolist()}: {tmp_path}"
        # the viewer's own buttons: Resume, Pause, Step (viser GUI in the iframe)
        frame.get_by_role("button", name="Resume").click()
        page.wait_for_function(f"+document.getElementById('status').dataset.step > {step}")
        frame.get_by_role("button", name="Pause").click()
        page.wait_for_function("document.getElementById('status').dataset.state == 'paused'")
        step = settled(server, run)["step"]
        frame.get_by_role("button", name="Step").click()
        page.wait_for_function(f"+document.getElementById('status').dataset.step == {step + 1}")
        st = settled(server, run)
        assert st["step"] == step + 1 and st["state"] == "paused", st
        step += 1
        page.click("#resume")
        page.wait_for_function(f"+document.getElementById('status').dataset.step > {step}")
        # the run's row in the Runs table says the headline's step at every look (it read the
        # newer list, a step or four ahead, between two polls of the headline)
        for _ in range(12):
            head, row = page.evaluate("""() => [document.getElementById('status').dataset.step,
                document.querySelector('#runs tbody tr.sel td.col-progress').innerText]""")
            assert row.strip().startswith(f"{head}/"), (head, row)
            page.wait_for_timeout(150)
        page.click("#stop")
        page.wait_for_function("document.getElementById('status').dataset.state == 'stopped'")
        # its summary is the sheet at its last step, and says so above the cards
        page.wait_for_function("document.getElementById('summary').dataset.ready === 'true'")
        step = int(page.get_attribute("#status", "data-step"))
        assert int(page.get_attribute("#summary", "data-count")) > 0
        note = page.locator("#summary .ended-early").text_content()
        assert note.startswith(f"Stopped at step {step} of "), note
    finally:
        page.close()


def test_scene_form_and_run_estimate(plain, browser):
    url, tmp = plain
    (tmp / "runs" / "study-formed").mkdir(parents=True)
    (tmp / "runs" / "study-formed" / "report.json").write_text(json.dumps({"study": {
        "plan": {"scene": "scenes/formed.toml", "probe": "tip", "elements": ["linear"],
                 "levels": [0.035], "reference": ["quadratic", 0.0035], "notes": []},
        "reference": {"value": -1.0}, "date": "2026-11-22",
        "rows": [{"element": "linear", "edge_length": 0.035, "status": "converged",
                  "dofs": 100, "probe": -0.9, "error": 0.1, "time": 0.1, "iterations": 1}]}}))
    # errors: the uncaught ones; of our scripts (/static/) none, the embedded viewer's aside
    page, errors = new_page(browser, url)
    try:
        field = lambda path: page.locator(f'#scene-form [data-path="{path}"]')  # noqa: E731
        nu = field("material.nu").locator("input")
        nu.wait_for()
        # a text box (a locale comma reads as a point), its bound given by the server's error
        assert nu.input_value() == "0.49"
        assert field("material.model").locator("select").input_value() == "neo_hookean"
        # every shipped scene: the form built from its JSON gives that JSON back
        for path in sorted((ROOT / "scenes").glob("*.toml")):
            scene = sceneform.parse(path.read_text())["scene"]
            back = page.evaluate("""async (scene) => {
                const schema = await (await fetch('/api/scenes/schema')).json();
                const f = new SceneForm.Form(document.createElement('div'), schema);
                f.build(scene);
                return f.value();
            }""", scene)
            assert back == drop_none(scene), path.stem
        # raw tables of an invalid scene come back as they are (the server names the errors)
        raw = {"name": "x", "mesh": {"kind": "rectanglee", "size": [1, None]}, "bcs": [{}]}
        back = page.evaluate("""(raw) => {
            const f = new SceneForm.Form(document.createElement('div'), state.form.schema);
            f.build(raw);
            return f.value();
        }""", raw)
        # an unknown kind has no fields of its own to show: its other fields are kept as they
        # are (shown read-only) and come back with the kind, for the server to name
        assert back["mesh"] == {"kind": "rectanglee", "size": [1, None]}
        assert back["bcs"] == [{"components": "xyz", "layers": "all",  # region: missing
                                "displacement": [0, 0, 0], "keyframes": [],
                                "release": False, "release_only": False}]

        # a bad value: the server's error next to the field; the TOML view follows the form
        nu.fill("0.7")
        err = field("material.nu").locator(":scope > .field-error")
        err.filter(has_text="Input should be less than 0.5").wait_for()
        assert "nu = 0.7" in page.input_value("#toml")
        nu.fill("0.3")
        page.wait_for_function("document.getElementById('toml').value.includes('nu = 0.3')")
        assert err.text_content() == ""
        # a list item: add a region (its name is missing, then its shape), then remove it
        page.click('#scene-form [data-path="regions"] > button.add')
        field("regions.1.name").locator(":scope > .field-error").filter(
            has_text="Field required").wait_for()
        field("regions.1.name").locator("input").fill("extra")
        field("regions.1").locator(":scope > .field-error").filter(
            has_text="exactly one of box, plane or ring").wait_for()
        assert field("regions.1.name").locator(":scope > .field-error").text_content() == ""
        page.click('#scene-form [data-path="regions.1"] button.remove')
        page.wait_for_function("document.getElementById('scene-error').dataset.count === '0'")
        # an optional field: unset -> set
        opt = field("shell.thickness_points")
        assert opt.locator("input.num").is_disabled()
        opt.locator("input.unset").uncheck()
        opt.locator("input.num").fill("5")
        page.wait_for_function(
            "document.getElementById('toml').value.includes('thickness_points = 5')")
        # the TOML view: an edit there rebuilds the form
        page.click("#tab-toml")
        toml = page.input_value("#toml").replace('name = "tiny"', 'name = "formed"')
        page.fill("#toml", toml.replace(f"steps = {STEPS}", "steps = 2"))
        page.click("#tab-form")
        page.wait_for_function("document.querySelector('#scene-form [data-path=\"stepping.steps"
                               "\"] input').value === '2'")
        assert field("shell.thickness_points").locator("input.num").input_value() == "5"
        # save under a new name, run it: the finished run shows its estimate
        page.fill("#scene-name", "formed")
        page.click("#save")
        page.wait_for_selector("#scenes li[data-name=formed]")
        saved = httpx.get(f"{url}/api/scenes/formed").json()
        assert saved["scene"]["material"]["nu"] == 0.3
        assert saved["scene"]["shell"]["thickness_points"] == 5
        assert saved["scene"]["stepping"]["steps"] == 2
        with httpx.Client(base_url=url) as c:
            stop_all(c)  # left running by a failed test before this one
        page.select_option("#element", "linear")
        page.click("#start")
        # this run's estimate, not the one of tiny's last run the page showed before it
        est = page.locator("#estimate[data-run^='formed-'] .estimate-text")
        est.wait_for()
        text = est.text_content()
        assert text.startswith("error estimate: 10 % vs quadratic at 3.5 mm (study of "
                               "2026-11-22); cost "), text
        assert "Newton iterations" in text
        assert page.get_attribute("#status", "data-state") == "finished", \
            page.text_content("#status")
        assert [e for e in errors if "/static/" in e] == [], errors
    finally:
        page.close()

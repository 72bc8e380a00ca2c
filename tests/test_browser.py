"""The real server in a subprocess, driven by Playwright in Debian's chromium: open the page,
start a run, see the coloured shell in the viser viewer (pixel colours from the colour map),
pause and see the step count stop."""

from __future__ import annotations

import io
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np
import pytest

from server.colormap import VIRIDIS
from tests.test_service import tiny_toml

CHROMIUM = "/usr/bin/chromium"
pytestmark = pytest.mark.browser
if not Path(CHROMIUM).exists():
    pytest.skip(f"{CHROMIUM} missing (apt-get install chromium)", allow_module_level=True)
sync_api = pytest.importorskip("playwright.sync_api", reason="playwright not installed")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("browser")
    (tmp / "scenes").mkdir()
    (tmp / "scenes" / "tiny.toml").write_text(tiny_toml(steps=400))
    port, vport = free_port(), free_port()
    env = {**os.environ, "XDG_CONFIG_HOME": str(tmp / "cfg"), "XDG_DATA_HOME": str(tmp / "data")}
    proc = subprocess.Popen(
        [sys.executable, "-m", "sim.cli", "serve", "tiny", "--port", str(port),
         "--viewer-port", str(vport), "--scenes-dir", str(tmp / "scenes"),
         "--runs-dir", str(tmp / "runs"), "--step-delay", "0.2"],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{port}"
    deadline = time.time() + 60
    while time.time() < deadline:
        try:
            if httpx.get(url + "/api/health", timeout=1).status_code == 200:
                break
        except httpx.HTTPError:
            time.sleep(0.2)
    else:
        proc.kill()
        raise AssertionError(proc.stdout.read().decode())
    yield url
    proc.terminate()
    proc.wait(10)


def hue(rgb: np.ndarray) -> np.ndarray:
    """Shape: (n, 3) in 0..255 -> hue in degrees (n,)."""
    r, g, b = (rgb / 255.0).T
    return np.degrees(np.arctan2(np.sqrt(3) * (g - b), 2 * r - g - b)) % 360


def colormap_pixels(png: bytes) -> tuple[int, float]:
    """Chromatic pixels left of viser's GUI panel whose hue is that of a colour-map entry
    (lighting changes brightness and saturation, not hue): their count and their fraction."""
    from PIL import Image

    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), np.float64)
    img = img[:, : int(0.6 * img.shape[1])].reshape(-1, 3)
    img = img[img.max(1) - img.min(1) > 25]  # not the grey background and grid
    t = np.linspace(0, len(VIRIDIS) - 1, 64)
    ref = np.array([np.interp(t, np.arange(len(VIRIDIS)), VIRIDIS[:, c]) for c in range(3)]).T
    d = np.abs(hue(img)[:, None] - hue(ref)[None, :])
    match = (np.minimum(d, 360 - d).min(1) < 8).sum()
    return int(match), float(match) / max(len(img), 1)


def test_page_run_viewer_pause(server, tmp_path):
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM,
                                    args=["--use-angle=swiftshader", "--enable-unsafe-swiftshader"])
        page = browser.new_page(viewport={"width": 1400, "height": 1000})
        page.goto(server + "/")
        page.wait_for_selector("#scenes li[data-name=tiny]")
        assert "name = \"tiny\"" in page.input_value("#toml")
        page.select_option("#element", "linear")
        page.click("#start")
        page.wait_for_function("+document.getElementById('status').dataset.step >= 2",
                               timeout=60_000)
        frame = page.frame_locator("#viewer")
        frame.locator("canvas").first.wait_for(timeout=30_000)
        frame.get_by_text("Colour by").first.wait_for(timeout=30_000)
        page.click("#pause")  # software WebGL is slow: pause before the screenshot
        time.sleep(1.0)  # the step under way when pause arrived may still finish
        run = page.get_attribute("#status", "data-run")
        step = httpx.get(f"{server}/api/runs/{run}").json()["step"]
        time.sleep(4.0)  # a few viewer frames at 2-3 frames/s
        png = page.locator("#viewer").screenshot()
        (tmp_path / "viewer.png").write_bytes(png)
        assert httpx.get(f"{server}/api/runs/{run}").json()["step"] == step, "pause ignored"
        assert int(page.get_attribute("#status", "data-step")) == step
        assert page.get_attribute("#status", "data-state") == "paused"
        count, frac = colormap_pixels(png)
        assert count > 1000 and frac > 0.5, f"colour-map pixels {count} ({frac:.2f}): {tmp_path}"
        page.click("#resume")
        page.wait_for_function(
            f"+document.getElementById('status').dataset.step > {step}", timeout=30_000)
        page.click("#stop")
        page.wait_for_function("document.getElementById('status').dataset.state == 'stopped'",
                               timeout=30_000)
        browser.close()

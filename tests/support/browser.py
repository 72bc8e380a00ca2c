"""Driving the page in Debian's chromium (Playwright): where the browser is, how long a wait
may take, and the run status once the solver has acted on what the page sent."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import httpx

from tests.support import ROOT
from tests.support.service import HANG, free_port, until

CHROMIUM = "/usr/bin/chromium"
# Screenshots are for a person to look at: with Q3T_SHOTS=folder each module's go to a
# subfolder of it, each after the wait software WebGL needs to draw. Without it a browser test
# drives and asserts the same workflow but takes no picture and spends none of those waits,
# which were much of the browser tests' time.
SHOTS_ROOT = os.environ.get("Q3T_SHOTS")
WAIT_MS = int(HANG * 1000)  # Playwright's waits: hang guards (its default is 30 s)
# WebGL without a GPU: chromium's software rasteriser, which headless chromium refuses unless
# told it may use it. The page itself is rastered and composited by chromium's software paths:
# Debian's chromium turns GPU rasterisation on (/etc/chromium.d/default-flags), and without a
# GPU that, and compositing, went through the emulated GL too, at several times the CPU of the
# software paths; WebGL's canvas is still drawn by SwiftShader
SWIFTSHADER = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader",
               "--disable-gpu-rasterization", "--disable-gpu-compositing"]
# the pages' 3-D view at a quarter of the pixel density (the page's viewer_dpr): software
# WebGL's cost per frame grows with the pixels, and one open viewer's frames kept nearly both
# cores busy, which the browser tests share with the rest of the suite; the screenshots to be
# looked at (Q3T_SHOTS) are drawn at the screen's own density
VIEWER_DPR = None if SHOTS_ROOT else 0.25
# a module whose workflow does not pass through the 3-D view serves without it but for the
# screenshots: software WebGL drawing an open view (each frame of a live run, and its idle
# redraws) took more of the suite's CPU than any other process
VIEWER_FOR_SHOTS = () if SHOTS_ROOT else ("--no-viewer",)


def settled(url: str, run: str) -> dict:
    """The run's status once the solver has acted on every command sent for it."""
    def idle() -> dict | None:
        st = httpx.get(f"{url}/api/runs/{run}").json()
        return st if not st["pending"] else None

    return until(idle, f"the solver never acted on the commands for {run}")


def ready(url: str, token: str | None = None) -> bool:
    """Whether the server at ``url`` answers and its solver process is up."""
    try:
        return httpx.get(url + "/api/config", params={"token": token} if token else None,
                         timeout=1).json()["ready"]
    except (httpx.HTTPError, ValueError):
        return False


@contextlib.contextmanager
def serve(tmp: Path, scenes: dict[str, str], default: str,
          *options: str, token: str | None = None) -> Iterator[tuple[str, int]]:
    """``q3t serve DEFAULT`` in a child process over ``tmp/scenes`` (written from ``scenes``:
    name -> TOML) and ``tmp/runs``, on free ports, with ``options`` (``--step-delay 0.2``,
    ``--no-viewer``; ``token``: ``--token``, which every request then needs); yields its url
    and the viewer's port once it is ready, and stops it.
    Its output goes to ``tmp/server.log``: a pipe nobody reads fills up (numba's compile
    warnings on a cold cache) and then blocks the server mid-write."""
    (tmp / "scenes").mkdir(exist_ok=True)
    for name, text in scenes.items():
        (tmp / "scenes" / f"{name}.toml").write_text(text)
    port, vport = free_port(), free_port()
    env = {**os.environ, "XDG_CONFIG_HOME": str(tmp / "cfg"), "XDG_DATA_HOME": str(tmp / "data"),
           "PYTHONPATH": str(ROOT)}
    with open(tmp / "server.log", "wb") as log:
        proc = subprocess.Popen(
            [sys.executable, "-m", "sim.apps", "serve", default, "--port", str(port),
             "--viewer-port", str(vport), "--scenes-dir", str(tmp / "scenes"),
             "--runs-dir", str(tmp / "runs"), *options, *(("--token", token) if token else ())],
            env=env, stdout=log, stderr=subprocess.STDOUT)
        url = f"http://127.0.0.1:{port}"
        try:
            until(lambda: ready(url, token), f"server not up: {tmp / 'server.log'}")
            yield url, vport
        finally:
            proc.terminate()
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:  # a server that will not stop, and its run, go
                proc.kill()
                proc.wait()


@contextlib.contextmanager
def serve_without_viewer(tmp: Path, scenes: dict[str, str],
                         default: str) -> Iterator[tuple[str, Path]]:
    """``serve`` with ``--no-viewer`` and a cache of its own (Q3T_CACHE, which the server
    inherits: no user's cache); yields its url and ``tmp``."""
    os.environ["Q3T_CACHE"] = str(tmp / "cache")
    try:
        with serve(tmp, scenes, default, "--no-viewer") as (url, _):
            yield url, tmp
    finally:
        del os.environ["Q3T_CACHE"]


def open_scene(open_page, url: str, scene: str, ready: str):  # noqa: ANN001, ANN201
    """The page with ``scene`` chosen and its form showing ``ready``. A scene's entry is
    marked chosen once its form is built; a click on the chosen one would build it again,
    after the test's first edits, so only another scene is clicked."""
    page = open_page(url, "#scenes li.sel")
    if page.get_attribute("#scenes li.sel", "data-name") != scene:
        page.click(f"#scenes li[data-name='{scene}']")
        page.wait_for_selector(f"#scenes li.sel[data-name='{scene}']")
    page.wait_for_selector(ready)
    return page


def shots_dir(module: str) -> Path | None:
    """Where a module's screenshots go (a subfolder of $Q3T_SHOTS), or None: none taken."""
    return Path(SHOTS_ROOT) / module if SHOTS_ROOT else None


def shot(page, shots: Path | None, name: str, *, settle_ms: int = 0,
         where: str | None = None) -> None:
    """A screenshot of ``page`` (of the element ``where`` only, if given) to ``shots/name``
    (.png added if missing) after ``settle_ms`` of drawing; nothing when ``shots`` is None."""
    if shots is None:
        return
    if settle_ms:
        page.wait_for_timeout(settle_ms)
    path = str(shots / (name if name.endswith(".png") else f"{name}.png"))
    (page.locator(where) if where else page).screenshot(path=path)


@contextlib.contextmanager
def chromium(shots: Path | None = None) -> Iterator[object]:
    """Debian's chromium under Playwright, with software WebGL; screenshots go to ``shots``."""
    from playwright.sync_api import sync_playwright

    if shots is not None:
        shots.mkdir(parents=True, exist_ok=True)
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=SWIFTSHADER)
        try:
            yield b
        finally:
            b.close()


def page_url(url: str) -> str:
    """The address a test opens for the page at ``url`` (a url with a query names its page):
    its 3-D view at VIEWER_DPR."""
    url = url if "?" in url else url + "/"
    if VIEWER_DPR is None:
        return url
    return f"{url}{'&' if '?' in url else '?'}viewer_dpr={VIEWER_DPR}"


def new_page(browser, url: str, *ready: str, width: int = 1400,
             height: int = 1000) -> tuple[object, list[str]]:
    """A page of the service at ``url`` once each selector of ``ready`` is there, and the
    list its uncaught script errors go to (a test asserts it stays empty)."""
    page = browser.new_page(viewport={"width": width, "height": height})
    page.set_default_timeout(WAIT_MS)
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(f"{e}\n{e.stack}"))
    page.goto(page_url(url))
    for selector in ready:
        page.wait_for_selector(selector)
    return page, errors


def click_row(page, run: str) -> None:
    """Click ``run``'s row in the runs table where it is drawn now, as a user does, until the
    page marks it selected. A live run's row is drawn again at each poll, and Playwright's
    click of an element can find it gone between checking it and clicking (the page selects
    on the press, so a user's click does not miss)."""
    row = page.locator(f'#runs tbody tr[data-id="{run}"]')

    def selected() -> bool:
        box = row.bounding_box()
        if box is not None:
            page.mouse.click(box["x"] + 10, box["y"] + box["height"] / 2)
        return page.evaluate("document.querySelector('#runs tbody tr.sel')?.dataset.id") == run
    until(selected, f"the row of {run} never showed selected")


def stacked_rows(page, div: str) -> list[dict]:
    """The rows of a plot of a quantity per row (web/plots.js's ``stacked``), top to bottom:
    each one's legend title, y axis title (the unit) and trace names. Asserts that each
    legend sits above its own row and that the rows do not overlap."""
    rows = page.evaluate("""(id) => { const d = document.getElementById(id);
        const L = d._fullLayout, rows = {};
        for (const t of d.data) {
          const a = L['yaxis' + t.yaxis.slice(1)], g = L[t.legend];
          const r = rows[t.legend] ||= { domain: a.domain, top: g.y, names: [],
                                         title: g.title.text, unit: a.title.text };
          r.names.push(t.name);
        }
        return Object.values(rows); }""", div)
    rows.sort(key=lambda r: -r["top"])
    for upper, lower in zip(rows, rows[1:], strict=False):
        assert upper["domain"][0] > lower["top"], (upper, lower)  # a gap between rows
    for r in rows:
        assert r["top"] > r["domain"][1], r  # the legend above its own row
    return rows


def js_number(v: float, digits: int = 3) -> str:
    """A number as the page writes it (web/units.js num): a count whole, in thousands; else
    ``digits`` significant digits."""
    if float(v).is_integer() and abs(v) < 1e9:
        return f"{int(v):,}"
    x = float(f"{v:.{digits}g}")
    return str(int(x)) if x.is_integer() else repr(x)


def js_duration(s: float | None) -> str:
    """A duration as the page writes it (web/units.js duration)."""
    if s is None:
        return "–"
    if s < 1:
        return "under 1 s"
    s = int(s + 0.5)  # Math.round: halves up
    if s < 60:
        return f"{s} s"
    m = s // 60
    if m < 60:
        return f"{m} min {s % 60:02d} s"
    return f"{m // 60} h {m % 60:02d} min"

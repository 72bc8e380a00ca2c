"""Driving the page in Debian's chromium (Playwright): where the browser is, how long a wait
may take, and the run status once the solver has acted on what the page sent."""

from __future__ import annotations

import httpx

from tests.support.service import HANG, until

CHROMIUM = "/usr/bin/chromium"
WAIT_MS = int(HANG * 1000)  # Playwright's waits: hang guards (its default is 30 s)
# WebGL without a GPU: chromium's software rasteriser, which headless chromium refuses unless
# told it may use it
SWIFTSHADER = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader"]


def settled(url: str, run: str) -> dict:
    """The run's status once the solver has acted on every command sent for it."""
    def idle() -> dict | None:
        st = httpx.get(f"{url}/api/runs/{run}").json()
        return st if not st["pending"] else None

    return until(idle, f"the solver never acted on the commands for {run}")

"""The API docs work off-line (many forming shops are air-gapped): /docs loads Swagger UI's
scripts and styles from the app, never from a CDN.

- The HTML of /docs names no other host, and every file it names is served, with the token of
  a protected server too.
- In Debian's chromium with every request to another host refused, /docs lists every operation
  of the OpenAPI schema, opens one to its parameters and schema, and never tries to reach out.

With Q3T_SHOTS set, screenshots go to `$Q3T_SHOTS/extras/`."""

from __future__ import annotations

from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import urlsplit

import httpx
import pytest
from fastapi.testclient import TestClient

from server.app import create_app
from server.settings import Settings
from tests.support.browser import CHROMIUM, WAIT_MS, serve, shot, shots_dir
from tests.support.scenes import tiny_toml

SHOTS = shots_dir("extras")


class Links(HTMLParser):
    """Every ``src`` and ``href`` of a page."""

    def __init__(self):
        super().__init__()
        self.urls: list[str] = []

    def handle_starttag(self, tag, attrs):
        self.urls += [v for k, v in attrs if k in ("src", "href") and v]


def links(html: str) -> list[str]:
    parser = Links()
    parser.feed(html)
    return parser.urls


@pytest.mark.parametrize("token", [None, "s3cret"])
def test_docs_name_no_other_host(tmp_path, token):
    # no lifespan (no ``with``): the docs need neither the solver process nor the viewer
    client = TestClient(create_app(Settings(scenes_dir=tmp_path, runs_dir=tmp_path / "runs",
                                            viewer=False, token=token)))
    r = client.get("/docs", params={"token": token} if token else None)
    assert r.status_code == 200
    assert "cdn" not in r.text.lower() and "://" not in r.text, r.text
    urls = links(r.text)
    assert any(u.endswith(".js") for u in urls), urls
    for u in urls:
        assert not urlsplit(u).netloc, f"/docs loads {u} from another host"
        # the token travels as a cookie set by the page's own response
        assert client.get(u).status_code == 200, u


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """The server's url, without a viewer."""
    tmp = tmp_path_factory.mktemp("docs-browser")
    with serve(tmp, {"tiny": tiny_toml()}, "tiny", "--no-viewer") as (url, _):
        yield url


@pytest.fixture(scope="module")
def offline_page():
    """A new page whose every request to a host other than 127.0.0.1 is refused (and noted):
    ``(page, refused urls, page errors)``."""
    if not Path(CHROMIUM).exists():
        pytest.skip(f"{CHROMIUM} missing (apt-get install chromium)")
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright not installed")
    if SHOTS is not None:
        SHOTS.mkdir(parents=True, exist_ok=True)
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM)

        def new_page():
            page = browser.new_page(viewport={"width": 1400, "height": 1000})
            page.set_default_timeout(WAIT_MS)
            refused, errors = [], []

            def route(r):
                if urlsplit(r.request.url).hostname == "127.0.0.1":
                    r.continue_()
                else:
                    refused.append(r.request.url)
                    r.abort()

            page.route("**/*", route)
            page.on("pageerror", lambda e: errors.append(str(e)))
            return page, refused, errors

        yield new_page
        browser.close()


def operations(url: str) -> list[tuple[str, str]]:
    schema = httpx.get(url + "/openapi.json").json()
    return [(m.upper(), path) for path, ops in schema["paths"].items() for m in ops]


@pytest.mark.browser
def test_swagger_ui_offline(served, offline_page):
    page, refused, errors = offline_page()
    page.goto(served + "/docs")
    ops = operations(served)
    blocks = page.locator(".opblock-summary")
    blocks.nth(len(ops) - 1).wait_for()
    shown = {(b.locator(".opblock-summary-method").inner_text().strip(),
              b.locator(".opblock-summary-path").get_attribute("data-path"))
             for b in blocks.all()}
    shot(page, SHOTS, "docs-offline.png")
    assert shown == set(ops)
    assert "q3t-forming preview" in page.locator(".info .title").inner_text()
    # an operation opens to its request body and its schema, drawn from /openapi.json
    start = page.locator("#operations-runs-start_run")
    start.locator(".opblock-summary").click()
    start.locator(".opblock-body .model-example").first.wait_for()
    start.scroll_into_view_if_needed()
    shot(page, SHOTS, "docs-offline-start-run.png")
    assert "scene" in start.locator(".opblock-body").inner_text()
    assert not refused, f"/docs reached out: {refused}"
    assert not errors, errors

"""The service the service tests talk to: a TestClient on a tiny scene in a throwaway folder,
one server per test module that asks for ``env`` (a module may define its own)."""

from __future__ import annotations

import pytest

pytest.importorskip("fastapi")

from tests.support.scenes import tiny_toml  # noqa: E402
from tests.support.service import in_process  # noqa: E402


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("service")
    # files next to the scenes folder that no request may read, write or delete
    (tmp / "secret.toml").write_text(tiny_toml())
    (tmp / "secret.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with in_process(tmp, {"tiny": tiny_toml()}, max_body=64_000) as (client, settings):
        yield client, settings


@pytest.fixture(scope="module")
def browser(request):
    """Debian's chromium for a module of browser tests; its screenshots go to the module's
    SHOTS folder."""
    from tests.support.browser import chromium

    with chromium(request.module.SHOTS) as b:
        yield b


@pytest.fixture
def open_page(browser):
    """Pages of the service a test opens: ``open_page(url, *ready, width=, height=)`` as
    tests.support.browser.new_page; each closed when the test ends, which fails if a page
    raised a script error."""
    from tests.support.browser import new_page

    opened = []

    def open_(url: str, *ready: str, **size: int):
        page, errors = new_page(browser, url, *ready, **size)
        opened.append((page, errors))
        return page

    yield open_
    for page, _ in opened:
        page.close()
    errors = [e for _, errs in opened for e in errs]
    assert not errors, errors

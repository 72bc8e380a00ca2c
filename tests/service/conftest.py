"""The service the service tests talk to: a TestClient on a tiny scene in a throwaway folder,
one server per test module that asks for ``env`` (a module may define its own)."""

from __future__ import annotations

import os

import pytest

pytest.importorskip("fastapi")
from fastapi.testclient import TestClient  # noqa: E402

from server.app import create_app  # noqa: E402
from server.settings import Settings  # noqa: E402
from tests.support.scenes import tiny_toml  # noqa: E402
from tests.support.service import HANG, until  # noqa: E402


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("service")
    os.environ.setdefault("XDG_CONFIG_HOME", str(tmp / "config"))
    os.environ.setdefault("XDG_DATA_HOME", str(tmp / "data"))
    scenes = tmp / "scenes"
    scenes.mkdir()
    (scenes / "tiny.toml").write_text(tiny_toml())
    # files next to the scenes folder that no request may read, write or delete
    (tmp / "secret.toml").write_text(tiny_toml())
    (tmp / "secret.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    # the solver answers a parameter change between two steps: on a loaded machine that may
    # take longer than the default second, never this long (a hang guard)
    settings = Settings(scenes_dir=scenes, runs_dir=tmp / "runs", viewer=False, max_body=64_000,
                        ack_timeout=HANG)
    with TestClient(create_app(settings)) as client:
        until(lambda: client.get("/api/config").json()["ready"], "the solver never got ready")
        yield client, settings


@pytest.fixture(scope="module")
def browser(request):
    """Debian's chromium for a module of browser tests; its screenshots go to the module's
    SHOTS folder."""
    from tests.support.browser import chromium

    with chromium(request.module.SHOTS) as b:
        yield b

"""The tiers are folders: unit (one piece at a time, in-process), scenes (scene input, and the
shipped scenes through the solver at coarse size), verification (numbers against closed forms,
the paper and references), apps (the q3t commands: child processes, Dask clusters) and service
(the server end to end: its solver process, uvicorn, the recording, the viewer, Chromium).
Shared helpers are plain modules in tests/support/."""

import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
os.environ.setdefault("XDG_CONFIG_HOME", "/tmp/q3t-test-config")

import sim  # noqa: E402,F401  (before numpy: the BLAS thread setting of sim/__init__.py)

# every test of these tiers is quick and in-process: marked fast (make test-fast), as are the
# modules of other tiers that say so with ``pytestmark = pytest.mark.fast``
FAST_TIERS = ("unit", "scenes")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    here = Path(__file__).resolve().parent
    for item in items:
        path = item.path.resolve()
        if path.is_relative_to(here) and path.relative_to(here).parts[0] in FAST_TIERS:
            item.add_marker(pytest.mark.fast)

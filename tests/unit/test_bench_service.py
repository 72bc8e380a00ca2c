"""q3t bench-service's start-up rows say what the numba cache held (--warm-only on a fresh
checkout starts on a cache that lacks kernels, and compiles them: that row must not say
"warm")."""

import pytest

pytest.importorskip("fastapi")

from server.bench import _cached_kernels, _warm_label  # noqa: E402


def test_the_warm_row_says_when_the_cache_was_empty(tmp_path):
    assert _cached_kernels(None) == 0 and _cached_kernels(str(tmp_path / "none")) == 0
    (tmp_path / "a").mkdir()
    assert _cached_kernels(str(tmp_path)) == 0
    (tmp_path / "a" / "k.f-1.py311.nbi").write_bytes(b"")
    (tmp_path / "a" / "k.f-1.py311.1.nbc").write_bytes(b"")
    assert _cached_kernels(str(tmp_path)) == 1  # index files, not the code files
    assert _warm_label(None) == _warm_label(0) == "start-up to a ready page, warm numba cache"
    assert "(3 kernels compiled during it)" in _warm_label(3)

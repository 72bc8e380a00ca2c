"""``q3t warm``: its shares cover every task once, bad --part values exit 2 naming the option,
and the whole of it leaves the solver's kernels in numba's cache (on the suite's cache, warmed
by tests.split, it only loads them)."""

import os
from pathlib import Path

import pytest

from sim.apps import warm
from sim.apps.cli import main


@pytest.mark.parametrize("parts", [1, 2, 3])
def test_the_shares_cover_every_task_once(parts):
    got = [t for i in range(1, parts + 1) for t in warm.share(i, parts)]
    assert sorted(got) == sorted(warm.TASKS)


@pytest.mark.parametrize("bad", ["2", "0/2", "3/2", "a/b", "1/2/3"])
def test_a_bad_part_exits_2_naming_the_option(bad, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["warm", "--part", bad])
    assert exit_.value.code == 2 and "--part" in capsys.readouterr().err


def test_a_share_without_a_task_says_so(capsys):
    assert main(["warm", "--part", f"{len(warm.TASKS) + 1}/{len(warm.TASKS) + 1}"]) == 0
    assert "has no task" in capsys.readouterr().out


def test_warm_leaves_the_kernels_in_the_cache(capsys):
    assert main(["warm"]) == 0
    out = capsys.readouterr().out
    assert all(f"{name} kernels ready" in out for name in warm.TASKS)
    cache = Path(os.environ["NUMBA_CACHE_DIR"])  # set by sim on import (sim.numba_cache_dir)
    for kernel in ("_elastic_block", "plastic_commit_kernel", "stress_kernel", "_ans_block",
                   "total", "ans_commit_kernel", "ans_stress_kernel", "ans_volume_kernel",
                   "_penalty_kernel", "sdf_world"):
        assert any(cache.rglob(f"*.{kernel}-*.nbi")), kernel

"""``q3t warm``: its shares cover every task once, bad --part values exit 2 naming the option,
and a share runs (on the suite's cache, warmed by tests.split, it only loads the kernels)."""

import pytest

from sim.apps import warm
from sim.apps.cli import main


@pytest.mark.parametrize("parts", [1, 2, 3])
def test_the_shares_cover_every_task_once(parts):
    got = [t for i in range(1, parts + 1) for t in warm.share(i, parts)]
    assert sorted(got) == sorted(warm.TASKS)


@pytest.mark.parametrize("bad", ["2", "0/2", "3/2", "a/b", "1/2/3"])
def test_a_bad_part_exits_2_naming_the_option(bad, capsys):
    assert main(["warm", "--part", bad]) == 2
    assert "--part" in capsys.readouterr().out


def test_a_share_compiles_or_loads_its_kernels(capsys):
    assert main(["warm", "--part", "2/2"]) == 0
    assert "anisotropic kernels ready" in capsys.readouterr().out

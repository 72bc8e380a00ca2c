"""The element kernels on any number of threads (sim.solve.threads): the same bits, and a run
on one numba thread beside MKL's own threads."""

from __future__ import annotations

import multiprocessing as mp
import os
import subprocess
import sys

import numpy as np
import pytest

from sim.solve import threads
from tests.support import ROOT


@pytest.mark.parametrize("lo,hi,parts", [(0, 10, 3), (5, 6, 4), (0, 0, 2), (3, 100, 1)])
def test_the_shares_cover_the_range_in_order(lo, hi, parts):
    got = threads.shares(lo, hi, parts)
    assert len(got) <= max(1, parts)
    if hi > lo:
        assert got[0][0] == lo and got[-1][1] == hi
        assert all(a < b for a, b in got)  # none empty
        assert all(b == a2 for (_, b), (a2, _) in zip(got, got[1:], strict=False))
        sizes = [b - a for a, b in got]
        assert max(sizes) - min(sizes) <= 1


def _evaluate(element: str) -> dict[str, np.ndarray]:
    """Energy, gradient, Hessian, a commit, stresses and volume ratios of the Hill48 cup's
    sheet (1,131 elements) past its yield point, plastic state committed twice."""
    from sim.model.build import build_model
    from sim.scene.load import load_scene

    m = build_model(load_scene(ROOT / "scenes" / "cup_drawing_aa5754.toml",
                               {"mesh.edge_length": 0.0025, "shell.element": element}))
    # three blocks in a colour: three threads each take one (one thread: all three)
    assert np.diff(m.pattern.schedule.color_ptr).max() >= 3
    term, rest = m.elasticity, m.shell.rest
    rng = np.random.default_rng(3)
    x = rest * [1.04, 0.99, 1.0] + 1e-5 * rng.standard_normal(rest.shape)
    term.commit(x)
    term.commit(x * [1.01, 1.0, 1.0])
    g, data = np.zeros_like(x), np.zeros(m.pattern.nnz)
    energy = term.add_gradient_hessian(x, g, data)
    return {"energy": np.array([energy, term.energy(x)]), "gradient": g, "hessian": data,
            "fp_inv": term.fp_inv.copy(), "ep": term.ep.copy(), "von_mises": term.von_mises(x),
            "volume": term.volume_ratios(x)}


@pytest.mark.parametrize("element", ["q3t", "q3t_ans"])
def test_one_two_and_three_threads_give_the_same_bits(element, monkeypatch):
    """Each thread takes a contiguous share and a colour's blocks share no node, so the sums
    are the same in any thread count: compared to the bit, not to a tolerance."""
    got = {}
    for n in (1, 2, 3):
        monkeypatch.setattr(threads, "COUNT", n)
        got[n] = _evaluate(element)
    assert got[1]["ep"].max() > 0  # it flowed: the commit kernels ran
    # the energy alone (no scatter, no colours) sums the same per-element energies in order
    assert got[1]["energy"][0] == got[1]["energy"][1]
    for n in (2, 3):
        for key, value in got[1].items():
            assert np.array_equal(got[n][key], value), (n, key)


def test_a_run_on_one_numba_thread_beside_mkls_threads(tmp_path):
    """With numba's parallel kernels (parallel=True), NUMBA_NUM_THREADS=1 with MKL's threads
    left at their default crashed this run in PARDISO's first factorisation (a segmentation
    fault, 2026-12-06, Intel Xeon); the kernels now start no threading layer of numba's."""
    env = {k: v for k, v in os.environ.items() if k != "MKL_NUM_THREADS"}
    env.update(NUMBA_NUM_THREADS="1", PYTHONPATH=str(ROOT))
    r = subprocess.run([sys.executable, "-m", "sim.apps", "run",
                        str(ROOT / "scenes" / "cup_drawing_aa5754.toml"),
                        "--set", "mesh.edge_length=0.004", "--set", "stepping.steps=2",
                        "--set", "tools.0.velocity=[0,0,-0.004]", "--quiet",
                        "--out", str(tmp_path / "run")],
                       env=env, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-2000:]


def _fill(out: np.ndarray, a: int, b: int) -> None:
    out[a:b] = np.arange(a, b)


def _in_a_forked_child() -> None:
    out = np.zeros(8)
    threads.over_ranges(_fill, 0, 8, out)
    os._exit(0 if np.array_equal(out, np.arange(8)) else 1)


def test_a_forked_child_makes_its_own_pool(monkeypatch):
    """A child forked after the pool was made inherits it without its threads; work handed to
    it would wait forever, so the child starts from no pool."""
    monkeypatch.setattr(threads, "COUNT", 2)
    out = np.zeros(8)
    threads.over_ranges(_fill, 0, 8, out)  # the parent's pool, made here if not before
    assert threads._pool is not None and np.array_equal(out, np.arange(8))
    child = mp.get_context("fork").Process(target=_in_a_forked_child)
    child.start()
    child.join(60)  # a hang shows as no exit code; the work itself takes microseconds
    if child.exitcode is None:
        child.kill()
    assert child.exitcode == 0

"""q3t sweep: grid parsing, one case's summary (converged, invalid, solver failure), a real
sweep on a 2-worker local Dask cluster, one whose --timeout cuts cases that never end in time
and keeps the invalid rows (sorted out before any clock starts), and one on an existing
cluster (--scheduler) whose per-case budget kills hung cases in turn; each runs as a child
process group that must end with the command. No test races a clock: a case is either done
long before any limit or one that runs for minutes, cut by it."""

import json
import math
import os
import signal
import subprocess
import sys
import time

import pytest

from sim.apps.cases import run_case
from sim.apps.sweep import cases, parse_grid, split_values
from tests.support import ROOT

CANTILEVER = str(ROOT / "scenes" / "cantilever.toml")
TINY = {"mesh.edge_length": 0.07, "stepping.steps": 1}  # 20 triangles


def test_values_split_at_top_level_commas_only():
    assert split_values("0.3, 0.49") == ["0.3", "0.49"]
    assert split_values("[0,0,-9.81],[0,0,-1]") == ["[0,0,-9.81]", "[0,0,-1]"]


def test_grid_is_the_cartesian_product_over_fixed_overrides():
    grid = parse_grid(["material.nu=0.3,0.49", "shell.element=linear,q3t,quadratic"])
    assert grid == {"material.nu": [0.3, 0.49], "shell.element": ["linear", "q3t", "quadratic"]}
    cs = cases(grid, {"stepping.steps": 1})
    assert len(cs) == 6 and all(c["stepping.steps"] == 1 for c in cs)
    assert {(c["material.nu"], c["shell.element"]) for c in cs} == {
        (nu, el) for nu in (0.3, 0.49) for el in ("linear", "q3t", "quadratic")}
    with pytest.raises(ValueError, match="key.path"):
        parse_grid(["material.nu"])


def test_case_summary_covers_converged_invalid_and_failed():
    ok = run_case(CANTILEVER, {**TINY, "shell.element": "linear"})
    assert ok["status"] == "converged" and ok["dofs"] == 3 * 2 * 22
    assert ok["probes"]["tip_deflection"] < 0 and all(map(math.isfinite, ok["probes"].values()))
    bad = run_case(CANTILEVER, {**TINY, "material.nu": 0.5})
    assert bad["status"] == "invalid" and "material.nu" in bad["reason"]
    fail = run_case(CANTILEVER, {**TINY, "solver.max_iterations": 1, "stepping.max_cutbacks": 0})
    assert fail["status"] == "failed" and "no convergence in 1 iterations" in fail["reason"]
    json.dumps([ok, bad, fail])  # small and serialisable: what a Dask task sends back


def _gone(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return True
    return False


# Cases of 100,000 steps (the most a scene allows) run for minutes: cases that block until a
# clock kills them
HUNG = "99999,100000"
HANG = 300  # s: a hang guard for a whole command, far above its time on a loaded machine


def _run(cmd: list[str], limit: float = HANG) -> tuple[int, str, int]:
    """``cmd`` in its own process group, killed whole past ``limit`` s; (rc, output, pgid)."""
    p = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                         text=True, start_new_session=True)
    try:
        out, _ = p.communicate(timeout=limit)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)  # the sweep and every worker it started
        p.communicate()
        pytest.fail(f"{cmd[:4]} did not finish in {limit} s")
    return p.returncode, out, p.pid


def _assert_group_ends(pgid: int, what: str) -> None:
    """Workers, forkservers and case children all stay in the command's process group; a case
    child notices its worker is gone within a second (hang guard: 60 s)."""
    deadline = time.monotonic() + 60
    while not _gone(pgid) and time.monotonic() < deadline:
        time.sleep(0.2)
    if not _gone(pgid):
        os.killpg(pgid, signal.SIGKILL)
        pytest.fail(f"processes outlived {what}")


def _statuses(res: dict, *keys: str) -> dict:
    return {tuple(c["overrides"][k] for k in keys): c["status"] for c in res["cases"]}


def test_sweep_on_a_local_cluster_reports_failures(tmp_path):
    """8 cases on 2 workers: 4 invalid, 2 solver failures, 2 converged; every case has its
    row, the sweep is complete."""
    cmd = [sys.executable, "-m", "sim.apps", "sweep", "cantilever",
           "--grid", "material.nu=0.3,0.5", "--grid", "solver.max_iterations=1,30",
           "--grid", "stepping.steps=1,2",
           "--set", "mesh.edge_length=0.07", "--set", "stepping.max_cutbacks=0",
           "--workers", "2", "--out", str(tmp_path)]
    rc, out, pgid = _run(cmd)
    assert rc == 0, out
    res = json.loads((tmp_path / "sweep.json").read_text())
    assert res["complete"] and len(res["cases"]) == 8
    # one Newton iteration cannot solve the step and no cut-back is allowed: a solver failure
    assert _statuses(res, "material.nu", "solver.max_iterations", "stepping.steps") == {
        **{(0.3, 1, s): "failed" for s in (1, 2)}, **{(0.3, 30, s): "converged" for s in (1, 2)},
        **{(0.5, m, s): "invalid" for m in (1, 30) for s in (1, 2)}}
    ok = [c for c in res["cases"] if c["status"] == "converged"]
    assert all(c["probes"]["tip_deflection"] < 0 and c["dofs"] > 0 and c["wall"] > 0
               for c in ok)
    md = (tmp_path / "sweep.md").read_text()
    assert md.count("| invalid |") == 4 and "material.nu: Input should be less than 0.5" in md
    assert "no convergence in 1 iterations" in md and "--timeout" not in md
    assert (tmp_path / "sweep.png").stat().st_size > 0 and (tmp_path / "sweep.svg").is_file()
    _assert_group_ends(pgid, "q3t sweep")


def test_sweep_timeout_keeps_what_finished_and_ends_every_case(tmp_path):
    """--timeout on a single worker busy with a case that never ends in time, another queued
    behind it: both are cut and marked timeout, the exit code is 1, the invalid cases (sorted
    out before any clock starts) keep their rows, and the running case's child ends with the
    sweep."""
    cmd = [sys.executable, "-m", "sim.apps", "sweep", "cantilever",
           "--grid", "material.nu=0.3,0.5", "--grid", f"stepping.steps={HUNG}",
           "--set", "mesh.edge_length=0.07", "--workers", "1", "--timeout", "3",
           "--out", str(tmp_path)]
    rc, out, pgid = _run(cmd)
    assert rc == 1, out
    res = json.loads((tmp_path / "sweep.json").read_text())
    assert not res["complete"] and len(res["cases"]) == 4
    assert _statuses(res, "material.nu", "stepping.steps") == {
        **{(0.3, s): "timeout" for s in (99999, 100000)},
        **{(0.5, s): "invalid" for s in (99999, 100000)}}
    assert all("--timeout of 3 s" in c["reason"] for c in res["cases"]
               if c["status"] == "timeout")
    md = (tmp_path / "sweep.md").read_text()
    assert md.count("| invalid |") == 2 and "The sweep's --timeout of 3 s ended it" in md
    _assert_group_ends(pgid, "q3t sweep")


CLUSTER = """
import sys, dask
from distributed import LocalCluster
from sim.apps.cli import main
# non-daemonic workers may start the child processes that enforce per-case budgets
with dask.config.set({"distributed.worker.daemon": False}), LocalCluster(
        n_workers=1, threads_per_worker=1, dashboard_address=None, silence_logs=40) as c:
    sys.exit(main([*sys.argv[1:], "--scheduler", c.scheduler_address]))
"""


def test_sweep_on_an_existing_cluster_kills_hung_cases_at_their_budget(tmp_path):
    """--scheduler ADDRESS: the cases go to a cluster the sweep did not start. Its one worker
    runs a case that never ends in time, which is killed at its 3 s budget, then goes on with
    the next one, killed at its budget too."""
    cmd = [sys.executable, "-c", CLUSTER, "sweep", "cantilever",
           "--grid", f"stepping.steps={HUNG}", "--set", "mesh.edge_length=0.07",
           "--budget", "3", "--out", str(tmp_path)]
    rc, out, pgid = _run(cmd)
    assert rc == 0, out
    res = json.loads((tmp_path / "sweep.json").read_text())
    assert res["complete"] and res["scheduler"].startswith("tcp://")
    assert len(res["cases"]) == 2
    for c in res["cases"]:
        assert c["status"] == "timeout" and "killed after the 3 s budget" in c["reason"], c
        assert c["budget"] == 3
    _assert_group_ends(pgid, "the cluster")

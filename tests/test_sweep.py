"""q3t sweep: grid parsing, one case's summary (converged, invalid, solver failure), and a real
sweep on a 2-worker local Dask cluster run as a child process group that cannot outlive its
timeout."""

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from sim.sweep import cases, parse_grid, run_case, split_values

ROOT = Path(__file__).resolve().parent.parent
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


def test_sweep_on_a_local_cluster_reports_failures_and_shuts_down(tmp_path):
    cmd = [sys.executable, "-m", "sim.cli", "sweep", "cantilever",
           "--grid", "material.nu=0.3,0.5", "--grid", "solver.max_iterations=1,30",
           "--set", "mesh.edge_length=0.07", "--set", "stepping.steps=1",
           "--set", "stepping.max_cutbacks=0", "--workers", "2", "--timeout", "90",
           "--out", str(tmp_path)]
    p = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                         text=True, start_new_session=True)
    try:
        out, _ = p.communicate(timeout=150)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)  # the sweep and every worker it started
        p.communicate()
        pytest.fail("q3t sweep did not finish in 150 s")
    assert p.returncode == 0, out
    res = json.loads((tmp_path / "sweep.json").read_text())
    status = {(c["overrides"]["material.nu"], c["overrides"]["solver.max_iterations"]):
              c["status"] for c in res["cases"]}
    # one Newton iteration cannot solve the step and no cut-back is allowed: a solver failure
    assert status == {(0.3, 1): "failed", (0.3, 30): "converged",
                      (0.5, 1): "invalid", (0.5, 30): "invalid"}
    ok = next(c for c in res["cases"] if c["status"] == "converged")
    assert ok["probes"]["tip_deflection"] < 0 and ok["dofs"] > 0 and ok["wall"] > 0
    md = (tmp_path / "sweep.md").read_text()
    assert md.count("| invalid |") == 2 and "material.nu: Input should be less than 0.5" in md
    assert "no convergence in 1 iterations" in md
    assert (tmp_path / "sweep.png").stat().st_size > 0 and (tmp_path / "sweep.svg").is_file()
    deadline = time.monotonic() + 10  # the cluster's worker processes end with the command
    while not _gone(p.pid) and time.monotonic() < deadline:
        time.sleep(0.2)
    if not _gone(p.pid):
        os.killpg(p.pid, signal.SIGKILL)
        pytest.fail("Dask worker processes outlived q3t sweep")

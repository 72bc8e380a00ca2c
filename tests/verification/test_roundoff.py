"""Results do not hinge on round-off: the scenes that release a formed part (springback)
converge under MKL's other code paths and thread counts with the same probes, and a run
repeated in the same process gives the same probes.

MKL reads MKL_CBWR and its thread count when it loads, so each setting runs in a child process.
"""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from sim.elements import ROUTINE
from sim.stepping.simulation import Simulation
from tests.support import ROOT
from tests.support.scenes import coarse

pytestmark = pytest.mark.fast  # make test-fast runs all but the tests marked slow

RELEASED = ["beam_forming", "cookie_cutter", "plastic_bending"]

CHILD = """
import json, sys
sys.path.insert(0, {root!r})
import sim
from sim.stepping.simulation import Simulation
from tests.support.scenes import coarse
out = {{}}
for scene in {scenes!r}:
    for element in {elements!r}:
        s = Simulation.from_scene(coarse(f"{root}/scenes/{{scene}}.toml", element))
        ok = s.run()
        out[f"{{scene}}-{{element}}"] = {{"ok": ok, "failure": s.failure,
                                       "probes": [r.probes for r in s.records]}}
print(json.dumps(out))
"""


def _run_child(env: dict) -> dict:
    code = CHILD.format(root=str(ROOT), scenes=RELEASED, elements=ROUTINE)
    full = {k: v for k, v in os.environ.items() if k not in ("MKL_CBWR", "MKL_NUM_THREADS")}
    # a hang guard only: the nine coarse runs take about 20 s on a quiet machine
    proc = subprocess.run([sys.executable, "-c", code], env={**full, **env}, cwd=ROOT,
                          capture_output=True, text=True, timeout=1800)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.splitlines()[-1])


def _here() -> dict:
    out = {}
    for scene in RELEASED:
        for element in ROUTINE:
            s = Simulation.from_scene(coarse(ROOT / "scenes" / f"{scene}.toml", element))
            ok = s.run()
            out[f"{scene}-{element}"] = {"ok": ok, "failure": s.failure,
                                         "probes": [r.probes for r in s.records]}
    return out


@pytest.fixture(scope="module")
def here():
    return _here()


@pytest.mark.slow
@pytest.mark.parametrize("cbwr,threads", [("AVX2", "1"), ("COMPATIBLE", "2")])
def test_springback_converges_on_other_mkl_code_paths_with_the_same_probes(here, cbwr, threads):
    """Another instruction path (MKL_CBWR) and thread count change the last bits of every
    factorisation. The releases once converged or stalled with those bits (a free rigid mode,
    a penalty whose Hessian jumped at the contact layer's edge); now each converges, and every
    probe at every step agrees with this process's run. Newton stops at 1e-8 of the force
    level, which leaves the states a few 1e-9 apart (measured: 2.3e-9 of a probe's largest
    value at most, the quadratic beam's curvature); 1e-6 is far above that and far below any
    physical difference."""
    there = _run_child({"MKL_CBWR": cbwr, "MKL_NUM_THREADS": threads})
    for case, a in here.items():
        b = there[case]
        assert a["ok"] and b["ok"], (case, a["failure"], b["failure"])
        assert len(a["probes"]) == len(b["probes"])
        for name in a["probes"][0]:
            va = np.array([p[name] for p in a["probes"]])
            vb = np.array([p[name] for p in b["probes"]])
            scale = max(np.abs(va).max(), np.abs(vb).max())
            assert np.all(np.abs(va - vb) <= 1e-6 * scale), (case, name, va, vb)


def test_a_run_repeated_gives_the_same_probes():
    """PARDISO in MKL's conditional reproducibility mode (sim.solve.linsolve) and numba's kernels
    summing in a fixed order: the same run twice gives the same numbers, bit for bit, at every
    step. The issue asked for 1e-9; without the mode, PARDISO's two threads gave 2 different
    solutions in 40 factorisations of the same matrix."""
    for scene in ("cookie_cutter", "cup_drawing"):
        runs = []
        for _ in range(2):
            s = Simulation.from_scene(coarse(ROOT / "scenes" / f"{scene}.toml", "q3t"))
            assert s.run(), s.failure
            runs.append([r.probes for r in s.records])
        assert runs[0] == runs[1], scene


def test_pardiso_gives_the_same_bits_twice():
    """The same Hessian factored and solved 60 times (13,806 DoFs, where PARDISO runs its two
    threads): one answer. Without MKL's reproducibility mode 2 distinct answers came out of 40
    in two of three trials here (1e-18 apart: enough to send a near-singular solve elsewhere)."""
    from sim.model.build import build_model
    from sim.scene.load import load_scene
    from sim.solve.linsolve import Pardiso, mkl

    if mkl() is None:
        pytest.skip("MKL not installed")
    m = build_model(load_scene(ROOT / "scenes" / "cantilever.toml", {"mesh.edge_length": 0.006}))
    _, _, g, data, _ = m.problem.evaluate(m.x0 + 1e-4)
    answers = set()
    for _ in range(60):
        s = Pardiso(m.pattern)
        s.factor(data)
        answers.add(s.solve(g.ravel()).tobytes())
    assert len(answers) == 1

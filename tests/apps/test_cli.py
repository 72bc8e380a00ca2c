"""`q3t run` end to end: progress output, --set and --element, exit codes (0 converged, 1 a run
that fails, 2 bad input), result.json and final.npz."""

import json

import numpy as np
import pytest

from sim.apps.cli import main

pytestmark = pytest.mark.fast  # seconds: make test-fast runs it

COARSE = ["--set", "mesh.edge_length=0.035", "--set", "stepping.steps=2"]


def test_run_writes_result_and_final_state(tmp_path, capsys):
    out = tmp_path / "run"
    code = main(["run", "cantilever", "--element", "linear", *COARSE,
                 "--set", "material.nu=0.3", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "cantilever: linear" in err and "step 2/2" in err and "wrote" in err  # progress
    res = json.loads((out / "result.json").read_text())
    assert res["scene"] == "cantilever" and res["element"] == "linear"
    assert res["converged"] is True and res["failure"] is None
    assert res["quadrature"] == [1, 2]
    c = res["counts"]
    # 20 x 2 cells: 63 vertices, 2 layers of nodes, 80 prisms
    assert (c["vertices"], c["nodes"], c["elements"], c["dofs"]) == (63, 126, 80, 378)
    assert 0 < c["free_dofs"] < c["dofs"]
    assert [s["step"] for s in res["steps"]] == [1, 2]
    for s in res["steps"]:
        assert {"time", "iterations", "residual", "energy", "cutbacks", "probes"} <= set(s)
        assert set(s["probes"]) == {"tip_deflection", "clamp_reaction_z", "volume"}
        assert s["iterations"] >= 1 and np.isfinite(s["energy"])
    assert res["steps"][-1]["time"] == pytest.approx(1.0)
    t = res["timing"]
    assert {"total", "assembly", "factorisation", "solve", "per_iteration",
            "newton_iterations"} <= set(t)
    assert t["newton_iterations"] == sum(s["iterations"] for s in res["steps"])
    assert t["total"] >= t["assembly"] + t["factorisation"] + t["solve"] > 0
    final = np.load(out / "final.npz")
    assert {"rest", "deformed", "faces", "thickness", "rest_thickness"} <= set(final.files)
    assert final["rest"].shape == final["deformed"].shape == (126, 3)
    assert final["faces"].shape == (80, 3) and final["thickness"].shape == (63,)
    tip = final["deformed"][:, 2].min() - final["rest"][:, 2].min()
    assert tip < 0  # it sagged under its weight


def test_a_failing_run_exits_1_and_reports(tmp_path, capsys):
    """One Newton iteration and no cut-back cannot reach rtol on a nonlinear sag."""
    out = tmp_path / "fail"
    code = main(["run", "cantilever", *COARSE, "--set", "material.E=1e7",
                 "--set", "solver.max_iterations=1", "--set", "stepping.max_cutbacks=0",
                 "--quiet", "--out", str(out)])
    assert code == 1
    assert "FAILED" in capsys.readouterr().err
    res = json.loads((out / "result.json").read_text())
    assert res["converged"] is False and res["failure"]["step"] == 1
    assert res["failure"]["residuals"]  # the residual history, not NaN
    assert all(np.isfinite(res["failure"]["residuals"]))


@pytest.mark.parametrize("args,names", [
    (["cantilever", "--set", "material.nu=0.7"], "material.nu"),
    (["cantilever", "--element", "hexahedron"], "shell.element"),
    (["no_such_scene"], "no_such_scene"),
    (["cantilever", "--set", "nothing"], "--set"),
])
def test_bad_input_exits_2_naming_it(tmp_path, capsys, args, names):
    code = main(["run", *args, "--out", str(tmp_path / "x")])
    assert code == 2
    assert names in capsys.readouterr().err
    assert not (tmp_path / "x").exists()  # nothing written


def test_an_output_path_that_cannot_be_written_exits_2_before_the_solve(tmp_path, capsys):
    """--out under a file, --results where no file can be made: said at once (exit 2), not
    as a traceback after the run (exit 1, the solve's time lost)."""
    (tmp_path / "afile").write_text("")
    code = main(["run", "cantilever", *COARSE, "--out", str(tmp_path / "afile" / "x")])
    assert code == 2
    err = capsys.readouterr().err
    assert f"--out: '{tmp_path / 'afile' / 'x'}' cannot be made: '{tmp_path / 'afile'}' is a " \
        "file" in err, err
    with pytest.raises(SystemExit) as exc:
        main(["run", "cantilever", *COARSE, "--results", str(tmp_path / "afile" / "r.md")])
    assert exc.value.code == 2
    assert "cannot write there" in capsys.readouterr().err

"""The forming results files are written by the runs that measure them: ``q3t sweep --results``
(one column per case: the run summary, the probes loaded and released, the plastic fields, the
cost) and ``q3t run --results`` (one run, each probe over the steps, the sections), each at its
smallest size, and their numbers are those of the results the runs wrote."""

import json
import re
import shlex

from sim import stamp
from sim.apps.cli import main


def cells(text: str, quantity: str) -> list[str]:
    """The cells of the table row whose first cell is ``quantity``."""
    m = re.search(rf"^\| {re.escape(quantity)} \| (.+) \|$", text, re.M)
    assert m, f"no row {quantity!r} in\n{text}"
    return [c.strip() for c in m.group(1).split(" | ")]


def stamped(text: str, argv: list[str]) -> None:
    # as typed, less the (temporary) --out folder: tests/apps/test_results.py checks that rule
    assert f"- command: `{stamp.reproducible(shlex.join(['q3t', *argv]))}`" in text
    assert re.search(r"^- CPU: .+, \d+ cores$", text, re.M)
    assert re.search(r"^- load average \(1 / 5 / 15 min\): ", text, re.M)


def test_sweep_writes_a_column_per_case_read_from_what_its_tasks_returned(tmp_path):
    """plastic_bending per element at 2 steps: the curvature under load and after release and
    the fraction retained; linear prisms spring back nearly flat, Q3T keeps most of the bend
    (the paper's Fig. 6 claim, asserted on the full scene by
    tests/verification/test_plasticity.py::test_linear_prisms_retain_less_plastic_deformation)."""
    path = tmp_path / "docs" / "springback-plastic_bending.md"
    argv = ["sweep", "plastic_bending", "--grid", "shell.element=linear,q3t",
            "--set", "stepping.steps=2", "--ratio", "curvature", "--out", str(tmp_path / "runs"),
            # a hang guard, not a clock: on a cold numba cache each case's child compiles
            # every kernel first, minutes on a loaded machine
            "--budget", "3600", "--results", str(path)]
    assert main(argv) == 0
    text = path.read_text()
    stamped(text, argv)
    assert "| shell.element | linear | q3t |" in text
    assert cells(text, "status") == ["converged", "converged"]
    rows = {c["overrides"]["shell.element"]: c
            for c in json.loads((tmp_path / "runs" / "sweep.json").read_text())["cases"]}
    for i, el in enumerate(("linear", "q3t")):
        r = rows[el]
        assert cells(text, "probe curvature, loaded [1/m]")[i] == \
            f"{r['loaded_probes']['curvature']:.4g}"
        assert cells(text, "probe curvature, released [1/m]")[i] == \
            f"{r['probes']['curvature']:.4g}"
        assert cells(text, "Newton iterations")[i] == str(r["iterations"])
        fields = r["fields"]["net_plastic_strain"]
        assert cells(text, "Net plastic strain (retained), vertex mean / max [%]")[i] == \
            f"{100 * fields['mean']:.4g} / {100 * fields['max']:.4g}"
    # the end is turned to a 1 m radius: both are bent to about 1 1/m under load
    loaded = [float(c) for c in cells(text, "probe curvature, loaded [1/m]")]
    assert all(0.8 < k < 1.2 for k in loaded), loaded
    lin, q3t = (float(c) for c in cells(text, "probe curvature, released / loaded"))
    assert lin < 0.2 < 0.8 < q3t < 1.0
    # the summary's springback (sim.frames.summary), in mm: the linear strip moves far more
    lin_sb, q3t_sb = (float(c) for c in cells(text, "Springback, largest deviation [mm]"))
    assert lin_sb > 5 * q3t_sb > 0


def test_a_ratio_of_a_probe_the_scene_lacks_is_refused_before_any_case_runs(tmp_path, capsys):
    argv = ["sweep", "plastic_bending", "--grid", "shell.element=linear", "--ratio", "nope",
            "--out", str(tmp_path / "runs"), "--results", str(tmp_path / "r.md")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "--ratio nope" in err and "curvature" in err  # what the scene has
    assert not (tmp_path / "runs").exists() and not (tmp_path / "r.md").exists()


def test_run_writes_the_summary_each_probe_over_the_steps_and_the_sections(tmp_path):
    """The cup on a 6 mm mesh in 2 steps: the table's numbers are result.json's."""
    path = tmp_path / "forming-cup_drawing.md"
    out = tmp_path / "run"
    argv = ["run", "cup_drawing", "--set", "mesh.edge_length=0.006", "--set", "stepping.steps=2",
            "--set", "sections.0.steps=[0,2]", "--quiet", "--out", str(out),
            "--results", str(path)]
    assert main(argv) == 0
    text = path.read_text()
    stamped(text, argv)
    res = json.loads((out / "result.json").read_text())
    summary = {e["name"]: e for e in res["summary"]}
    peak = summary["peak_punch_force"]
    assert cells(text, "Peak punch force (punch) [kN]") == [f"{peak['value'] / 1e3:.4g}"]
    assert peak["value"] > 1e3  # the punch draws the cup: kilonewtons
    assert cells(text, "Minimum thickness [mm]") == \
        [f"{summary['min_thickness']['value'] * 1e3:.4g}"]
    # each probe over the run: final, smallest and largest with their steps
    forces = [s["probes"]["punch_force"] for s in res["steps"]]
    k = max(range(len(forces)), key=forces.__getitem__)
    assert cells(text, "punch_force [kN]") == [
        f"{forces[-1] / 1e3:.4g}", f"{min(forces) / 1e3:.4g} "
        f"({res['steps'][forces.index(min(forces))]['step']})",
        f"{forces[k] / 1e3:.4g} ({res['steps'][k]['step']})"]
    # the radial section at rest and at the end of the stroke: uniform 1 mm, then thinned
    assert cells(text, "0")[:2] == ["1", "1"]
    h = res["sections"]["radial"][-1]["thickness"]
    assert cells(text, "2")[:2] == [f"{min(h) * 1e3:.4g}", f"{max(h) * 1e3:.4g}"]
    assert min(h) < 0.95e-3  # thinned by the punch's nose: 0.916 mm (q3t_ans, 2026-12-07)

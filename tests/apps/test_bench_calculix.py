"""`q3t bench --cases calculix`: without CalculiX it exits 2 naming the program and writes
nothing; with Debian's calculix-ccx installed (CI has none: skipped there) it runs both codes on
the coarse cantilever and writes the stamped side-by-side table."""

import json
import shutil

import pytest

from sim.apps import bench, bench_calculix, calculix
from sim.apps.cli import main

COARSE = 0.035  # m: 80 triangles, a few seconds per run of either code


def test_without_ccx_the_case_exits_2_naming_the_program(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("PATH", str(tmp_path))  # no ccx on it
    assert calculix.program() is None
    code = main(["bench", "--cases", "calculix", "--out", str(tmp_path / "b"),
                 "--results", str(tmp_path / "b.md")])
    err = capsys.readouterr().err
    assert code == 2
    assert "`ccx` is not on PATH" in err and "calculix-ccx" in err and "Traceback" not in err
    assert not (tmp_path / "b").exists() and not (tmp_path / "b.md").exists()


def test_an_element_without_a_calculix_counterpart_is_refused_before_running(tmp_path, capsys):
    assert main(["bench", "--cases", "calculix", "--elements", "linear,quartic",
                 "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err
    assert "--elements: quartic has no CalculiX counterpart" in err and "Traceback" not in err
    assert not (tmp_path / "b").exists()


@pytest.mark.skipif(shutil.which("ccx") is None,
                    reason="CalculiX's ccx is not installed (Debian: apt-get install calculix-ccx)")
def test_both_codes_side_by_side_on_the_coarse_cantilever(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(bench.CASES["beam"], "spacing", COARSE)
    monkeypatch.setattr(bench_calculix, "WARM_EDGE", COARSE)
    out, md = tmp_path / "b", tmp_path / "bench-calculix.md"
    assert main(["bench", "--cases", "calculix", "--elements", "linear,q3t", "--repeat", "1",
                 "--out", str(out), "--results", str(md)]) == 0
    rows = json.loads((out / "bench.json").read_text())["rows"]
    side = {(r["element"], r["setting"]): r for r in rows if r["case"] == "calculix"}
    assert set(side) == {(el, s) for el in ("linear", "q3t") for s in bench_calculix.TOLERANCES}
    for r in side.values():
        assert r["ccx_status"] == "converged", r["ccx_status"]
        assert r["ours_iterations"] >= 4 and r["ccx_iterations"] >= 4  # one per step at least
        assert r["ours_wall"] > 0 and r["ccx_wall"] > 0 and r["ours_cpu"] > 0 and r["ccx_cpu"] > 0
    for s in bench_calculix.TOLERANCES:
        # C3D6 is our linear prism on the same mesh and rule; the laws differ at second order
        # in a strain of about 1e-3 and the tolerances leave 1e-4 of the load: 1e-4 covers both
        assert abs(side[("linear", s)]["tip_diff"]) < 1e-4
        assert side[("linear", s)]["ccx_element"] == "C3D6"
        assert side[("q3t", s)]["ccx_element"] == "C3D15"
    # at the matched tolerance ccx's NEO HOOKE is the closer of its laws to ours
    material = {r["material"]: r for r in rows if r["case"] == "calculix_material"}
    neo, svk = (abs(material[k]["tip_diff"]) for k in
                ("`*HYPERELASTIC, NEO HOOKE`", "`*ELASTIC` (St. Venant-Kirchhoff)"))
    assert neo < svk
    text = md.read_text()
    assert text.startswith("# The cantilever beside CalculiX")
    assert "- CPU:" in text and "- load average" in text and "| C3D15 |" in text
    assert (out / "calculix" / "linear-matched" / "job.sta").is_file()
    assert "calculix q3t" in capsys.readouterr().out

"""`q3t bench` runs the Fig. 7 factorisation comparison (through the study's code) besides
the per-iteration cost; here at two coarse levels."""

import json

from sim.apps import bench
from sim.apps.cli import main


def test_bench_includes_the_factorisation_comparison(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(bench, "FIG7_LEVELS", [0.07, 0.035])
    out = tmp_path / "b"
    code = main(["bench", "--cases", "factorisation", "--elements", "linear,q3t,quadratic",
                 "--repeat", "1", "--out", str(out)])
    assert code == 0
    rows = json.loads((out / "bench.json").read_text())["rows"]
    assert {r["case"] for r in rows} == {"fig7"} and len(rows) == 6
    by = {(r["element"], r["edge_length"]): r for r in rows}
    for edge in (0.07, 0.035):  # same elements at the same edge length, more nodes
        n = [by[(el, edge)] for el in ("linear", "q3t", "quadratic")]
        assert len({r["elements"] for r in n}) == 1
        assert n[0]["nodes"] < n[1]["nodes"] < n[2]["nodes"]
        assert all(r["factorisation"] > 0 for r in n)
    # Q3T at the finer level has the nodes of quadratic at the coarser one (Fig. 7, right)
    assert by[("q3t", 0.035)]["nodes"] == by[("quadratic", 0.07)]["nodes"]
    assert (out / "factorisation" / "report.json").is_file()
    assert "median [s]" in capsys.readouterr().out


def test_bench_refuses_an_unknown_case_or_element_before_timing_anything(tmp_path, capsys):
    """Bad input exits 2 naming the option (it was a KeyError traceback), and writes nothing."""
    for opts, words in ((["--cases", "beam,cupp"], "--cases: unknown cupp"),
                        (["--cases", "beam", "--elements", "linear,cubic"],
                         "--elements: unknown element 'cubic'")):
        assert main(["bench", *opts, "--out", str(tmp_path / "b")]) == 2
        err = capsys.readouterr().err
        assert words in err and "Traceback" not in err
    assert not (tmp_path / "b").exists()


def test_bench_times_forming_per_element_against_q3t(tmp_path):
    """The forming case per element of --forming-elements, each run --repeat times, the
    ratios to Q3T's iteration (medians of the rounds') in the results (a coarse cup, its
    first steps: the table's making, not its numbers)."""
    out, md = tmp_path / "b", tmp_path / "bench.md"
    code = main(["bench", "--cases", "forming", "--forming-elements", "q3t,q3t_ans",
                 "--forming-edge", "0.004", "--forming-to", "2", "--forming-steps", "1",
                 "--repeat", "2", "--out", str(out), "--results", str(md)])
    assert code == 0
    rows = json.loads((out / "bench.json").read_text())["rows"]
    assert [r["element"] for r in rows] == ["q3t", "q3t_ans"]
    assert rows[0]["elements"] == rows[1]["elements"] and all(r["converged"] for r in rows)
    assert all(r["per_iteration"] > 0 and r["newton_per_step"] >= 1 for r in rows)
    assert [r["runs"] for r in rows] == [2, 2]
    ratio = rows[1]["per_iteration_vs_q3t"]
    assert ratio > 0 and "per_iteration_vs_q3t" not in rows[0]
    text = md.read_text()
    assert "per iteration / Q3T's" in text and f"| q3t_ans | {ratio:.2f} |" in text


def test_bench_refuses_an_unknown_forming_element(tmp_path, capsys):
    assert main(["bench", "--cases", "forming", "--forming-elements", "q3t,q4t",
                 "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err
    assert "--forming-elements: unknown element 'q4t'" in err and "Traceback" not in err
    assert not (tmp_path / "b").exists()

"""``q3t reference``: a run's answers written, compared with a later run, a moved answer
named with its deviation (exit 1), bad options refused (exit 2)."""

import json

import pytest

from sim.apps.cli import main
from sim.apps.reference import deviation

pytestmark = pytest.mark.fast
COARSE = ["--set", "mesh.edge_length=0.035"]


def test_written_answers_are_met_and_a_moved_one_is_named(tmp_path, capsys):
    ref = tmp_path / "ref.json"
    assert main(["reference", "cantilever", *COARSE, "--out", str(ref)]) == 0
    data = json.loads(ref.read_text())
    assert data["steps"] == [1, 2, 3, 4] and len(data["probes"]["tip_deflection"]) == 4
    assert data["stamp"]["command"].startswith("q3t reference cantilever")
    md = tmp_path / "docs" / "stroke.md"
    assert main(["reference", "cantilever", *COARSE, "--check", str(ref), "--results",
                 str(md)]) == 0
    text = md.read_text()  # stamped like every results file, the cost and the deviations
    assert "- command: `q3t reference cantilever" in text and "- CPU: " in text
    assert "| run | steps | Newton iterations |" in text and "| tip_deflection | " in text
    # the tip 1 % off at step 3: beyond the 0.5 % default, named
    data["probes"]["tip_deflection"][2] *= 1.01
    ref.write_text(json.dumps(data))
    capsys.readouterr()
    assert main(["reference", "cantilever", *COARSE, "--check", str(ref)]) == 1
    line = next(ln for ln in capsys.readouterr().out.splitlines() if "tip_deflection" in ln)
    assert "(beyond)" in line


def test_deviation_is_relative_to_the_largest_size_and_missing_is_infinite():
    result = {"steps": [{"step": 1, "probes": {"f": 0.0}}, {"step": 2, "probes": {"f": 10.0}}],
              "sections": {"s": [{"step": 2, "thickness": [1.0, 2.0]}]}}
    ref = {"steps": [1, 2], "probes": {"f": [0.1, 10.0]},
           "sections": {"s": [{"step": 2, "thickness": [1.0, 1.9]}]}}
    dev = deviation(result, ref)
    # 0.1 off where the force passes zero is 1 % of its largest size, not infinitely wrong
    assert dev["f"] == pytest.approx(0.01)
    assert dev["section s"] == pytest.approx(0.1 / 1.9)
    assert deviation(result, {**ref, "probes": {"g": [1.0, 1.0]}})["g"] == float("inf")


@pytest.mark.parametrize("argv", [[], ["--out", "a.json", "--check", "b.json"],
                                  ["--check", "/nonexistent/ref.json"],
                                  ["--check", "NOTJSON"], ["--check", "NOTREF"]])
def test_bad_options_exit_2(argv, capsys, tmp_path):
    (tmp_path / "bad.json").write_text("{not json")
    (tmp_path / "other.json").write_text('{"steps": [1]}')  # JSON, but no probes
    argv = [{"NOTJSON": str(tmp_path / "bad.json"),
             "NOTREF": str(tmp_path / "other.json")}.get(a, a) for a in argv]
    assert main(["reference", "cantilever", *argv]) == 2  # before any run
    assert "q3t reference" in capsys.readouterr().err

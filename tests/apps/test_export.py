"""`q3t export`: a run of `q3t run` written out in each format, read back; bad input is exit 2
naming the problem."""

import csv
import json
from xml.etree import ElementTree

import meshio
import pytest
import trimesh

from sim.apps.cli import main
from tests.support.scenes import PRESS_TOML

pytestmark = pytest.mark.fast  # seconds: make test-fast runs it


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """The press (3 steps) run by `q3t run`, a frame saved every second step."""
    tmp = tmp_path_factory.mktemp("press")
    (tmp / "press.toml").write_text(PRESS_TOML)
    out = tmp / "press-run"
    assert main(["run", str(tmp / "press.toml"), "--quiet", "--record-every", "2",
                 "--out", str(out)]) == 0
    return out


def test_every_format_is_written_and_reads_back(run, tmp_path, capsys):
    res = json.loads((run / "result.json").read_text())
    for fmt in ("csv", "vtu", "stl", "ply", "json"):
        assert main(["export", str(run), "--format", fmt, "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out.split()
    rows = list(csv.reader((tmp_path / "press-run.csv").open()))
    assert rows[0][:2] == ["step", "pseudo-time [-]"] and "max_plastic_strain [%]" in rows[0]
    assert len(rows) - 1 == len(res["steps"]) == 3
    pvd = ElementTree.parse(tmp_path / "press-run.pvd").getroot()
    files = [d.get("file") for d in pvd.iter("DataSet")]
    assert files == [f"press-run_frames/step-00000{k}.vtu" for k in (0, 2, 3)]
    for f in files + ["press-run_final.vtu"]:
        assert meshio.read(tmp_path / f).cells[0].type == "wedge"
    for fmt in ("stl", "ply"):
        assert trimesh.load(tmp_path / f"press-run.{fmt}").is_watertight
    summary = json.loads((tmp_path / "press-run_summary.json").read_text())
    assert summary["summary"] == res["summary"]
    # it prints what it wrote, one path a line
    assert str(tmp_path / "press-run.pvd") in printed and str(tmp_path / "press-run.csv") \
        in printed


@pytest.mark.parametrize("args, says", [
    (["nowhere"], "runs/nowhere: no such run folder"),
    (["{tmp}"], "no result.json"),
    (["{run}", "--out", "{file}"], "not a folder to write into"),
])
def test_bad_input_is_exit_2_naming_the_problem(run, tmp_path, capsys, args, says):
    (tmp_path / "file").write_text("")
    args = [a.format(tmp=tmp_path, run=run, file=tmp_path / "file") for a in args]
    assert main(["export", *args, "--format", "csv"]) == 2
    assert says in capsys.readouterr().err


def test_unknown_format_and_record_every_are_exit_2(run, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["export", str(run), "--format", "obj"])
    assert exc.value.code == 2 and "invalid choice: 'obj'" in capsys.readouterr().err
    assert main(["run", "cantilever", "--record-every", "0", "--out", str(tmp_path)]) == 2
    assert "--record-every: 0 is not a number of steps >= 1" in capsys.readouterr().err

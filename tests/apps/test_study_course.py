"""``q3t study --course``: the shell obstacle course's plan (elements, levels, the cases left
out by size) and its bad input; tests/apps/test_results.py runs it end to end at 2 cells."""

import pytest

from sim.apps.cli import main
from sim.apps.study_course import COURSE, benchmark, cases, chosen

pytestmark = pytest.mark.fast  # in-process, a few seconds in all


CURVED = ("scordelis_lo", "pinched_cylinder", "pinched_hemisphere")


def test_plan_takes_each_scenes_levels_and_leaves_out_the_largest():
    marks = [benchmark(n) for n in COURSE]
    assert all(m.source for m in marks)
    assert {m.name: m.levels for m in marks} == {
        **{n: [16, 32, 64] for n in CURVED}, "clamped_plate": [8, 16, 32],
        "twisted_beam_inplane": [12, 24, 48], "twisted_beam_outofplane": [12, 24, 48],
        "straight_beam_inplane": [6, 12, 24, 48], "straight_beam_outofplane": [6, 12, 24, 48]}
    plan = cases(marks, ["q3t", "quadratic"], None, {}, 60_000)
    skipped = {(c["scene"], c["element"], c["cells"]) for c in plan if c["skip"]}
    # the quadratic prism at 64 cells per side has about 150,000 DoFs; everything else is
    # below 40,000 (the beams 6 x 1 to 48 x 8 cells, the plate 8 x 8 to 32 x 32)
    assert skipped == {(n, "quadratic", 64) for n in CURVED}
    assert all("DoFs > --max-dofs 60000" in c["skip"] for c in plan if c["skip"])


def test_scenes_picks_part_of_the_course_in_its_order():
    assert chosen(None) == list(COURSE)
    assert chosen("pinched_hemisphere,scordelis_lo") == ["scordelis_lo", "pinched_hemisphere"]
    with pytest.raises(ValueError, match="--scenes: cantilever not in the course"):
        chosen("scordelis_lo,cantilever")
    assert chosen("clamped_plate,") == ["clamped_plate"]
    with pytest.raises(ValueError, match="--scenes: none given"):
        chosen(" , ")


def test_course_bad_input_names_the_option(tmp_path, capsys):
    for args, words in ((["--cells", "0"], "--cells"), (["--elements", "hexahedron"],
                                                         "hexahedron"),
                        (["--max-dofs", "0"], "--max-dofs"),
                        (["--set", "mesh.cells=-1"], "mesh.cells"),
                        (["--scenes", "cup_drawing"], "--scenes: cup_drawing")):
        assert main(["study", "--course", *args, "--out", str(tmp_path)]) == 2
        assert words in capsys.readouterr().err
    assert main(["study", "--out", str(tmp_path)]) == 2
    assert "give a scene, or --course" in capsys.readouterr().err
    assert main(["study", "scordelis_lo", "--out", str(tmp_path)]) == 2
    assert "--course" in capsys.readouterr().err

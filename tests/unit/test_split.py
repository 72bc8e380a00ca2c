"""``python -m tests.split`` (``make test``): which arguments go to which part, and the
progress line it prints while the parts run."""

import pytest

from tests.split import SERVICE, parts, progress

pytestmark = pytest.mark.fast


def test_no_path_runs_both_parts_with_the_options():
    assert parts(["-x", "-m", "not slow"]) == {
        "service": ["-x", "-m", "not slow", str(SERVICE)],
        "other tiers": ["-x", "-m", "not slow", f"--ignore={SERVICE}"]}


def test_each_path_goes_to_its_own_part_only():
    got = parts(["tests/unit/test_split.py::test_no_path_runs_both_parts_with_the_options",
                 "./tests/service/test_page_api.py", "-q"])
    assert got == {"service": ["-q", "./tests/service/test_page_api.py"],
                   "other tiers": ["-q", "tests/unit/test_split.py::"
                                   "test_no_path_runs_both_parts_with_the_options"]}
    assert parts(["tests/unit"]) == {"other tiers": ["tests/unit"]}  # run once, not twice


def test_an_options_value_is_no_path_even_when_it_names_one():
    got = parts(["--deselect", "tests/unit/test_split.py", "-k", "tests"])
    assert got["service"][:4] == ["--deselect", "tests/unit/test_split.py", "-k", "tests"]
    assert set(got) == {"service", "other tiers"}


def test_progress_is_the_last_percentage_printed(tmp_path):
    log = tmp_path / "part.log"
    log.write_text("")
    assert progress(log) == "starting"
    log.write_text("....... [  5%]\n...... [ 21%]\n...")
    assert progress(log) == "[ 21%]"

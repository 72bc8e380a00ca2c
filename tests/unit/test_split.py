"""``python -m tests.split`` (``make test``): which arguments go to which part, and the
progress line it prints while the parts run."""

import sys

import pytest

from tests import split
from tests.split import BROWSER, parts, progress

pytestmark = pytest.mark.fast


def test_the_suite_splits_into_the_browser_tests_and_the_rest():
    got = parts(["-x", "-m", "not slow"])
    assert set(got) == {"browser", "other"} and len(BROWSER) > 10
    assert got["browser"] == ["-x", "-m", "not slow", *map(str, BROWSER)]
    assert got["other"] == ["-x", "-m", "not slow", *(f"--ignore={f}" for f in BROWSER)]
    assert all("browser" in f.name for f in BROWSER)


def test_paths_given_run_as_one_part():
    args = ["./tests/service/test_page_api.py", "-q", "tests/unit::x"]
    assert parts(args) == {"selected": args}


def test_an_options_value_is_no_path_even_when_it_names_one():
    got = parts(["--deselect", "tests/unit/test_split.py", "-k", "tests"])
    assert set(got) == {"browser", "other"}
    assert got["other"][:4] == ["--deselect", "tests/unit/test_split.py", "-k", "tests"]


def test_progress_is_the_last_percentage_printed(tmp_path):
    log = tmp_path / "part.log"
    log.write_text("")
    assert progress(log) == "starting"
    log.write_text(".....")
    assert progress(log) == "+5"
    log.write_text("....... [  5%]\n...... [ 21%]")
    assert progress(log) == "[ 21%]"
    log.write_text("....... [  5%]\n...... [ 21%]\n..F")
    assert progress(log) == "[ 21%] +3"


def test_warm_runs_its_shares_side_by_side_and_fails_if_one_does(tmp_path, monkeypatch, capsys):
    # a stand-in for `q3t warm` that fails its second share, and one that never ends
    fail_2 = "import sys; sys.exit(3 if sys.argv[-1] == '2/2' else 0)"
    monkeypatch.setattr(split, "WARM_COMMAND", [sys.executable, "-c", fail_2])
    assert split.warm(tmp_path) is False
    out = capsys.readouterr().out
    assert "warm1 ok" in out and "warm2 FAILED (3)" in out
    monkeypatch.setattr(split, "WARM_COMMAND", [sys.executable, "-c", "print('compiled')"])
    assert split.warm(tmp_path) is True and "warm2 ok" in capsys.readouterr().out
    hang = "import time; time.sleep(60)"
    monkeypatch.setattr(split, "WARM_COMMAND", [sys.executable, "-c", hang])
    monkeypatch.setattr(split, "WARM_GUARD", 1.0)
    assert split.warm(tmp_path) is False  # killed at the guard, not waited for

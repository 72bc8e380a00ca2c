"""``python -m tests.split`` (``make test``): which arguments go to which part, and the
progress line it prints while the parts run."""

import signal
import subprocess
import sys

import pytest

from tests import split
from tests.split import BROWSER, COMPUTING_FIRST, ROOT, parts, progress

pytestmark = pytest.mark.fast


def test_the_suite_splits_into_two_browser_parts_and_two_computing_parts():
    got = parts(["-x", "-m", "not slow"])
    assert set(got) == {"browser-1", "browser-2", "computing-1", "computing-2"}
    assert len(BROWSER) > 10 and all("browser" in f.name for f in BROWSER)
    assert all(a[:3] == ["-x", "-m", "not slow"] for a in got.values())
    # each browser module in one browser part, half of them each
    b1, b2 = got["browser-1"][3:], got["browser-2"][3:]
    assert sorted(b1 + b2) == sorted(map(str, BROWSER)) and abs(len(b1) - len(b2)) <= 1
    # the second computing part ignores what the others run, so no test runs twice or never
    first = got["computing-1"][3:]
    assert first == [str(ROOT / d) for d in COMPUTING_FIRST]
    assert got["computing-2"][3:] == [f"--ignore={f}" for f in [*map(str, BROWSER), *first]]


def test_a_folder_or_module_ignored_leaves_the_part_that_names_it():
    # pytest ignores what it finds in a folder, not a path it is given: parts() must
    got = parts(["--ignore", "tests/verification", f"--ignore={BROWSER[0]}"])
    assert str(ROOT / "tests" / "verification") not in got["computing-1"]
    assert str(BROWSER[0]) not in got["browser-1"] + got["browser-2"]
    got = parts([f"--ignore={ROOT / 'tests' / 'service'}"])
    assert set(got) == {"computing-1", "computing-2"}  # no browser part left to run


def test_paths_given_run_as_one_part():
    args = ["./tests/service/test_page_api.py", "-q", "tests/unit::x"]
    assert parts(args) == {"selected": args}


def test_an_options_value_is_no_path_even_when_it_names_one():
    got = parts(["--deselect", "tests/unit/test_split.py", "-k", "tests"])
    assert len(got) == 4
    assert got["computing-2"][:4] == ["--deselect", "tests/unit/test_split.py", "-k", "tests"]


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
    # a stand-in for `q3t warm` that fails its second share, saying why
    fail_2 = "import sys; print('share', sys.argv[-1]); sys.exit(3 if sys.argv[-1] == '2/2' else 0)"
    monkeypatch.setattr(split, "WARM_COMMAND", [sys.executable, "-c", fail_2])
    assert split.warm(tmp_path) is False
    out = capsys.readouterr().out
    assert "warm1 ok" in out and "warm2 FAILED (exit 3)" in out and "share 2/2" in out
    monkeypatch.setattr(split, "WARM_COMMAND", [sys.executable, "-c", "print('ok, share')"])
    assert split.warm(tmp_path) is True
    out = capsys.readouterr().out
    assert "warm2 ok" in out and "ok, share" not in out  # a share's output only on failure


def test_warm_kills_a_share_at_its_guard(tmp_path, monkeypatch, capsys):
    marker = tmp_path / "finished"
    hang = f"import time, pathlib; time.sleep(30); pathlib.Path({str(marker)!r}).touch()"
    monkeypatch.setattr(split, "WARM_COMMAND", [sys.executable, "-c", hang])
    monkeypatch.setattr(split, "WARM_GUARD", 1.0)
    assert split.warm(tmp_path) is False
    assert "killed after 1 s (WARM_GUARD)" in capsys.readouterr().out
    assert not marker.exists()  # ended, not waited for


def test_end_sessions_terms_then_kills_what_ignores_it():
    code = ("import signal, sys, time; "
            "signal.signal(signal.SIGTERM, signal.SIG_IGN if sys.argv[1] == 'deaf' else "
            "signal.SIG_DFL); print('up', flush=True); time.sleep(60)")
    procs = [subprocess.Popen([sys.executable, "-c", code, kind], stdout=subprocess.PIPE,
                              start_new_session=True) for kind in ("deaf", "polite")]
    for p in procs:
        p.stdout.readline()  # its handler is set
    split.end_sessions(procs, grace=0.5)
    assert procs[0].returncode == -signal.SIGKILL and procs[1].returncode == -signal.SIGTERM

"""``python -m tests.split`` (``make test``): which arguments go to which part, and the
progress line it prints while the parts run."""

import signal
import subprocess
import sys

import pytest

from tests import split
from tests.split import BROWSER, ROOT, RUNS_BROWSER, SERVING, parts, progress

pytestmark = pytest.mark.fast


def test_the_suite_splits_into_two_browser_parts_the_service_and_the_rest():
    got = parts(["-x", "-m", "not slow"])
    assert list(got) == ["browser-page", "browser-runs", "service", "other"]
    assert all("browser" in f.name for f in BROWSER) and len(BROWSER) > 10
    page, runs = ([str(f) for f in BROWSER if (f.stem in RUNS_BROWSER) is r] for r in (False, True))
    assert len(page) > 5 and len(runs) > 5
    assert got["browser-page"] == ["-x", "-m", "not slow", *page]
    assert got["browser-runs"] == ["-x", "-m", "not slow", *runs]
    no_browser = [f"--ignore={f}" for f in BROWSER]
    assert got["service"] == ["-x", "-m", "not slow", *no_browser, *map(str, SERVING)]
    assert got["other"] == ["-x", "-m", "not slow", *no_browser,
                            *(f"--ignore={d}" for d in SERVING)]
    # every browser module in one browser part; every module named there exists
    assert {f.stem for f in BROWSER} >= RUNS_BROWSER


def test_an_ignored_module_or_folder_leaves_its_part():
    # pytest ignores what it finds in a folder, not a path it is given: parts() must
    page = [f for f in BROWSER if f.stem not in RUNS_BROWSER]
    got = parts([f"--ignore={page[0]}"])
    assert str(page[0]) not in got["browser-page"] and str(page[1]) in got["browser-page"]
    got = parts(["--ignore", str(ROOT / "tests" / "service")])
    assert list(got) == ["service", "other"]  # no browser part left to run
    assert got["service"][-1] == str(ROOT / "tests" / "apps")
    got = parts(["--ignore=tests/service", "--ignore=tests/apps"])
    assert list(got) == ["other"]


def test_paths_given_run_as_one_part():
    args = ["./tests/service/test_page_api.py", "-q", "tests/unit::x"]
    assert parts(args) == {"selected": args}


def test_an_options_value_is_no_path_even_when_it_names_one():
    got = parts(["--deselect", "tests/unit/test_split.py", "-k", "tests"])
    assert list(got) == ["browser-page", "browser-runs", "service", "other"]
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


def test_a_parts_end_says_the_cpu_its_processes_used(tmp_path, capsys):
    before = split.cpu_children()
    burn = "import time\nt = time.process_time()\nwhile time.process_time() - t < 0.3: pass"
    subprocess.run([sys.executable, "-c", burn], check=True)
    assert split.cpu_children() - before >= 0.3  # a child waited for counts
    log = tmp_path / "part.log"
    log.write_text("1 passed\n")
    split.show("other", log, 0, 600.0, 90.0)
    assert capsys.readouterr().out.endswith(
        "===== other: passed after 10.0 min, 1.5 min of CPU =====\n")


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

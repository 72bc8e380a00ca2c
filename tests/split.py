"""The whole suite as two pytest processes side by side (``make test``, what CI runs).

``python -m tests.split [pytest options] [paths]``: four pytest processes side by side, each
with its own temporary folder: the browser tests (tests/service's ``test_*browser*.py``, which
mostly wait on servers, solver processes and pages) in two, those of the page's forms and files
and those that show, compare and export runs; the service's and the command line's other tests
(tests/service, tests/apps: servers, solver processes and clusters started, driven and
stopped) in the third; every other test (which mostly computes) in the fourth. On a 2-core
machine they overlap: the waiting of one is another's computing time (with two parts the
machine's two cores were a third idle). Options go to every part; paths given run as one part,
as asked. Each part's
output goes to a log (its path printed first) and is printed whole once the part ends, so the
parts never interleave; every minute a line gives each running part's progress. Exits 0 only
if every part run passes; a part that collects no test (pytest's 5) fails only if all do.

The whole suite starts with ``q3t warm`` in two processes, each compiling half of the
solver's numba kernels: otherwise each part compiles the kernels it meets first, both the same
ones at once (numba holds no lock), and the computing part pays for all of them in turn.

Not pytest-xdist: one of its workers died mid-module here ("node down: Not properly
terminated") with no trace, and the replacement then stalled the session; two plain pytest
processes have no channel between them to lose.
"""

from __future__ import annotations

import contextlib
import os
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterable
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SERVICE = ROOT / "tests" / "service"
# the page driven in chromium: mostly waiting on servers, solver processes and pages
BROWSER = sorted(SERVICE.glob("test_*browser*.py"))
# the browser modules that show, compare and export runs (the rest drive the page's forms and
# files): the two browser parts take about as long as each other
RUNS_BROWSER = {"test_compare3d_browser", "test_compare_browser", "test_exports_browser",
                "test_runs_table_browser", "test_runs_units_browser", "test_trust_browser",
                "test_viewer_browser", "test_views_browser"}
# the service and the command line, apart from the page
SERVING = (SERVICE, ROOT / "tests" / "apps")
# a line per minute: CI shows the suite alive (and where) while the logs wait for their part
HEARTBEAT = 60.0
# processes of `q3t warm`, one per core (sim/apps/warm.py), and how long they may take (a
# hang guard: a cold compile of every kernel takes minutes on a loaded machine)
WARM, WARM_GUARD = 2, 1800.0
WARM_COMMAND = [sys.executable, "-m", "sim.apps", "warm"]
# pytest options whose value is the next argument (so that value is no path to sort)
VALUED = {"-k", "-m", "-p", "-o", "-W", "-c", "--deselect", "--ignore", "--ignore-glob",
          "--durations", "--rootdir", "--confcutdir", "--maxfail", "--tb"}


def parts(args: list[str]) -> dict[str, list[str]]:
    """Each part's pytest arguments: the options for both. Paths given: one part, as asked."""
    options, paths, value = [], [], False
    for a in args:
        if value or a.startswith("-") or not Path(a.split("::")[0]).exists():
            options.append(a)
            value = not value and a in VALUED
        else:
            paths.append(a)
    if paths:
        return {"selected": args}
    # pytest applies --ignore to what it finds in a folder, not to a path it is given: the
    # parts' own paths leave out what the options ignore
    ignored = [Path(a.split("=", 1)[1] if "=" in a else options[i + 1]).resolve()
               for i, a in enumerate(options) if a.split("=", 1)[0] == "--ignore"]

    def kept(paths: Iterable[Path]) -> list[str]:
        return [str(f) for f in paths if not any(f == d or d in f.parents for d in ignored)]

    no_browser = [f"--ignore={f}" for f in BROWSER]
    plan = {"browser-page": kept(f for f in BROWSER if f.stem not in RUNS_BROWSER),
            "browser-runs": kept(f for f in BROWSER if f.stem in RUNS_BROWSER),
            "service": kept(SERVING)}
    plan = {name: [*options, *(no_browser if name == "service" else ()), *paths]
            for name, paths in plan.items() if paths}
    return {**plan, "other": [*options, *no_browser, *(f"--ignore={d}" for d in SERVING)]}


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if any(a.startswith("--basetemp") for a in args):
        print("tests.split: --basetemp is its own (one per part)", file=sys.stderr)
        return 2
    tmp = Path(tempfile.mkdtemp(prefix="q3t-tests-"))
    procs: dict[str, subprocess.Popen] = {}
    logs: dict[str, Path] = {}
    codes: dict[str, int] = {}
    t0 = time.monotonic()
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # through the finally below
    plan = parts(args)
    warmed = "selected" in plan or warm(tmp)  # paths given: the kernels they need, as they go
    try:
        for i, (name, a) in enumerate(plan.items()):
            logs[name] = tmp / f"part{i}.log"
            print(f"tests.split: {name} -> {logs[name]}", flush=True)
            with open(logs[name], "wb") as out:
                # a session of its own: ending a part ends its servers and browsers too
                procs[name] = subprocess.Popen(
                    [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                     f"--basetemp={tmp / f'part{i}'}", *a],
                    cwd=ROOT, stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
        beat, cpu = t0, cpu_children()
        while len(codes) < len(procs):
            time.sleep(1.0)
            for name, p in procs.items():
                if name not in codes and p.poll() is not None:
                    codes[name] = p.returncode
                    # the parts are waited for one at a time: what the children's CPU grew
                    # by since the last is this part's, its servers', solvers' and browsers'
                    # (those it waited for)
                    now = cpu_children()
                    show(name, logs[name], p.returncode, time.monotonic() - t0, now - cpu)
                    cpu = now
            if time.monotonic() - beat >= HEARTBEAT and len(codes) < len(procs):
                beat = time.monotonic()
                running = "; ".join(f"{n} {progress(logs[n])}" for n in procs if n not in codes)
                print(f"tests.split: {(beat - t0) / 60:.0f} min: {running}", flush=True)
    finally:
        # a second signal must not cut this short and leave a part running unseen
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        running = {n: p for n, p in procs.items() if n not in codes}
        end_sessions(list(running.values()), grace=30.0)
        for name in running:
            show(name, logs[name], None, time.monotonic() - t0)
        # a passed part's files go; a failed (or stopped) part's stay with the logs: its
        # servers' logs are what says why a browser test waited out its guard
        for i, name in enumerate(procs):
            if codes.get(name) in (0, 5):
                shutil.rmtree(tmp / f"part{i}", ignore_errors=True)
            else:
                print(f"tests.split: {name}'s files kept in {tmp / f'part{i}'}", flush=True)
    if not warmed:
        print("tests.split: FAILED: q3t warm (its output is above the parts')", flush=True)
        return 1
    if codes and all(c == 5 for c in codes.values()):
        return 1
    return 0 if all(c in (0, 5) for c in codes.values()) else 1


def warm(tmp: Path) -> bool:
    """``q3t warm --part i/WARM`` side by side, with a heartbeat; each one's output printed if
    one failed; whether all succeeded (a failure fails the suite, after the parts have run)."""
    t0 = beat = time.monotonic()
    procs, logs, codes = [], [], {}
    try:
        for i in range(1, WARM + 1):
            logs.append(tmp / f"warm{i}.log")
            print(f"tests.split: q3t warm --part {i}/{WARM} -> {logs[-1]}", flush=True)
            with open(logs[-1], "wb") as out:
                procs.append(subprocess.Popen(
                    [*WARM_COMMAND, "--part", f"{i}/{WARM}"],
                    cwd=ROOT, stdout=out, stderr=subprocess.STDOUT, start_new_session=True))
        while len(codes) < len(procs) and time.monotonic() - t0 < WARM_GUARD:
            time.sleep(0.2)
            codes.update({i: p.returncode for i, p in enumerate(procs) if p.poll() is not None})
            if time.monotonic() - beat >= HEARTBEAT and len(codes) < len(procs):
                beat = time.monotonic()
                print(f"tests.split: {(beat - t0) / 60:.0f} min: compiling numba's kernels",
                      flush=True)
    finally:
        # every share ended before waiting on any; a second signal must not cut this short
        # and leave a share compiling in its own session
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        end_sessions(procs, grace=0.0)
        signal.signal(signal.SIGINT, signal.default_int_handler)
    ok = len(codes) == len(procs) and all(c == 0 for c in codes.values())
    for i, log in enumerate(logs):
        if not ok:
            sys.stdout.write(log.read_text(errors="replace"))
        end = "ok" if codes.get(i) == 0 else f"FAILED (exit {codes[i]})" if i in codes else \
            f"FAILED: killed after {WARM_GUARD:.0f} s (WARM_GUARD)"
        print(f"tests.split: {log.stem} {end}", flush=True)
    print(f"tests.split: numba's kernels compiled in {(time.monotonic() - t0) / 60:.1f} min",
          flush=True)
    return ok


def end_sessions(procs: list[subprocess.Popen], grace: float) -> None:
    """End each still running process's session (its servers and browsers too): SIGTERM to
    all and ``grace`` seconds to stop (none if 0), then SIGKILL; every one waited for."""
    running = [p for p in procs if p.poll() is None]
    if grace > 0:
        for p in running:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(p.pid, signal.SIGTERM)
        deadline = time.monotonic() + grace
        for p in running:
            with contextlib.suppress(subprocess.TimeoutExpired):
                p.wait(max(0.0, deadline - time.monotonic()))
    for p in running:
        if p.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(p.pid, signal.SIGKILL)
        p.wait()


def progress(log: Path) -> str:
    """The last percentage pytest printed in ``log`` and the tests done since ("[ 53%] +12"),
    or "starting"."""
    text = log.read_text(errors="replace")
    i = text.rfind("%]")
    done = sum(c in ".FEsxX" for c in text[text.rfind("\n") + 1:]) if "\n" in text[i:] or \
        i < 0 else 0
    if i < 0:
        return f"+{done}" if done else "starting"
    return text[text.rfind("[", 0, i):i + 2] + (f" +{done}" if done else "")


def cpu_children() -> float:
    """CPU seconds (user and system) of this process's children that have ended and been
    waited for, theirs included."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def show(name: str, log: Path, code: int | None, elapsed: float,
         cpu: float | None = None) -> None:
    """A part's whole output, then a line with its end (and the CPU it used: on a machine
    the parts share, that, not the wall time, is what a cut in the suite's time must
    lower)."""
    sys.stdout.write(f"\n===== {name} =====\n{log.read_text(errors='replace')}")
    end = "stopped before its end" if code is None else "passed" if code == 0 else \
        "collected no tests" if code == 5 else f"FAILED (pytest exit {code})"
    used = "" if cpu is None else f", {cpu / 60:.1f} min of CPU"
    print(f"===== {name}: {end} after {elapsed / 60:.1f} min{used} =====", flush=True)


if __name__ == "__main__":
    sys.exit(main())

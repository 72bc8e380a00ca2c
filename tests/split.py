"""The whole suite as two pytest processes side by side (``make test``, what CI runs).

``python -m tests.split [pytest arguments]``: ``tests/service`` (the service and its browser
tests, which mostly wait on servers, solver processes and pages) in one process, every other
tier (which mostly computes) in the other, each with its own temporary folder. On a 2-core
machine the two overlap: the waiting of one is the other's computing time. Each part's output
goes to a log and is printed whole once the part ends (the parts never interleave), with a
line every minute while they run. Exits 0 only if both parts pass; a part that collected no
test (pytest's 5) is a failure, as is a part stopped by a signal (its log printed so far).

Not pytest-xdist: one of its workers died mid-module here twice ("node down: Not properly
terminated") with no trace, and the replacement then stalled the session; two plain pytest
processes have no channel between them to lose.
"""

from __future__ import annotations

import contextlib
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SERVICE = "tests/service"
HEARTBEAT = 60.0  # s between the lines that say the parts are still running


def parts(args: list[str]) -> dict[str, list[str]]:
    """Each part's pytest arguments: ``args`` (options, or paths to keep to) for both."""
    return {"service": [*args, SERVICE], "other tiers": [*args, f"--ignore={SERVICE}"]} \
        if not any(a.startswith("tests") for a in args) else {"selected": args}


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # through the finally below
    with tempfile.TemporaryDirectory(prefix="q3t-tests-") as tmp:
        procs, logs, t0 = {}, {}, time.monotonic()
        try:
            for i, (name, a) in enumerate(parts(args).items()):
                logs[name] = Path(tmp) / f"part{i}.log"
                with open(logs[name], "wb") as out:
                    procs[name] = subprocess.Popen(
                        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                         f"--basetemp={Path(tmp) / f'part{i}'}", *a],
                        cwd=ROOT, stdout=out, stderr=subprocess.STDOUT)
            codes, beat = {}, t0
            while len(codes) < len(procs):
                time.sleep(1.0)
                for name, p in procs.items():
                    if name not in codes and p.poll() is not None:
                        codes[name] = p.returncode
                        show(name, logs[name], p.returncode, time.monotonic() - t0)
                if time.monotonic() - beat >= HEARTBEAT and len(codes) < len(procs):
                    beat = time.monotonic()
                    running = [n for n in procs if n not in codes]
                    print(f"tests.split: {', '.join(running)} running, "
                          f"{(beat - t0) / 60:.0f} min", flush=True)
        finally:
            for name, p in procs.items():
                if p.poll() is None:
                    p.terminate()
                    with contextlib.suppress(subprocess.TimeoutExpired):
                        p.wait(30)
                    p.kill()
                    p.wait()
                    show(name, logs[name], None, time.monotonic() - t0)
    return 0 if all(c == 0 for c in codes.values()) else 1


def show(name: str, log: Path, code: int | None, elapsed: float) -> None:
    """A part's whole output, then a line with its end."""
    sys.stdout.write(f"\n===== {name} =====\n{log.read_text(errors='replace')}")
    end = "stopped" if code is None else "passed" if code == 0 else \
        "collected no tests" if code == 5 else f"FAILED (pytest exit {code})"
    print(f"===== {name}: {end} after {elapsed / 60:.1f} min =====", flush=True)


if __name__ == "__main__":
    sys.exit(main())

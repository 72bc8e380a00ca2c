"""pytest beside busy processes: a test that races the clock fails here.

``python -m tests.loaded [--busy N] [pytest arguments]`` starts N processes that spin forever
(default: one per core, so the tests get about half the machine), runs pytest with the given
arguments (default: the whole suite) and stops the spinners on every way out. Exits with
pytest's code (5, no test collected, becomes 1, as in ``make test``).
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys

SPIN = "while True: pass"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tests.loaded", description=__doc__.split("\n")[0])
    ap.add_argument("--busy", type=int, default=os.cpu_count() or 2,
                    help="busy processes beside the tests (default: one per core)")
    args, pytest_args = ap.parse_known_args(argv)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # through the finally below
    spinners = [subprocess.Popen([sys.executable, "-c", SPIN]) for _ in range(args.busy)]
    print(f"tests.loaded: {args.busy} busy process(es) {[p.pid for p in spinners]}",
          file=sys.stderr, flush=True)
    try:
        rc = subprocess.call([sys.executable, "-m", "pytest", "-q", *pytest_args])
    finally:
        for p in spinners:
            p.kill()
            p.wait()
    return 1 if rc == 5 else rc


if __name__ == "__main__":
    sys.exit(main())

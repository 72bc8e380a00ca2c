"""The ``q3t`` command: run, bench, serve, play, study, check."""

from __future__ import annotations

import argparse
import sys

from sim.apps import bench, check, run, study, sweep
from sim.apps.common import BAD_INPUT


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="q3t", description=__doc__)
    sub = ap.add_subparsers(dest="cmd", required=True)
    for app in (run, bench, study, sweep, check):  # matplotlib and dask load only when run
        app.add_parser(sub)
    try:  # the service commands exist only where the service stack is installed
        from server import cli as server_cli
    except ImportError:
        server_cli = None
    if server_cli is not None:
        server_cli.add_parser(sub)
    args = ap.parse_args(argv)
    from sim.scene import SceneError

    try:
        return args.func(args)
    except SceneError as exc:  # bad input, whichever command read it: exit 2 like argparse
        print(f"q3t: {exc}", file=sys.stderr)
        return BAD_INPUT

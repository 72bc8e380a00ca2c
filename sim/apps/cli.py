"""The ``q3t`` command: run, export, bench, bifurcation, serve, play, study, springback,
splitring, check, warm."""

from __future__ import annotations

import argparse
import shlex
import sys
from importlib.metadata import entry_points

from sim.apps import (
    bench,
    bifurcation,
    check,
    export,
    meshtools,
    reference,
    run,
    splitring,
    springback,
    study,
    sweep,
    warm,
)
from sim.apps.common import BAD_INPUT

# Entry-point group of commands from other installed packages, each an ``add_parser(sub)``:
# the service's (serve, play, bench-service) come from server/ this way (pyproject.toml)
COMMANDS = "q3t.commands"


def add_plugins(sub: argparse._SubParsersAction) -> None:
    """The commands of the ``q3t.commands`` entry points whose package imports here: the
    service's exist only where the service stack is installed."""
    for ep in entry_points(group=COMMANDS):
        try:
            add_parser = ep.load()
        except ImportError:
            continue
        add_parser(sub)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="q3t", description=__doc__)
    sub = ap.add_subparsers(dest="cmd", required=True)
    # matplotlib and dask load only when run
    for app in (run, export, reference, bench, bifurcation, study, springback, splitring, sweep,
                check, meshtools, warm):
        app.add_parser(sub)
    add_plugins(sub)
    argv = sys.argv[1:] if argv is None else argv
    args = ap.parse_args(argv)
    args.command = shlex.join(["q3t", *argv])  # as typed: the stamp of a results file says it
    from sim.scene.load import SceneError

    try:
        return args.func(args)
    except SceneError as exc:  # bad input, whichever command read it: exit 2 like argparse
        print(f"q3t: {exc}", file=sys.stderr)
        return BAD_INPUT

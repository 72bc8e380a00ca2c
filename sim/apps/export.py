"""``q3t export``: a run's results as files other tools read (sim.frames.export)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sim.apps.common import BAD_INPUT, OK


def run_folder(name: str) -> Path:
    """A run folder's path, or a run's name in runs/ (where ``q3t run`` writes them)."""
    p = Path(name)
    return p if p.is_dir() or p.parent != Path() else Path("runs") / name


def export(args: argparse.Namespace) -> int:
    from sim.frames.export import ExportError
    from sim.frames.export import export as write

    try:
        written = write(run_folder(args.run), args.format, Path(args.out))
    except ExportError as exc:
        print(f"q3t: export: {exc}", file=sys.stderr)
        return BAD_INPUT
    for path in written:
        print(path)
    return OK


def add_parser(sub: argparse._SubParsersAction) -> None:
    from sim.frames.export import FORMATS

    e = sub.add_parser("export", help="write a run's results as CSV, VTU (ParaView), STL, PLY "
                       "or JSON", description="Write a run's results in a format other tools "
                       "read: " + "; ".join(f"{k}: {v}" for k, v in FORMATS.items()) + ".")
    e.add_argument("run", help="the run's folder (or its name in runs/)")
    e.add_argument("--format", required=True, choices=list(FORMATS))
    e.add_argument("--out", default=".", help="folder to write into (default: here)")
    e.set_defaults(func=export)

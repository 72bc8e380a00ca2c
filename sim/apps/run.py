"""``q3t run``: one scene headless, with a progress bar, to result.json and final.npz."""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from sim.apps import case_table
from sim.apps.common import BAD_INPUT, FAILED, OK, load, parse_sets
from sim.apps.progress import Progress, summary_text
from sim.frames import summary
from sim.stamp import Stamp, add_results_option, write_results

if TYPE_CHECKING:
    from sim.stepping.simulation import Simulation


def run(args: argparse.Namespace) -> int:
    from sim.frames import results
    from sim.model import size
    from sim.scene.load import SceneError
    from sim.stepping.simulation import Simulation

    started = Stamp.begin(args.command)
    overrides = parse_sets(args.set)
    if args.element:
        overrides["shell.element"] = args.element
    if args.record_every < 1:
        raise SceneError(f"--record-every: {args.record_every} is not a number of steps >= 1")
    if not 0 < args.max_memory < float("inf"):
        raise SceneError(f"--max-memory: {args.max_memory:g} GiB is not a positive size")
    scene = load(args.scene, overrides)  # SceneError: exit 2 (sim.apps.cli.main)
    size.check(scene, args.max_memory * 2**30)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    out = Path(args.out or f"runs/{scene.name}-{scene.shell.element}-{stamp}")
    # before the solve: a folder that cannot be made is bad input, not a failed run (made
    # only once there is something to write in it)
    there = next(a for a in (out, *out.parents) if a.exists())
    if not there.is_dir() or not os.access(there, os.W_OK | os.X_OK):
        why = "is a file" if not there.is_dir() else "cannot be written"
        raise SceneError(f"--out: {str(out)!r} cannot be made: {str(there)!r} {why}")
    try:
        sim = Simulation.from_scene(scene)
    except ValueError as exc:  # bad input the build finds (a region selecting no node, ...)
        print(f"q3t: {exc}", file=sys.stderr)
        return BAD_INPUT
    except Exception as exc:  # a failed run, not bad input: say why, with a result.json
        reason = f"build failed: {type(exc).__name__}: {exc}"
        out.mkdir(parents=True, exist_ok=True)
        results.write(out / "result.json", results.interrupted(scene.name, scene.shell.element,
                                                           reason))
        print(f"q3t: FAILED: {reason}\nwrote {out}/result.json", file=sys.stderr)
        return FAILED
    c = sim.result()["counts"]
    print(f"{scene.name}: {scene.shell.element}, {c['elements']} elements, {c['dofs']} DoFs, "
          f"solver {sim.model.built['linear_solver']}", file=sys.stderr)
    sim.save_frames(out / "frames", args.record_every)  # the time series q3t export reads
    progress = Progress(sys.stderr, sys.stderr.isatty())
    sim.run(progress=None if args.quiet else progress)
    progress.close()
    # converged as result.json says: a run whose values are not finite did not
    res = sim.write(out)
    if not res["converged"]:
        print(f"q3t: FAILED: {res['failure']['reason']} at step {res['failure']['step']}",
              file=sys.stderr)
    t = res["timing"]
    print(f"wrote {out}/result.json (solver {sim.wall:.2f} s, {t['newton_iterations']} Newton "
          "iterations)", file=sys.stderr)
    # the run's result on stdout, what it did on stderr: ``q3t run ... > summary.txt``
    if res["summary"]:
        print(("Summary of the steps done (the run failed)" if not res["converged"]
               else "Summary") + "\n" + summary_text(res["summary"]))
    if args.results:
        write_results(args.results, f"`{scene.name}`, {scene.shell.element}: one run",
                      results_body(res, overrides, sim), started)
        print(f"wrote {args.results}", file=sys.stderr)
    return OK if res["converged"] else FAILED


def results_body(res: dict, overrides: dict, sim: Simulation) -> str:
    """``--results``: the run's quantities (sim.apps.case_table), the summary's with where and
    when (step, stroke, share of the peak), each probe over the steps and the sections'
    thickness at their steps."""
    units = case_table.probe_units(sim.model.scene)
    row = case_table.row_of_result(res, overrides, sim.stroke_steps)
    keys = list(overrides)
    return "\n".join([
        "## The run", "", case_table.table([row], keys, units),
        "## Where and when", "", summary.table(res["summary"]), "",
        "## Probes over the run", "", case_table.history_table(res, units),
        case_table.sections_table(res)])


def add_parser(sub: argparse._SubParsersAction) -> None:
    from sim.model.size import DEFAULT_LIMIT

    r = sub.add_parser("run", help="run a scene headless and write result.json")
    r.add_argument("scene", help="scene name in scenes/ or a TOML path")
    r.add_argument("--element",
                   help="override shell.element (linear, q3t, q3t_ans, quadratic, quartic)")
    r.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scene value, e.g. material.nu=0.3 (repeatable)")
    r.add_argument("--out", help="output folder (default runs/<scene>-<element>-<time>)")
    r.add_argument("--quiet", action="store_true")
    r.add_argument("--record-every", type=int, default=10, metavar="N",
                   help="save the state to OUT/frames every N steps and at the end (default "
                        "%(default)s, as q3t serve records): the time series of q3t export")
    r.add_argument("--max-memory", type=float, default=DEFAULT_LIMIT / 2**30, metavar="GIB",
                   help="refuse a scene whose model would need more memory to build (GiB; "
                        "default %(default)g: half of a 24 GiB machine)")
    add_results_option(r, "forming-cup_drawing.md")
    r.set_defaults(func=run)

"""``q3t reference``: a run's answers kept as the reference, and how far a run is from them.

The answers are what a forming engineer reads of a run: every probe at every step and every
section's thickness at its steps. They are stored before an algorithm changes (a faster
Newton, another friction treatment, an adaptive step) so that the new algorithm is held to
the same forming result: ``q3t reference SCENE --out FILE`` runs the scene and writes them,
``q3t reference SCENE --check FILE`` runs it again and says how far each quantity moved.

A probe's deviation is the largest difference over the steps relative to the probe's largest
size over the run (a punch force that passes through zero has no relative error there); a
section's, the largest thickness difference relative to the largest thickness.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

from sim.apps.common import BAD_INPUT, FAILED, OK, load, parse_sets
from sim.frames import results
from sim.stamp import Stamp, add_results_option, write_results

# the bar for a faster algorithm: the same punch force at every step and the same
# thickness section within 0.5 %
TOLERANCE = 5e-3


def answers(result: dict) -> dict:
    """The answers of a result.json: ``probes`` {name: [value per step]}, ``steps`` and
    ``sections`` {name: [{step, thickness}]}."""
    steps = result["steps"]
    names = list(steps[0]["probes"]) if steps else []
    return {"steps": [s["step"] for s in steps],
            "probes": {n: [s["probes"][n] for s in steps] for n in names},
            "sections": {name: [{"step": r["step"], "thickness": r["thickness"]} for r in rows]
                         for name, rows in (result.get("sections") or {}).items()}}


def deviation(result: dict, ref: dict) -> dict[str, float]:
    """Each probe's and section's deviation of ``result`` from the stored ``ref`` (see the
    module's doc); a quantity the run does not have, or whose steps differ, is infinitely
    far."""
    new = answers(result)
    out = {}
    for name, want in ref["probes"].items():
        got = new["probes"].get(name)
        if got is None or new["steps"] != ref["steps"]:
            out[name] = float("inf")
            continue
        a, b = np.asarray(got, float), np.asarray(want, float)
        scale = float(np.abs(b).max())
        out[name] = float(np.abs(a - b).max() / scale) if scale > 0 else float(np.abs(a).max())
    for name, rows in ref["sections"].items():
        got = {r["step"]: r["thickness"] for r in new["sections"].get(name, [])}
        worst = 0.0
        for r in rows:
            if r["step"] not in got or len(got[r["step"]]) != len(r["thickness"]):
                worst = float("inf")
                break
            b = np.asarray(r["thickness"], float)
            worst = max(worst, float(np.abs(np.asarray(got[r["step"]]) - b).max() / b.max()))
        out[f"section {name}"] = worst
    return out


def _run(args: argparse.Namespace, ref: dict | None) -> tuple[dict, dict] | str:
    """The run's result and overrides, or why it was not run: a stored run of another element
    than the scene's (as the scene's default element changed) is not its answer."""
    from sim.stepping.simulation import Simulation

    overrides = parse_sets(args.set)
    if args.element:
        overrides["shell.element"] = args.element
    scene = load(args.scene, overrides)
    if ref is not None and ref.get("element", scene.shell.element) != scene.shell.element:
        return (f"{args.check} holds a run with {ref['element']}, this run would have "
                f"{scene.shell.element} (give --element {ref['element']})")
    sim = Simulation.from_scene(scene)
    sim.run()
    return sim.result(), overrides


def run(args: argparse.Namespace) -> int:
    if (args.out is None) == (args.check is None):
        print("q3t reference: give --out FILE (write) or --check FILE (compare)", file=sys.stderr)
        return BAD_INPUT
    ref = None
    if args.check is not None:  # read before the run, which may take minutes
        try:
            ref = json.loads(Path(args.check).read_text())
            ref["steps"], ref["probes"], ref["sections"]  # noqa: B018 - what deviation reads
        except (OSError, ValueError, KeyError, TypeError) as exc:
            print(f"q3t reference: --check: {args.check} is not a stored reference "
                  f"({type(exc).__name__}: {exc})", file=sys.stderr)
            return BAD_INPUT
    stamp = Stamp.begin(args.command)
    ran = _run(args, ref)
    if isinstance(ran, str):
        print(f"q3t reference: --check: {ran}", file=sys.stderr)
        return BAD_INPUT
    result, overrides = ran
    if not result["converged"]:
        print(f"q3t reference: FAILED: {result['failure']['reason']}", file=sys.stderr)
        return FAILED
    iterations = sum(s["iterations"] for s in result["steps"])
    if args.out is not None:
        ref = {"scene": result["scene"], "element": result["element"], "overrides": overrides,
               "newton_iterations": iterations, "stamp": dataclasses.asdict(stamp),
               **answers(result)}
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        results.write(Path(args.out), ref)  # strict JSON, through a temporary name
        print(f"wrote {args.out} ({len(ref['steps'])} steps, {iterations} Newton iterations)")
        return OK
    dev = deviation(result, ref)
    text = report(result, ref, dev, args.tolerance)
    print(text)
    if args.results:
        write_results(args.results, f"Time to a formed part: {result['scene']} against its "
                      "stored answers (`q3t reference --check`)", text, stamp)
        print(f"wrote {args.results}")
    return OK if max(dev.values(), default=0.0) <= args.tolerance else FAILED


def report(result: dict, ref: dict, dev: dict[str, float], tolerance: float) -> str:
    """Markdown: what the run cost (Newton iterations per step, cut-backs, wall time) and
    each quantity's deviation from the stored answers."""
    steps = result["steps"]
    its = np.array([s["iterations"] for s in steps])
    t = result["timing"]
    lines = ["| run | steps | Newton iterations | per step (mean / max) | cut-backs | "
             "solver wall time [s] |", "|---|---|---|---|---|---|",
             f"| this | {len(steps)} | {its.sum()} | {its.mean():.1f} / {its.max()} | "
             f"{sum(s['cutbacks'] for s in steps)} | {t['total']:.1f} |",
             f"| stored | {len(ref['steps'])} | {ref.get('newton_iterations')} | | | |", "",
             f"| quantity | deviation (tolerance {tolerance:g}) |", "|---|---|"]
    lines += [f"| {name} | {d:.2e}{'' if d <= tolerance else ' (beyond)'} |"
              for name, d in dev.items()]
    return "\n".join(lines)


def add_parser(sub: argparse._SubParsersAction) -> None:
    r = sub.add_parser("reference", help="keep a run's answers as the reference, or compare "
                                         "a run with them")
    r.add_argument("scene", help="scene name in scenes/ or a TOML path")
    r.add_argument("--element", help="override shell.element")
    r.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scene value (repeatable)")
    r.add_argument("--out", help="write the answers to this JSON file")
    r.add_argument("--check", help="compare the run with the answers in this JSON file")
    r.add_argument("--tolerance", type=float, default=TOLERANCE,
                   help="largest relative deviation that passes (default %(default)g)")
    add_results_option(r, "stroke.md")
    r.set_defaults(func=run)

"""``q3t study``: accuracy against cost under refinement (paper Fig. 8), the factorisation
comparison of Fig. 7 (``--factorisation``), and what building only the needed terms saves.

Every (element, edge length) pair is one case, run as a Dask task through
``sim.apps.tasks.run_tasks`` (a local cluster by default, ``--scheduler`` for an existing one).
A study measures run time, so by default one worker process with one thread (numba, OpenMP and
MKL pinned) runs one case at a time: cases running side by side on a 2-core machine would slow
each other down. Each worker first runs every element once on the coarsest level (a warm-up, not
timed), so numba's cache loading is not counted. ``report.md`` says how the cases ran.

The error of a case is that of the study's measure (``[study]`` table, sim.scene.StudySpec)
against the reference: a closed-form value (``analytic``, sim.analytic) when the scene has
one, else one numerical run (the quadratic element at ``reference_edge_length``, by default
half the finest level). Measures: the final probe (relative difference), the probe's curve
over the run or a section's profile (relative L2 or max difference on the common range).
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path

import numpy as np

from sim.apps.cases import study_case
from sim.apps.common import BAD_INPUT, FAILED, OK, parse_sets, resolve_scene
from sim.apps.factorisation import FACTOR_REPEAT, factorisation_report
from sim.apps.overhead import OVERHEAD_REPEAT, terms_overhead
from sim.apps.study_report import (
    STUDY_COLS,
    factorisation_md,
    markdown_table,
    overhead_md,
    overhead_report,
    study_md,
    write_overhead,
    write_study,
)
from sim.apps.tasks import cluster_text, run_tasks
from sim.refinement import Plan, case_sizes, element_overrides, make_plan
from sim.stamp import Stamp, add_results_option, write_results


class StudyError(RuntimeError):
    """The study cannot give errors: its reference run failed."""


def measured(r: dict, m: dict) -> float | tuple[np.ndarray, np.ndarray] | None:
    """What a case gives for measure ``m``: a float (final), or (x, y) arrays."""
    if m["measure"] == "final":
        return r.get("probes", {}).get(m["probe"], math.nan)
    if m["measure"] == "curve":
        h = r.get("history") or {}
        if m["over"] not in h or m["probe"] not in h:
            return None
        return np.asarray(h[m["over"]], float), np.asarray(h[m["probe"]], float)
    recs = (r.get("sections") or {}).get(m["section"]) or []
    if m["step"] is not None:
        recs = [s for s in recs if s["step"] == m["step"]]
    if not recs:
        return None
    return np.asarray(recs[-1]["rest_radius"], float), np.asarray(recs[-1][m["field"]], float)


def curve_error(x: np.ndarray, y: np.ndarray, xr: np.ndarray, yr: np.ndarray,
                norm: str = "l2") -> float:
    """Relative difference of curve (x, y) from the reference (xr, yr) on their common range of
    x, both interpolated (piecewise linear) onto the union of their abscissae there:
    ``l2``: sqrt(int (y - yr)^2 dx / int yr^2 dx), ``max``: max |y - yr| / max |yr|. NaN when
    an abscissa is not monotonic (a curve that folds back has no single value per x) or the
    ranges do not overlap."""
    curves = []
    for a, b in ((x, y), (xr, yr)):
        d = np.diff(a)
        if len(a) < 2 or not (np.all(d > 0) or np.all(d < 0)):
            return math.nan
        order = np.argsort(a)
        curves.append((a[order], b[order]))
    (x, y), (xr, yr) = curves
    lo, hi = max(x[0], xr[0]), min(x[-1], xr[-1])
    if not hi > lo:
        return math.nan
    grid = np.union1d(x, xr)
    grid = grid[(grid >= lo) & (grid <= hi)]
    a, b = np.interp(grid, x, y), np.interp(grid, xr, yr)
    if norm == "max":
        return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))
    return float(np.sqrt(np.trapezoid((a - b) ** 2, grid) / np.trapezoid(b * b, grid)))


def case_error(r: dict, ref: float | tuple[np.ndarray, np.ndarray], m: dict) -> float:
    """Relative error of case ``r`` against the reference's ``measured`` value ``ref``."""
    if r.get("status") != "converged":
        return math.nan
    v = measured(r, m)
    if v is None:
        return math.nan
    if m["measure"] == "final":
        return abs(v - ref) / abs(ref)
    return curve_error(*v, *ref, m["norm"])


def _finite(v: float) -> float | None:
    """None (JSON null, 'no error') for a case without one: failed, or no common range."""
    return v if math.isfinite(v) else None


def _ratio(value: float | None, ref: float) -> float | None:
    """A final value over the reference's: how far off, and on which side (stiffer below 1)."""
    if value is None or not math.isfinite(value) or ref == 0:
        return None
    return value / ref


def _case(plan: Plan, element: str, edge: float, budget: float | None) -> tuple:
    o = {**plan.overrides, **element_overrides(element), "mesh.edge_length": edge}
    warm = {**o, "mesh.edge_length": plan.levels[0]}
    return (study_case, plan.scene, o, warm, budget)


def run_study(plan: Plan, progress: Callable[[str], None] = print, workers: int = 1,
              threads: int = 1, scheduler: str | None = None, timeout: float | None = None,
              overhead: dict | None = None, budget: float | None = None) -> dict:
    """The reference run (unless analytic), then every element at every level, on Dask; rows
    carry the relative error. ``overhead``: also ``terms_overhead(**overhead)`` as the last
    task. ``budget``: seconds per case (``run_case``; the reference run has none: the study
    needs it). Raises StudyError when the reference run fails."""
    m = plan.measure
    calls, labels = [], []
    if plan.reference:
        calls.append(_case(plan, *plan.reference, None))
        labels.append({"overrides": calls[-1][2]})
    grid = [(el, edge) for el in plan.elements for edge in plan.levels]
    calls += [_case(plan, el, edge, budget) for el, edge in grid]
    labels += [{"overrides": c[2]} for c in calls[len(labels):]]
    if overhead is not None:
        calls.append((terms_overhead, plan.scene, overhead["overrides"], overhead["repeat"]))
        labels.append({})
    n_ref = 1 if plan.reference else 0

    def report(i: int, r: dict) -> None:
        if i < n_ref:
            el, edge = plan.reference
            v = measured(r, m) if r.get("status") == "converged" else None
            if v is None or (m["measure"] == "final" and not math.isfinite(v)):
                why = r.get("reason") or f"no {plan.probe} in its output"
                raise StudyError(f"reference run {el} at {edge:g} m ended {r.get('status')}: "
                                 f"{why}")
            progress(f"reference {el} h={edge:.6g}: {r['dofs']} DoFs, "
                     f"{r['build'] + r['wall']:.2f} s")
        elif i < n_ref + len(grid):
            el, edge = grid[i - n_ref]
            progress(f"{el:9s} h={edge:.6g} {r.get('dofs') or 0:7d} DoFs  {r['status']}  "
                     f"{r.get('build', 0) + r.get('wall', 0):.3f} s")
        else:
            progress("lean against all-terms timing done")

    results, finished = run_tasks(calls, labels, workers, threads, scheduler, timeout, report)
    if plan.reference:
        ref = results[0]
        ref_value = measured(ref, m)
    else:
        ref = {"analytic": plan.analytic}
        ref_value = plan.analytic["value"]
    rows = []
    for (el, edge), r in zip(grid, results[n_ref:n_ref + len(grid)], strict=True):
        final = r.get("probes", {}).get(m["probe"]) if m["measure"] != "profile" else None
        rows.append({"element": el, "edge_length": edge, "status": r["status"],
                     "elements": r.get("elements"), "dofs": r.get("dofs"), "probe": final,
                     "ratio": _ratio(final, ref_value) if m["measure"] == "final" else None,
                     "error": _finite(case_error(r, ref_value, m)),
                     "time": r.get("build", 0.0) + r.get("wall", 0.0),
                     "solve_time": r.get("wall", 0.0), "iterations": r.get("iterations"),
                     "reason": r.get("reason")})
    ref_out = {k: v for k, v in ref.items() if k not in ("history", "sections")}
    if plan.reference and m["measure"] == "final":
        ref_out["value"] = ref_value
    label = (f"{plan.analytic['name']} (analytic)" if plan.analytic else
             f"{plan.reference[0]} at edge {plan.reference[1]:.6g} m")
    where = cluster_text(workers, threads, scheduler)
    out = {"plan": asdict(plan), "reference": ref_out, "reference_label": label,
           "analytic": plan.analytic, "rows": rows, "cluster": where, "finished": finished,
           "overhead": results[-1] if overhead is not None else None}
    if overhead is not None and results[-1].get("status") in ("error", "timeout"):
        out["overhead"] = None
        out["overhead_failed"] = results[-1].get("reason")
    return out


def _inputs(args: argparse.Namespace) -> tuple[str, Plan]:
    """The plan from the command line; ValueError / SceneError on bad input."""
    scene = str(resolve_scene(args.scene))
    ref = None
    if args.reference:
        el, _, edge = args.reference.partition(":")
        if not edge:
            raise ValueError("--reference needs ELEMENT:EDGE, e.g. quadratic:0.0035")
        ref = (el, float(edge))
    for name in ("workers", "threads"):
        if getattr(args, name) < 1:
            raise ValueError(f"--{name} must be at least 1")
    for name in ("timeout", "budget"):
        if getattr(args, name) is not None and getattr(args, name) <= 0:
            raise ValueError(f"--{name} must be positive (seconds)")
    if args.repeat is not None and args.repeat < 1:
        raise ValueError("--repeat must be at least 1")
    study = {k: v for k, v in (("probe", args.probe), ("measure", args.measure),
                               ("analytic", args.analytic)) if v}
    plan = make_plan(scene, args.elements and args.elements.split(","),
                     args.levels and [float(v) for v in args.levels.split(",")], ref,
                     parse_sets(args.set), study)
    return scene, plan


def _factorisation(args: argparse.Namespace, scene: str, plan: Plan, out: Path,
                   kw: dict) -> tuple[str, str]:
    rows = factorisation_report(scene, plan.elements, plan.levels, out,
                                args.repeat or FACTOR_REPEAT, plan.overrides, **kw)
    return (f"Factorisation time against elements: {Path(scene).stem} (paper Fig. 7)",
            factorisation_md(rows, cluster_text(**_where(kw))))


def _overhead(args: argparse.Namespace, scene: str, plan: Plan, out: Path,
              kw: dict) -> tuple[str, str] | None:
    o = {"overrides": {**plan.overrides, "mesh.edge_length": plan.levels[-1]},
         "repeat": args.repeat or OVERHEAD_REPEAT}
    rows, _ = run_tasks([(terms_overhead, scene, o["overrides"], o["repeat"])], [{}], **kw)
    if "lean" not in rows[0]:
        print(f"q3t study: the timing run ended {rows[0]['status']}: {rows[0]['reason']}",
              file=sys.stderr)
        return None
    where = cluster_text(**_where(kw))
    write_overhead(rows, out, where)
    print(overhead_md(rows))
    return (f"What leaving unused terms out saves: {Path(scene).stem}",
            overhead_report(rows, where))


def _study(args: argparse.Namespace, scene: str, plan: Plan, out: Path,
           kw: dict) -> tuple[str, str] | None:
    overhead = None if args.no_overhead else {
        "overrides": {**plan.overrides, "mesh.edge_length": plan.levels[len(plan.levels) // 2]},
        "repeat": args.repeat or OVERHEAD_REPEAT}
    try:
        study = run_study(plan, lambda s: print(s, file=sys.stderr, flush=True),
                          overhead=overhead, budget=args.budget, **kw)
    except StudyError as exc:
        print(f"q3t study: {exc}", file=sys.stderr)
        return None
    overheads = [study["overhead"]] if study["overhead"] else []
    study["changes"] = list(args.changes)
    write_study(study, overheads, out, args.workers, args.scheduler)
    print(markdown_table(study["rows"], STUDY_COLS)
          + (overhead_md(overheads) if overheads else ""))
    return (f"Refinement study: {Path(scene).stem}",
            study_md(study, overheads, args.workers, args.scheduler))


def _print_plan(plan: Plan) -> int:
    """``--plan``: the cases and their sizes, nothing run."""
    from sim.scene.load import SceneError

    try:
        rows = case_sizes(plan)
    except (SceneError, ValueError) as exc:
        print(f"q3t study: {exc}", file=sys.stderr)
        return BAD_INPUT
    print(f"Study of {Path(plan.scene).stem}: {plan.probe}, "
          + (f"against {plan.analytic['name']}" if plan.analytic else
             f"reference {plan.reference[0]} at {plan.reference[1]:.6g} m") + "\n")
    table = [{**r, "case": ("reference " if r["reference"] else "") + r["element"],
              "gib": r["bytes"] / 2**30} for r in rows]
    print(markdown_table(table, [("case", "case", ""), ("edge_length", "edge [m]", ".6g"),
                                 ("dofs", "DoFs", ","), ("gib", "memory [GiB]", ".2f")]))
    for note in plan.notes:
        print(f"- {note}")
    return OK


def _where(kw: dict) -> dict:
    return {k: kw[k] for k in ("workers", "threads", "scheduler")}


def run(args: argparse.Namespace) -> int:
    """Exit 0 on success, 1 when the reference run failed (no errors to give), 2 on bad input
    (as ``q3t run``: 1 = a run failed, 2 = bad input)."""
    from sim.scene.load import SceneError

    stamp = Stamp.begin(args.command)
    if args.course:
        from sim.apps import study_course

        return study_course.run(args, stamp)
    try:
        if args.scene is None:
            raise ValueError("give a scene, or --course")
        scene, plan = _inputs(args)
    except (SceneError, ValueError) as exc:
        print(f"q3t study: {exc}", file=sys.stderr)
        return BAD_INPUT
    out = Path(args.out or f"runs/study-{Path(scene).stem}")
    kw = {"workers": args.workers, "threads": args.threads, "scheduler": args.scheduler,
          "timeout": args.timeout}
    if args.plan:
        return _print_plan(plan)
    mode = _factorisation if args.factorisation else (
        _overhead if args.overhead_only else _study)
    made = mode(args, scene, plan, out, kw)
    if made is None:
        return FAILED
    print(f"wrote {out}/report.md, report.json and plots")
    if args.results:
        write_results(args.results, *made, stamp)
        print(f"wrote {args.results}")
    return OK


def add_parser(sub: argparse._SubParsersAction) -> None:
    s = sub.add_parser("study", help="error against run time and DoFs under refinement")
    s.add_argument("scene", nargs="?", help="scene name in scenes/ or a TOML path")
    s.add_argument("--course", action="store_true",
                   help="the shell obstacle course (sim.apps.study_course): its scenes, every "
                        "routine element (or --elements), their published references")
    s.add_argument("--cells", help="--course: cells per side (along a strip), comma-separated "
                                   "(default: each scene's study.cells)")
    s.add_argument("--scenes", help="--course: some of its scenes, comma-separated (default: "
                                    "all of them)")
    s.add_argument("--max-dofs", type=int, default=60_000,
                   help="--course: leave out cases above this many DoFs (default 60000)")
    s.add_argument("--elements", help="comma-separated (default: the scene's study table)")
    s.add_argument("--levels", help="comma-separated mesh edge lengths in m")
    s.add_argument("--reference", metavar="ELEMENT:EDGE",
                   help="a numerical reference run, e.g. quadratic:0.0035")
    s.add_argument("--analytic", help="closed-form reference: euler_bernoulli, springback, fibre")
    s.add_argument("--probe", help="the probe to measure (study.probe)")
    s.add_argument("--measure", choices=["final", "curve", "profile"],
                   help="study.measure: the final value, the curve over the run, a profile")
    s.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="a scene override for every case, e.g. material.nu=0 (repeatable)")
    s.add_argument("--changes", action="append", default=[], metavar="TEXT",
                   help="what the studied scene changed of the saved one, in words (the "
                        "service's study of a run's edits); kept in the report, where a run's "
                        "error estimate compares it with what the run changed")
    s.add_argument("--plan", action="store_true",
                   help="print the cases with their DoFs and memory, and run nothing")
    s.add_argument("--factorisation", action="store_true",
                   help="time the Hessian factorisation instead (paper Fig. 7)")
    s.add_argument("--repeat", type=int, default=None,
                   help=f"factorisations per case (default {FACTOR_REPEAT}) or interleaved "
                        f"lean/all-terms runs (default {OVERHEAD_REPEAT})")
    s.add_argument("--no-overhead", action="store_true",
                   help="skip the lean-against-all-terms timing")
    s.add_argument("--overhead-only", action="store_true",
                   help="only the lean-against-all-terms timing, at the finest level")
    s.add_argument("--workers", type=int, default=1,
                   help="local Dask workers (default 1: cases side by side skew timings)")
    s.add_argument("--threads", type=int, default=1,
                   help="numba/OpenMP/MKL threads of each local worker (default 1)")
    s.add_argument("--scheduler", help="address of an existing Dask scheduler")
    s.add_argument("--timeout", type=float, default=None,
                   help="seconds for the whole study; unfinished cases are marked timeout")
    s.add_argument("--budget", type=float, default=None,
                   help="seconds per case (not the reference run), checked after each step: "
                        "a case over it stops there, marked timeout, and the study goes on")
    s.add_argument("--out", help="output folder (default runs/study-<scene>)")
    add_results_option(s, "fig8-convergence.md")
    s.set_defaults(func=run)

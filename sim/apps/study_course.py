"""``q3t study --course``: the classical shell obstacle course (MacNeal and Harder 1985) for
every element: each benchmark scene at each level of cells per side, its probe against the
published value the scene gives (``[study] published``), and the run time.

The course is the scenes in ``COURSE``; each states its levels (``study.cells``), probe and
published value. The elements are the registry's routine ones unless ``--elements`` names
others, so a newly registered element runs with no change here. A case whose model would have
more than ``--max-dofs`` degrees of freedom is left out (said in the table): the finest levels
of the higher-order elements cost minutes and add nothing the coarser levels do not show.
Cases run as ``q3t study``'s do (one worker, one thread, a warm-up per element first).
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from sim.apps.study_report import markdown_table

if TYPE_CHECKING:
    from sim.stamp import Stamp

COURSE = ("scordelis_lo", "pinched_cylinder", "pinched_hemisphere", "clamped_plate",
          "twisted_beam_inplane", "twisted_beam_outofplane", "straight_beam_inplane",
          "straight_beam_outofplane")
# linear and Q3T to 64 cells per side (about 38,000 DoFs), the quadratic prism to 32 (about
# 37,000; at 64 it would have about 150,000)
MAX_DOFS = 60_000


@dataclass(frozen=True)
class Benchmark:
    name: str
    path: str
    probe: str
    value: float  # published
    source: str
    levels: list[int]  # cells per side


def benchmark(name: str, overrides: dict | None = None) -> Benchmark:
    """A course scene's study: ValueError naming what it lacks."""
    from sim.apps.common import resolve_scene
    from sim.scene.load import load_scene

    path = str(resolve_scene(name))
    st = load_scene(path, overrides).study
    if st is None or st.published is None or not st.cells:
        raise ValueError(f"{name}: a course scene needs [study] with cells and published")
    return Benchmark(name, path, st.probe, st.published.value, st.published.source,
                     list(st.cells))


def cases(marks: list[Benchmark], elements: list[str], cells: list[int] | None,
          overrides: dict, max_dofs: int) -> list[dict]:
    """Every (benchmark, element, level) as ``{scene, element, cells, overrides, skip}``;
    ``skip`` says why a case does not run (its size, from the mesh parameters alone)."""
    from sim.model.size import estimate
    from sim.refinement import element_overrides
    from sim.scene.load import load_scene

    out = []
    for b in marks:
        for el in elements:
            for n in cells or b.levels:
                o = {**overrides, **element_overrides(el), "mesh.cells": n}
                dofs = estimate(load_scene(b.path, o)).dofs
                skip = f"{dofs} DoFs > --max-dofs {max_dofs}" if dofs > max_dofs else None
                out.append({"scene": b.name, "element": el, "cells": n, "overrides": o,
                            "path": b.path, "skip": skip})
    return out


def run_course(marks: list[Benchmark], plan: list[dict], progress: Callable[[str], None],
               workers: int = 1,
               threads: int = 1, scheduler: str | None = None, timeout: float | None = None,
               budget: float | None = None) -> list[dict]:
    """Run the cases of ``plan`` that are not skipped; a row per case of the plan."""
    from sim.apps.cases import study_case
    from sim.apps.tasks import run_tasks

    todo = [c for c in plan if c["skip"] is None]
    calls = []
    for c in todo:  # the warm-up: the element on its scene's coarsest level
        warm = {**c["overrides"], "mesh.cells": min(x["cells"] for x in todo
                                                     if x["scene"] == c["scene"])}
        calls.append((study_case, c["path"], c["overrides"], warm, budget))

    def report(i: int, r: dict) -> None:
        c = todo[i]
        progress(f"{c['scene']:18s} {c['element']:9s} {c['cells']:4d} cells "
                 f"{r.get('dofs') or 0:7d} DoFs  {r['status']}  "
                 f"{r.get('build', 0) + r.get('wall', 0):.2f} s")

    results = run_tasks(calls, [{} for _ in calls], workers, threads, scheduler, timeout,
                        report)[0] if calls else []
    done = {id(c): r for c, r in zip(todo, results, strict=True)}
    by_name = {b.name: b for b in marks}
    return [_row(c, done.get(id(c)), by_name[c["scene"]]) for c in plan]


def _row(c: dict, r: dict | None, b: Benchmark) -> dict:
    row = {k: c[k] for k in ("scene", "element", "cells")}
    if r is None:
        return {**row, "status": "skipped", "reason": c["skip"]}
    value = r.get("probes", {}).get(b.probe)
    ok = r.get("status") == "converged" and value is not None and math.isfinite(value)
    return {**row, "status": r.get("status"), "reason": r.get("reason"),
            "triangles": r.get("elements"), "dofs": r.get("dofs"), "probe": value,
            "ratio": value / b.value if ok else None,
            "time": r.get("build", 0.0) + r.get("wall", 0.0), "solve_time": r.get("wall")}


def course_md(marks: list[Benchmark], rows: list[dict]) -> str:
    """The ratio to the published value per benchmark, element and level, run times beside;
    then every case, and the sources."""
    levels = sorted({r["cells"] for r in rows})
    cols = [("scene", "benchmark", ""), ("element", "element", "")]
    table = []
    for b in marks:
        for el in dict.fromkeys(r["element"] for r in rows if r["scene"] == b.name):
            line = {"scene": b.name, "element": el}
            for r in rows:
                if r["scene"] == b.name and r["element"] == el:
                    line[f"r{r['cells']}"] = _cell(r)
                    line[f"t{r['cells']}"] = r.get("time")
            table.append(line)
    cols += [(f"r{n}", f"{n} cells", "") for n in levels]
    cols += [(f"t{n}", f"time {n} [s]", ".2f") for n in levels]
    detail = [("scene", "benchmark", ""), ("element", "element", ""), ("cells", "cells", "d"),
              ("triangles", "triangles", "d"), ("dofs", "DoFs", "d"),
              ("probe", "probe", ".6g"), ("ratio", "probe / published", ".4f"),
              ("time", "time [s]", ".3f"), ("status", "status", ""), ("reason", "note", "")]
    sources = "\n".join(f"- {b.name}: published {b.value:g} ({b.probe}); {b.source}"
                        for b in marks)
    return ("Ratio of each benchmark's probe to its published value (1 is exact; below 1 "
            "stiffer) per element and cells per side (along the length of a strip: the beams), "
            "and the run time of each case (build and solve, one thread):\n\n"
            + markdown_table(table, cols)
            + "\nEvery case:\n\n" + markdown_table(rows, detail)
            + "\nPublished values:\n\n" + sources + "\n")


def _cell(r: dict) -> str:
    if r.get("ratio") is not None:
        return f"{r['ratio']:.3f}"
    return "-" if r["status"] == "skipped" else r["status"]


def write_course(rows: list[dict], out: Path, md: str) -> None:
    import json

    out.mkdir(parents=True, exist_ok=True)
    (out / "report.json").write_text(json.dumps(rows, indent=1, default=str))
    (out / "report.md").write_text(md)


def chosen(scenes: str | None) -> list[str]:
    """The course's scenes ``--scenes`` names (all of them when None), in the course's order;
    ValueError naming one that is not in it."""
    if scenes is None:
        return list(COURSE)
    names = [n.strip() for n in scenes.split(",") if n.strip()]
    if not names:
        raise ValueError(f"--scenes: none given (the course: {', '.join(COURSE)})")
    unknown = [n for n in names if n not in COURSE]
    if unknown:
        raise ValueError(f"--scenes: {', '.join(unknown)} not in the course "
                         f"({', '.join(COURSE)})")
    return [n for n in COURSE if n in names]


def run(args: argparse.Namespace, stamp: Stamp) -> int:
    """``q3t study --course``; exit codes as ``q3t study``'s."""
    import sys

    from sim.apps.common import BAD_INPUT, OK, parse_sets
    from sim.apps.tasks import cluster_text
    from sim.elements import ROUTINE
    from sim.scene.load import SceneError
    from sim.stamp import write_results

    try:
        if args.max_dofs < 1:
            raise ValueError("--max-dofs must be at least 1")
        cells = [int(v) for v in args.cells.split(",")] if args.cells else None
        if cells is not None and min(cells) < 1:
            raise ValueError("--cells: cells per side must be at least 1")
        overrides = parse_sets(args.set)
        marks = [benchmark(n, overrides) for n in chosen(args.scenes)]
        elements = args.elements.split(",") if args.elements else list(ROUTINE)
        plan = cases(marks, elements, cells, overrides, args.max_dofs)
    except (SceneError, ValueError) as exc:
        print(f"q3t study: {exc}", file=sys.stderr)
        return BAD_INPUT
    rows = run_course(marks, plan, lambda s: print(s, file=sys.stderr, flush=True),
                      args.workers, args.threads, args.scheduler, args.timeout, args.budget)
    md = course_md(marks, rows) + "\n" + (
        f"Cases ran as Dask tasks on {cluster_text(args.workers, args.threads, args.scheduler)};"
        " each worker ran each element once on the coarsest level first (warm-up, not timed).\n")
    out = Path(args.out or "runs/study-course")
    write_course(rows, out, md)
    print(md)
    print(f"wrote {out}/report.md and report.json")
    if args.results:
        write_results(args.results, "The shell obstacle course", md, stamp)
        print(f"wrote {args.results}")
    return OK

"""``q3t sweep``: the cartesian product of scene overrides, one Dask task per case.

Each task runs one case, writes its folder ``cases/NNN`` (result.json, final.npz, scene.toml,
case.json: the service opens it as a run to compare, server/sweeps.py) and returns a small dict
(``run_case``): a case whose scene is invalid or whose solver fails is a row of the table,
never the end of the sweep. By default a
``LocalCluster`` of single-threaded worker processes runs the cases; ``--scheduler`` sends them
to an existing cluster instead (its workers need this package).

A case whose scene does not validate is an ``invalid`` row before anything starts, so no
clock runs for it. Two clocks bound the others. Each case runs in a child process of its
worker (``sim.apps.cases.run_isolated``) that is killed after ``--budget`` seconds (status
``timeout``), so one hung case costs its budget and the worker moves on. ``--timeout`` bounds
the whole sweep: cases not finished by then are cancelled and marked ``timeout``. Results are
gathered as they finish and ``sweep.json`` is rewritten after each one, so whatever finished is
always on disk.
"""

from __future__ import annotations

import argparse
import itertools
import multiprocessing as mp
import sys
import time
from collections.abc import Callable
from pathlib import Path

from sim.apps import case_table
from sim.apps.cases import WatchedContext, run_case, run_isolated, scene_row
from sim.apps.common import BAD_INPUT, FAILED, OK, parse_sets, resolve_scene
from sim.apps.tasks import cluster_text, run_tasks
from sim.frames import results
from sim.stamp import Stamp, add_results_option, write_results

DEFAULT_BUDGET = 600.0  # s per case: the slowest shipped scene at its default size takes ~60 s


def isolated_case(scene_path: str, overrides: dict, budget: float,
                  out_dir: str | None = None) -> dict:
    """``run_case`` in a child process killed after ``budget`` s (runs on a Dask worker);
    ``out_dir``: the case's folder (``sim.apps.cases.write_case``).

    A daemonic worker (an external cluster's default) may not start children: the case then
    runs in the worker itself, without a budget, and the row says so."""
    if mp.current_process().daemon:
        out = run_case(scene_path, overrides, out_dir=out_dir)
        out["budget"] = ("none: daemonic Dask worker (start it with "
                         "DASK_DISTRIBUTED__WORKER__DAEMON=False)")
        return out
    out = run_isolated(scene_path, overrides, budget, WatchedContext(), out_dir)
    out.setdefault("overrides", dict(overrides))
    out["budget"] = budget
    return out


def split_values(text: str) -> list[str]:
    """Split ``v1,v2,...`` at top-level commas, so ``[0,0,-9.81],[0,0,-1]`` is two values."""
    items, depth, cur = [], 0, ""
    for ch in text:
        depth += (ch in "[{") - (ch in "]}")
        if ch == "," and depth == 0:
            items.append(cur)
            cur = ""
        else:
            cur += ch
    items.append(cur)
    return [s.strip() for s in items if s.strip()]


def parse_grid(items: list[str]) -> dict[str, list]:
    """``["key=v1,v2", ...]`` -> ``{key: [v1, v2]}`` with values parsed as TOML."""
    from sim.scene.load import parse_value

    grid: dict[str, list] = {}
    for it in items:
        if "=" not in it:
            raise ValueError(f"--grid needs key.path=v1,v2,..., got {it!r}")
        key, vals = it.split("=", 1)
        grid[key.strip()] = [parse_value(v) for v in split_values(vals)]
        if not grid[key.strip()]:
            raise ValueError(f"--grid {key}: no values")
    return grid


def cases(grid: dict[str, list], fixed: dict | None = None) -> list[dict]:
    """Every combination of the grid's values, each merged over ``fixed``."""
    keys = list(grid)
    return [{**(fixed or {}), **dict(zip(keys, combo, strict=True))}
            for combo in itertools.product(*(grid[k] for k in keys))]


def run_sweep(scene_path: str, overrides: list[dict], workers: int = 2,
              scheduler: str | None = None, timeout: float | None = None,
              budget: float = DEFAULT_BUDGET,
              on_result: Callable[[int, dict], None] | None = None,
              out: Path | None = None) -> tuple[list[dict], bool]:
    """Every case with a valid scene through ``isolated_case`` (see ``run_tasks``); the others
    are ``invalid`` rows at once (``scene_row``), and never reach the cluster. ``out``: case
    ``i`` writes its folder ``out/case_folder(i)`` (its row's ``folder``), which the service
    opens as a run."""
    rows = [scene_row(scene_path, o) for o in overrides]
    todo = [i for i, r in enumerate(rows) if r is None]
    for i, r in enumerate(rows):
        if r is not None and on_result:
            on_result(i, r)
    if not todo:
        return rows, True
    done, finished = run_tasks(
        [(isolated_case, scene_path, overrides[i], budget,
          None if out is None else str(out.resolve() / case_folder(i))) for i in todo],
        [{"overrides": overrides[i]} for i in todo], workers, 1, scheduler, timeout,
        on_result and (lambda k, row: on_result(todo[k], _placed(row, todo[k], out))))
    for k, i in enumerate(todo):
        rows[i] = _placed(done[k], i, out)
    return rows, finished


def case_folder(i: int) -> str:
    return f"cases/{i:03d}"


def _placed(row: dict, i: int, out: Path | None) -> dict:
    """The row with its case folder (relative to the sweep's), once the case has written it."""
    if out is not None and (out / case_folder(i) / "case.json").is_file():
        row["folder"] = case_folder(i)
    return row


def table(rows: list[dict], grid_keys: list[str]) -> str:
    """Markdown: one line per case with its grid values, status, probes, time and DoFs."""
    probes = sorted({k for r in rows for k in r.get("probes", {})})
    head = [*grid_keys, "status", *probes, "wall [s]", "DoFs", "reason"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [str(r["overrides"].get(k)) for k in grid_keys] + [r["status"]]
        cells += [f"{r['probes'][p]:.6g}" if p in r.get("probes", {}) else "" for p in probes]
        cells += [f"{r.get('wall', 0.0):.3f}", str(r.get("dofs") or ""),
                  (r.get("reason") or "").replace("|", "/")[:120]]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], grid_keys: list[str], probe: str, out: Path) -> list[Path]:
    """``probe`` against the first grid key, one line per combination of the others; failed
    cases are left out of the lines and marked on the axis."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x_key, rest = grid_keys[0], grid_keys[1:]
    fig, (ax, at) = plt.subplots(1, 2, figsize=(10, 4))
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault(tuple(str(r["overrides"].get(k)) for k in rest), []).append(r)
    for label, rs in groups.items():
        ok = [r for r in rs if r["status"] == "converged" and probe in r["probes"]]
        xs = [_as_x(r["overrides"][x_key]) for r in ok]
        name = ", ".join(f"{k}={v}" for k, v in zip(rest, label, strict=True)) or probe
        ax.plot(xs, [r["probes"][probe] for r in ok], "o-", label=name)
        at.plot(xs, [r["wall"] for r in ok], "o-", label=name)
        bad = [_as_x(r["overrides"][x_key]) for r in rs if r["status"] != "converged"]
        ax.plot(bad, [0.0] * len(bad), "rx", ms=10)
    ax.set(xlabel=x_key, ylabel=probe, title=f"{probe} (x: not converged)")
    at.set(xlabel=x_key, ylabel="wall time [s]", title="run time")
    ax.legend(fontsize=7)
    fig.tight_layout()
    paths = [out / "sweep.png", out / "sweep.svg"]
    for p in paths:
        fig.savefig(p)
    plt.close(fig)
    return paths


def _as_x(v: object) -> float | str:
    return v if isinstance(v, (int, float)) else str(v)


def _write(out: Path, name: str, data: dict) -> None:
    """Through a temporary name: an interrupted sweep never leaves half a file."""
    tmp = out / f"{name}.tmp"
    tmp.write_text(results.dumps(data, nulls=True, indent=1))
    tmp.replace(out / name)


def check_ratios(scene: str, fixed: dict, ratios: list[str]) -> None:
    """``--ratio`` names probes of the scene (ValueError otherwise), checked before any case
    runs."""
    from sim.scene.load import load_scene

    if ratios:
        names = [p.name for p in load_scene(scene, fixed).probes]
        for r in ratios:
            if r not in names:
                raise ValueError(f"--ratio {r}: the scene has no probe {r!r} "
                                 f"(it has {', '.join(names)})")


def results_body(scene: str, fixed: dict, rows: list[dict], keys: list[str],
                 ratios: list[str]) -> str:
    """The ``--results`` table (sim.apps.case_table): a column per case, the scene's probes in
    the units their kinds have."""
    from sim.scene.load import load_scene

    try:
        units = case_table.probe_units(load_scene(scene, fixed))
    except ValueError:  # every case is an invalid row then: the names its rows have, no unit
        units = {p: "" for r in rows for p in r.get("probes", {})}
    return case_table.table(rows, keys, units, ratios)


def run(args: argparse.Namespace) -> int:
    """Exit 0 when every case has a row of its own; 1 when ``--timeout`` cut the sweep short
    (the rows that finished are still written); 2 on bad input."""
    stamp = Stamp.begin(args.command)
    scene = str(resolve_scene(args.scene))
    try:
        grid = parse_grid(args.grid)
        if args.budget <= 0 or (args.timeout is not None and args.timeout <= 0):
            raise ValueError("--budget and --timeout must be positive (seconds)")
        if args.workers < 1:
            raise ValueError("--workers must be at least 1")
        fixed = parse_sets(args.set)
        check_ratios(scene, fixed, args.ratio)
    except ValueError as exc:
        print(f"q3t sweep: {exc}", file=sys.stderr)
        return BAD_INPUT
    todo = cases(grid, fixed)
    where = cluster_text(args.workers, 1, args.scheduler)
    print(f"sweep {scene}: {len(todo)} cases on {where}", file=sys.stderr)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    head = {"scene": scene, "grid": grid, "fixed": fixed, "workers": args.workers,
            "scheduler": args.scheduler, "budget": args.budget, "timeout": args.timeout}
    done: dict[int, dict] = {}
    t0 = time.perf_counter()

    def partial(i: int, row: dict) -> None:
        done[i] = row
        print(f"case {i + 1}/{len(todo)}: {row['status']}", file=sys.stderr, flush=True)
        _write(out, "sweep.json", {**head, "complete": False, "wall": time.perf_counter() - t0,
                                   "cases": [done[k] for k in sorted(done)]})

    rows, finished = run_sweep(scene, todo, args.workers, args.scheduler, args.timeout,
                               args.budget, partial, out)
    wall = time.perf_counter() - t0
    keys = list(grid)
    md = table(rows, keys)
    note = "" if finished else (f" The sweep's --timeout of {args.timeout:g} s ended it: "
                                "unfinished cases are marked timeout.")
    (out / "sweep.md").write_text(f"# Sweep of {scene}\n\n{len(rows)} cases in {wall:.1f} s on "
                                  f"{where}; budget {args.budget:g} s per case.{note}\n\n" + md)
    _write(out, "sweep.json", {**head, "complete": finished, "wall": wall, "cases": rows})
    probe = args.probe or next((p for r in rows for p in r.get("probes", {})), None)
    if probe:
        plot(rows, keys, probe, out)
    if args.results:
        write_results(args.results, f"`{Path(scene).stem}` over {', '.join(keys)}",
                      results_body(scene, fixed, rows, keys, args.ratio)
                      + f"\n{len(rows)} cases on {where}.{note}\n", stamp)
        print(f"wrote {args.results}")
    print(md + f"wrote {out}/sweep.json, sweep.md ({wall:.1f} s)")
    if not finished:
        print(f"q3t sweep: --timeout {args.timeout:g} s reached; "
              f"{sum(r['status'] == 'timeout' for r in rows)} case(s) unfinished",
              file=sys.stderr)
    return OK if finished else FAILED


def add_parser(sub: argparse._SubParsersAction) -> None:
    s = sub.add_parser("sweep", help="run the cartesian product of overrides on Dask")
    s.add_argument("scene", help="scene name in scenes/ or a TOML path")
    s.add_argument("--grid", action="append", required=True, metavar="KEY=V1,V2",
                   help="values of one scene key (repeatable; the product is swept)")
    s.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="an override for every case (repeatable)")
    s.add_argument("--workers", type=int, default=2, help="local single-threaded workers")
    s.add_argument("--scheduler", help="address of an existing Dask scheduler")
    s.add_argument("--budget", type=float, default=DEFAULT_BUDGET,
                   help="wall-clock seconds per case; a case over it is killed (timeout)")
    s.add_argument("--timeout", type=float, default=None,
                   help="seconds for the whole sweep; unfinished cases are marked timeout")
    s.add_argument("--probe", help="probe to plot (default: the first)")
    s.add_argument("--ratio", action="append", default=[], metavar="PROBE",
                   help="in --results, also PROBE released / loaded (a part that is released: "
                        "the curvature it retains; repeatable)")
    add_results_option(s, "forming-mesh.md")
    s.add_argument("--out", default="runs/sweep")
    s.set_defaults(func=run)

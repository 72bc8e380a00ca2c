"""``q3t sweep``: the cartesian product of scene overrides, one Dask task per case.

Each task loads the scene with its overrides, runs it and returns a small dict (``run_case``):
a case whose scene is invalid or whose solver fails is a row of the table, never the end of the
sweep. By default a ``LocalCluster`` of single-threaded worker processes runs the cases;
``--scheduler`` sends them to an existing cluster instead (its workers need this package).
"""

from __future__ import annotations

import itertools
import json
import math
import sys
import time
from pathlib import Path

# Numba's own pool would give every worker all cores: one thread each, the cluster is the pool.
WORKER_ENV = {"NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def run_case(scene_path: str, overrides: dict, measure=None) -> dict:
    """Run one scene with ``overrides``; a summary that pickles small (no arrays).

    status: ``converged``, ``failed`` (solver diagnostic in ``reason``), ``invalid`` (the scene
    was rejected, message in ``reason``) or ``nan`` (converged with a non-finite probe).
    ``measure(sim) -> dict``, when given, adds its numbers as ``measured`` after the run.
    """
    from sim.scene import load_scene
    from sim.simulation import Simulation

    out = {"overrides": dict(overrides), "status": "invalid", "converged": False,
           "reason": None, "probes": {}, "wall": 0.0, "build": 0.0, "dofs": None,
           "elements": None, "iterations": 0, "cutbacks": 0, "residual": None}
    t0 = time.perf_counter()
    try:
        sim = Simulation.from_scene(load_scene(scene_path, overrides))
    except ValueError as exc:  # SceneError is a ValueError; so are model-building errors
        out["reason"] = str(exc)
        return out
    out["build"] = time.perf_counter() - t0
    ok = sim.run()
    res = sim.result()
    out.update(converged=ok, wall=sim.wall, dofs=res["counts"]["dofs"],
               elements=res["counts"]["elements"], iterations=res["timing"]["newton_iterations"],
               cutbacks=sum(r.cutbacks for r in sim.records))
    if sim.records:
        out["probes"] = dict(sim.records[-1].probes)
        out["residual"] = float(sim.records[-1].residual)
    if measure is not None:
        out["measured"] = measure(sim)
    if not ok:
        f = sim.failure
        out.update(status="failed", reason=f["reason"], cutbacks=out["cutbacks"] + f["cutbacks"],
                   residual=float(f["residuals"][-1]) if f["residuals"] else None)
    elif all(math.isfinite(v) for v in out["probes"].values()):
        out["status"] = "converged"
    else:
        out.update(status="nan", reason="non-finite probe after a converged run")
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
    from sim.scene import parse_value

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
              scheduler: str | None = None, timeout: float | None = None) -> list[dict]:
    """Results in the order of ``overrides``. The cluster is closed on every way out; a sweep
    still running after ``timeout`` seconds raises ``TimeoutError``."""
    from distributed import Client, LocalCluster, wait

    def gather(client) -> list[dict]:
        futures = client.map(run_case, [scene_path] * len(overrides), overrides, pure=False)
        wait(futures, timeout=timeout)
        return [_row(f, o) for f, o in zip(futures, overrides, strict=True)]

    if scheduler:
        with Client(scheduler, timeout=30) as client:
            return gather(client)
    with (LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                       dashboard_address=None, env=WORKER_ENV, silence_logs=40) as cluster,
          Client(cluster) as client):
        return gather(client)


def _row(future, overrides: dict) -> dict:
    """A task that raised (a bug, a lost worker) is still a row, not the end of the sweep."""
    if future.status == "finished":
        return future.result()
    try:
        reason = repr(future.exception(timeout=1))
    except Exception as exc:  # noqa: BLE001 - cancelled or lost: say which
        reason = f"{future.status}: {exc!r}"
    return {"overrides": overrides, "status": "error", "converged": False, "reason": reason,
            "probes": {}}


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


def _as_x(v):
    return v if isinstance(v, (int, float)) else str(v)


def run(args) -> int:
    from sim.cli import parse_sets, resolve_scene

    scene = str(resolve_scene(args.scene))
    try:
        grid = parse_grid(args.grid)
    except ValueError as exc:
        print(f"q3t sweep: {exc}", file=sys.stderr)
        return 2
    todo = cases(grid, parse_sets(args.set))
    print(f"sweep {scene}: {len(todo)} cases on "
          f"{args.scheduler or f'{args.workers} local workers'}", file=sys.stderr)
    t0 = time.perf_counter()
    rows = run_sweep(scene, todo, args.workers, args.scheduler, args.timeout)
    wall = time.perf_counter() - t0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    keys = list(grid)
    md = table(rows, keys)
    (out / "sweep.md").write_text(f"# Sweep of {scene}\n\n{len(rows)} cases in {wall:.1f} s on "
                                  f"{args.scheduler or f'{args.workers} local workers'}.\n\n"
                                  + md)
    (out / "sweep.json").write_text(json.dumps(
        {"scene": scene, "grid": grid, "fixed": parse_sets(args.set), "wall": wall,
         "workers": args.workers, "scheduler": args.scheduler, "cases": rows}, indent=1))
    probe = args.probe or next((p for r in rows for p in r.get("probes", {})), None)
    if probe:
        plot(rows, keys, probe, out)
    print(md + f"wrote {out}/sweep.json, sweep.md ({wall:.1f} s)")
    return 0


def add_parser(sub) -> None:
    s = sub.add_parser("sweep", help="run the cartesian product of overrides on Dask")
    s.add_argument("scene", help="scene name in scenes/ or a TOML path")
    s.add_argument("--grid", action="append", required=True, metavar="KEY=V1,V2",
                   help="values of one scene key (repeatable; the product is swept)")
    s.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="an override for every case (repeatable)")
    s.add_argument("--workers", type=int, default=2, help="local single-threaded workers")
    s.add_argument("--scheduler", help="address of an existing Dask scheduler")
    s.add_argument("--timeout", type=float, default=None, help="give up after this many s")
    s.add_argument("--probe", help="probe to plot (default: the first)")
    s.add_argument("--out", default="runs/sweep")
    s.set_defaults(func=run)

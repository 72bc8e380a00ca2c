"""``q3t mesh-tools``: the cost of tools made from triangle meshes (sim.tools.meshtool).

The cup's punch, die and blank holder (scenes/cup_drawing.toml) are tessellated with chords
within ``--chord`` of their surfaces, and the die once more finely (``--fine-chord``, past
100,000 triangles); each is prepared from scratch (an empty cache) and its time, samples,
stored bytes and the process's peak memory are reported. Then one contact evaluation
(sim.terms.contact_kernels.penalty_contact: distances of all candidate nodes, derivatives of
those in contact) of the analytic die and of its mesh at the same candidate nodes."""

from __future__ import annotations

import argparse
import os
import resource
import tempfile
import time
from pathlib import Path

import numpy as np

from sim.apps.common import OK
from sim.stamp import Stamp, add_results_option, write_results

# the cup's tools (scenes/cup_drawing.toml), m
TOOLS = {"punch": ("punch", (0.0165, 0.04, 0.005)),
         "die": ("die_ring", (0.0177, 0.045, 0.02, 0.005)),
         "blank_holder": ("blank_holder", (0.0227, 0.045, 0.01, 0.001))}


def _program(name: str) -> np.ndarray:
    from sim.tools import builders

    kind, args = TOOLS[name]
    return getattr(builders, kind)(*args)


def _prepare(name: str, chord: float, spacing: float, folder: Path) -> dict:
    import trimesh

    from sim.tools.meshtool import MeshOptions, grid_params, read_surface
    from sim.tools.surface import chordal_mesh

    path = folder / f"{name}-{chord:g}.stl"
    trimesh.Trimesh(*chordal_mesh(_program(name), chord)).export(path)
    t0, c0 = time.perf_counter(), time.process_time()
    V, F = read_surface(path, MeshOptions(spacing=spacing))
    read = time.perf_counter() - t0
    params, rep = grid_params(V, F, spacing)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return {"tool": name, "chord_mm": chord * 1e3, "triangles": rep["triangles"],
            "spacing_mm": spacing * 1e3, "samples": rep["samples"],
            "bricks": rep["bricks"], "stored_MB": rep["bytes"] / 1e6,
            "check_s": read, "prepare_s": time.perf_counter() - t0,
            "cpu_s": time.process_time() - c0,
            "peak_rss_MB": peak, "params": params}


def _contact_cost(params: np.ndarray, n: int, repeat: int) -> dict:
    """Median seconds of one penalty_contact of the analytic die and of its grid at the same
    ``n`` candidate nodes, a third of them in contact (over the die's face and shoulder)."""
    from sim.terms.contact_kernels import penalty_contact
    from sim.tools.evaluate import sdf_distance
    from sim.tools.program import OP_GRID, program, record

    exact, grid = _program("die"), program(record(OP_GRID, params))
    rng = np.random.default_rng(0)
    X = rng.uniform([-0.045, -0.045, -0.006], [0.045, 0.045, 0.002], (40 * n, 3))
    d = sdf_distance(exact, X)
    X = np.concatenate([X[(d > -2e-5) & (d < 0)][: n // 3], X[(d > 0) & (d < 2e-3)]])[:n]
    R, t = np.eye(3), np.zeros(3)
    out = {}
    for label, prog in (("analytic", exact), ("mesh", grid)):
        penalty_contact(X, prog, R, t, 1e8, 2e-5, c2=True)  # compiled
        times = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            penalty_contact(X, prog, R, t, 1e8, 2e-5, c2=True)
            times.append(time.perf_counter() - t0)
        out[label] = float(np.median(times))
    return {"nodes": len(X), "analytic_ms": 1e3 * out["analytic"], "mesh_ms": 1e3 * out["mesh"],
            "ratio": out["mesh"] / out["analytic"]}


def report_md(rows: list[dict], cost: dict) -> str:
    head = ("| tool | chord (mm) | triangles | spacing (mm) | samples | bricks | stored (MB) "
            "| read + checks (s) | preparation (s) | its CPU time (s) | process peak RSS (MB) |\n"
            "|---|---|---|---|---|---|---|---|---|---|---|\n")
    body = "".join(f"| {r['tool']} | {r['chord_mm']:g} | {r['triangles']:,} | "
                   f"{r['spacing_mm']:g} | {r['samples']:,} | {r['bricks']:,} | "
                   f"{r['stored_MB']:.1f} | {r['check_s']:.2f} | {r['prepare_s']:.1f} | "
                   f"{r['cpu_s']:.1f} | "
                   f"{r['peak_rss_MB']:.0f} |\n" for r in rows)
    contact = ("\nOne contact evaluation (`penalty_contact`: every candidate's distance, the "
               "derivatives of those in contact) at the same candidate nodes of the die:\n\n"
               "| candidate nodes | analytic die (ms) | mesh die (ms) | mesh / analytic |\n"
               "|---|---|---|---|\n"
               f"| {cost['nodes']:,} | {cost['analytic_ms']:.2f} | {cost['mesh_ms']:.2f} | "
               f"{cost['ratio']:.2f} |\n")
    note = ("\nPreparation is wall time, with its CPU time (all threads) beside it: on a "
            "machine shared with other jobs the wall time is an upper bound. The peak RSS is "
            "the process's high-water mark so far (the rows run in order in one process).\n")
    return head + body + note + contact


def run(args: argparse.Namespace) -> int:
    stamp = Stamp.begin(args.command)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        os.environ["Q3T_CACHE"] = tmp  # prepared from scratch, nothing left behind
        folder = Path(args.out or tmp)
        folder.mkdir(parents=True, exist_ok=True)
        for name, chord in [*((n, args.chord) for n in TOOLS), ("die", args.fine_chord)]:
            r = _prepare(name, chord, args.spacing, folder)
            rows.append(r)
            print(f"{name} chord {chord:g} m: {r['triangles']} triangles, {r['samples']} "
                  f"samples, {r['stored_MB']:.1f} MB stored, {r['prepare_s']:.1f} s, peak RSS "
                  f"{r['peak_rss_MB']:.0f} MB", flush=True)
    cost = _contact_cost(rows[1]["params"], args.nodes, args.repeat)
    print(f"contact at {cost['nodes']} nodes: analytic {cost['analytic_ms']:.2f} ms, mesh "
          f"{cost['mesh_ms']:.2f} ms ({cost['ratio']:.2f}x)")
    if args.results:
        write_results(args.results, "Tools from meshes: preparation and contact cost "
                      "(`q3t mesh-tools`)", report_md(rows, cost), stamp)
        print(f"wrote {args.results}")
    return OK


def add_parser(sub: argparse._SubParsersAction) -> None:
    s = sub.add_parser("mesh-tools", help="cost of tools from triangle meshes: preparation "
                                          "and contact evaluation against the analytic tools")
    s.add_argument("--chord", type=float, default=1e-5,
                   help="the tessellation's chordal error, m (default %(default)g)")
    s.add_argument("--fine-chord", type=float, default=2.5e-6,
                   help="the die's finer tessellation, m (default %(default)g: over 100,000 "
                        "triangles)")
    s.add_argument("--spacing", type=float, default=5e-4,
                   help="the grids' spacing, m (default %(default)g: the mesh shape's)")
    s.add_argument("--nodes", type=int, default=6000,
                   help="candidate nodes of the contact evaluation (default %(default)d)")
    s.add_argument("--repeat", type=int, default=20, help="(default %(default)d)")
    s.add_argument("--out", default=None,
                   help="keep the tessellated tools (STL) there (default: not kept)")
    add_results_option(s, "mesh-tools.md")
    s.set_defaults(func=run)

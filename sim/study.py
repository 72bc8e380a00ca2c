"""``q3t study``: accuracy against cost under refinement (paper Fig. 8), the factorisation
comparison of Fig. 7 (``--factorisation``), and what building only the needed terms saves.

Every (element, edge length) pair is one in-process run, timed after a warm-up run of each
element on the coarsest mesh, so numba's cache loading is not counted. The error is
``|p - p_ref| / |p_ref|`` of the study probe against one reference run (by default the quadratic
element at the scene's ``study.reference_edge_length``, else half the finest edge length).
"""

from __future__ import annotations

import json
import platform
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from sim.sweep import run_case

MARKERS = {"linear": "o", "q3t": "s", "quadratic": "^", "quartic": "D"}


@dataclass(frozen=True)
class Plan:
    scene: str
    probe: str
    elements: list[str]
    levels: list[float]  # mesh edge lengths (m), coarse to fine
    reference: tuple[str, float]  # (element, edge length)
    notes: list[str] = field(default_factory=list)  # which defaults were taken and why


def make_plan(scene_path: str, elements: list[str] | None = None,
              levels: list[float] | None = None,
              reference: tuple[str, float] | None = None) -> Plan:
    """Options over the scene's ``study`` table; without one, its first probe at 4, 2 and 1
    times its own edge length."""
    from sim.elements import ELEMENTS
    from sim.scene import load_scene

    sc = load_scene(scene_path)
    st, notes = sc.study, []
    if sc.mesh.edge_length is None:
        raise ValueError(f"{sc.name}: mesh kind {sc.mesh.kind!r} has no edge_length to refine")
    if st is None:
        notes.append("scene has no [study] table: first probe, edge lengths 4x, 2x, 1x its own")
        if not sc.probes:
            raise ValueError(f"{sc.name}: no probe to study")
    probe = st.probe if st else sc.probes[0].name
    elements = elements or (st.elements if st else ["linear", "q3t", "quadratic"])
    unknown = set(elements) - set(ELEMENTS)
    if unknown:
        raise ValueError(f"unknown element(s) {sorted(unknown)}; known: {sorted(ELEMENTS)}")
    e0 = sc.mesh.edge_length
    levels = sorted(levels or (st.edge_lengths if st else [4 * e0, 2 * e0, e0]), reverse=True)
    if reference is None:
        ref_edge = st.reference_edge_length if st and st.reference_edge_length else None
        if ref_edge is None:
            ref_edge = levels[-1] / 2
            notes.append(f"reference edge length: half the finest level ({ref_edge:.6g} m)")
        reference = (st.reference_element if st else "quadratic", ref_edge)
    return Plan(str(scene_path), probe, list(elements), list(levels), tuple(reference), notes)


def run_study(plan: Plan, progress=print) -> dict:
    """The reference run, then every element at every level; rows carry the relative error."""
    for el in plan.elements:  # warm-up: load every kernel from the numba cache once
        run_case(plan.scene, {"shell.element": el, "mesh.edge_length": plan.levels[0]})
    ref_el, ref_edge = plan.reference
    ref = run_case(plan.scene, {"shell.element": ref_el, "mesh.edge_length": ref_edge})
    if ref["status"] != "converged":
        raise RuntimeError(f"reference run {ref_el} at {ref_edge} m: {ref['reason']}")
    p_ref = ref["probes"][plan.probe]
    progress(f"reference {ref_el} h={ref_edge:.6g}: {plan.probe} = {p_ref:.8g} "
             f"({ref['dofs']} DoFs, {ref['build'] + ref['wall']:.2f} s)")
    rows = []
    for el in plan.elements:
        for edge in plan.levels:
            r = run_case(plan.scene, {"shell.element": el, "mesh.edge_length": edge})
            p = r["probes"].get(plan.probe, float("nan"))
            row = {"element": el, "edge_length": edge, "status": r["status"],
                   "elements": r["elements"], "dofs": r["dofs"], "probe": p,
                   "error": abs(p - p_ref) / abs(p_ref), "time": r["build"] + r["wall"],
                   "solve_time": r["wall"], "iterations": r["iterations"]}
            rows.append(row)
            progress(f"{el:9s} h={edge:.6g} {row['dofs'] or 0:7d} DoFs  {plan.probe}={p:.6g}  "
                     f"error {row['error']:.3e}  {row['time']:.3f} s")
    return {"plan": asdict(plan), "reference": {**ref, "value": p_ref}, "rows": rows}


def factorisation_times(scene_path: str, elements: list[str], levels: list[float],
                        repeat: int = 5) -> list[dict]:
    """Median time of ``solver.factor`` on the Hessian at rest (paper Fig. 7)."""
    from sim.scene import load_scene
    from sim.simulation import Simulation

    rows = []
    for el in elements:
        for edge in levels:
            sim = Simulation.from_scene(load_scene(scene_path, {"shell.element": el,
                                                                "mesh.edge_length": edge}))
            P = sim.model.problem
            _, data = P.gradient_hessian(sim.model.shell.rest)
            times = []
            for _ in range(repeat + 1):  # the first includes one-off allocations: dropped
                t0 = time.perf_counter()
                P.solver.factor(data)
                times.append(time.perf_counter() - t0)
            c = sim.result()["counts"]
            rows.append({"element": el, "edge_length": edge, "elements": c["elements"],
                         "nodes": c["nodes"], "dofs": c["dofs"], "nnz_upper": int(P.pattern.nnz),
                         "solver": P.solver.name, "factorisation": float(np.median(times[1:]))})
    return rows


def all_terms_overrides(scene) -> dict:
    """Overrides that build every term without changing the answer: dynamic with dt = 1e6 s
    (inertia stiffness M/dt^2: 1e-12 N/m per kg of node mass, nothing beside any elastic
    stiffness) ramping the load as the static steps do, plastic with a yield stress of 1e30 Pa
    (never reached), a zero load if none."""
    o = {}
    st = scene.stepping
    if st.kind == "static":
        o.update({"stepping.kind": "dynamic", "stepping.dt": 1e6,
                  "stepping.load_ramp": 1e6 * st.steps})
    if scene.material.model != "plastic":
        o.update({"material.model": "plastic", "material.yield_stress": 1e30})
    if not scene.loads:
        o["loads"] = [{"kind": "gravity", "vector": [0.0, 0.0, 0.0]}]
    return o


def terms_overhead(scene_path: str, overrides: dict | None = None, repeat: int = 3) -> dict:
    """Run time of the scene as it is against the same scene with every term built: the two
    interleaved, after one warm-up each, and the fastest of ``repeat`` (other processes on the
    machine only ever add time)."""
    from sim.scene import load_scene
    from sim.simulation import Simulation

    base = dict(overrides or {})
    variants = {"lean": base, "all_terms": {**base, **all_terms_overrides(
        load_scene(scene_path, base))}}
    runs: dict[str, list] = {k: [] for k in variants}
    for i in range(repeat + 1):
        for name, o in variants.items():
            sim = Simulation.from_scene(load_scene(scene_path, o))
            sim.run()
            if i:
                runs[name].append(sim)
    out = {"overrides": base, "all_terms_overrides": variants["all_terms"], "repeat": repeat}
    for name, sims in runs.items():
        r = sims[0].result()
        out[name] = {"built": r["built"], "converged": r["converged"],
                     "wall": min(s.wall for s in sims),
                     "per_iteration": min(s.result()["timing"]["per_iteration"] for s in sims),
                     "iterations": r["timing"]["newton_iterations"],
                     "probes": r["steps"][-1]["probes"] if r["steps"] else {}}
    lean, full = out["lean"], out["all_terms"]
    out["saved_wall"] = 1 - lean["wall"] / full["wall"]
    out["saved_per_iteration"] = 1 - lean["per_iteration"] / full["per_iteration"]
    return out


def _save(fig, out: Path, stem: str) -> list[str]:
    names = [f"{stem}.png", f"{stem}.svg"]
    for n in names:
        fig.savefig(out / n, dpi=120)
    return names


def plot_study(study: dict, out: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = []
    ref_el, ref_edge = study["plan"]["reference"]
    for x_key, xlabel, stem in (("time", "run time [s]", "error_time"),
                                ("dofs", "degrees of freedom", "error_dofs")):
        fig, ax = plt.subplots(figsize=(5.5, 4))
        for el in study["plan"]["elements"]:
            rs = [r for r in study["rows"] if r["element"] == el and r["error"] > 0]
            ax.loglog([r[x_key] for r in rs], [r["error"] for r in rs],
                      marker=MARKERS.get(el, "o"), label=el)
        ax.set(xlabel=xlabel, ylabel=f"relative error of {study['plan']['probe']}",
               title=f"reference: {ref_el}, edge {ref_edge:.4g} m")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
        fig.tight_layout()
        files += _save(fig, out, stem)
        plt.close(fig)
    return files


def plot_factorisation(rows: list[dict], out: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for ax, key in zip(axes, ("elements", "nodes"), strict=True):
        for el in dict.fromkeys(r["element"] for r in rows):
            rs = [r for r in rows if r["element"] == el]
            ax.loglog([r[key] for r in rs], [r["factorisation"] for r in rs],
                      marker=MARKERS.get(el, "o"), label=el)
        ax.set(xlabel=f"number of {key}", ylabel="factorisation time [s]",
               title=f"same number of {key}")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    fig.tight_layout()
    files = _save(fig, out, "factorisation")
    plt.close(fig)
    return files


def _table(rows: list[dict], cols: list[tuple[str, str, str]]) -> str:
    lines = ["| " + " | ".join(c[1] for c in cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        lines.append("| " + " | ".join(format(r[k], f) if r[k] is not None else "" for k, _, f
                                       in cols) + " |")
    return "\n".join(lines) + "\n"


STUDY_COLS = [("element", "element", ""), ("edge_length", "edge [m]", ".5g"),
              ("elements", "triangles", "d"), ("dofs", "DoFs", "d"), ("probe", "probe", ".6g"),
              ("error", "rel. error", ".3e"), ("time", "time [s]", ".3f"),
              ("iterations", "Newton it.", "d"), ("status", "status", "")]
FACTOR_COLS = [("element", "element", ""), ("edge_length", "edge [m]", ".5g"),
               ("elements", "elements", "d"), ("nodes", "nodes", "d"), ("dofs", "DoFs", "d"),
               ("nnz_upper", "nnz (upper)", "d"), ("factorisation", "factor [s]", ".4f")]


def overhead_md(o: dict) -> str:
    lean, full = o["lean"], o["all_terms"]
    probe = next(iter(lean["probes"]), None)
    rows = [{"run": name, "terms": ", ".join(d["built"]["terms"]),
             "plastic": str(d["built"]["plastic_state"]), "it": d["iterations"],
             "per_it": d["per_iteration"], "wall": d["wall"],
             "probe": d["probes"].get(probe, float("nan"))}
            for name, d in (("as the scene needs", lean), ("every term built", full))]
    cols = [("run", "run", ""), ("terms", "terms", ""), ("plastic", "plastic state", ""),
            ("probe", str(probe), ".6g"), ("it", "Newton it.", "d"),
            ("per_it", "per iteration [s]", ".4f"), ("wall", "total [s]", ".3f")]
    return (f"Overrides for every term: `{o['all_terms_overrides']}` (same answer: inertia "
            f"weight M/dt^2 negligible, yield never reached).\n\n" + _table(rows, cols)
            + f"\nSaved: {100 * o['saved_per_iteration']:.0f} % per Newton iteration, "
            f"{100 * o['saved_wall']:.0f} % of the run (fastest of {o['repeat']} interleaved "
            "runs; the plastic variant uses the Hencky law, so iteration counts may differ).\n")


def _meta() -> str:
    import os

    return (f"{time.strftime('%Y-%m-%d')}, {platform.machine()} with {os.cpu_count()} cores, "
            f"Python {platform.python_version()}")


def write_study(study: dict, overhead: dict | None, out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    plots = plot_study(study, out)
    p, ref = study["plan"], study["reference"]
    if p["reference"][0] in p["elements"]:  # say so: its rows converge to themselves
        p = {**p, "notes": [*p["notes"], f"{p['reference'][0]} rows: error against the same "
                            "element on a finer mesh (self-convergence, an underestimate)"]}
    md = [f"# Refinement study: {Path(p['scene']).stem}\n\n", f"{_meta()}.\n\n",
          f"Probe `{p['probe']}`; reference **{p['reference'][0]} at edge "
          f"{p['reference'][1]:.6g} m** ({ref['dofs']} DoFs): {ref['value']:.8g}. Times are build "
          "plus solve of one run, after a warm-up run of each element.\n\n",
          *[f"- {n}\n" for n in p["notes"]], "\n" if p["notes"] else "",
          _table(study["rows"], STUDY_COLS), "\n",
          *[f"![{f}]({f})\n" for f in plots if f.endswith(".png")]]
    if overhead:
        md += ["\n## Leave out what a scene does not need\n\n", overhead_md(overhead)]
    (out / "report.md").write_text("".join(md))
    (out / "report.json").write_text(json.dumps({"study": study, "overhead": overhead},
                                                indent=1))


def write_factorisation(scene: str, rows: list[dict], out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    plots = plot_factorisation(rows, out)
    md = (f"# Factorisation of the Hessian at rest: {Path(scene).stem} (paper Fig. 7)\n\n"
          f"{_meta()}; solver {rows[0]['solver']}; median of repeated `solver.factor` calls.\n\n"
          + _table(rows, FACTOR_COLS) + "\n" + "".join(f"![{f}]({f})\n" for f in plots
                                                       if f.endswith(".png")))
    (out / "report.md").write_text(md)
    (out / "report.json").write_text(json.dumps({"scene": scene, "factorisation": rows},
                                                indent=1))


def factorisation_report(scene: str, elements: list[str], levels: list[float], repeat: int,
                         out: Path) -> list[dict]:
    """Fig. 7: time the factorisations, print the table, write report.md / .json and plots
    (the last only where matplotlib is installed). ``q3t bench`` runs this too."""
    rows = factorisation_times(scene, elements, levels, repeat)
    print(_table(rows, FACTOR_COLS), flush=True)
    try:
        write_factorisation(scene, rows, out)
    except ImportError as exc:  # the study extra is not installed: keep the numbers
        out.mkdir(parents=True, exist_ok=True)
        (out / "report.json").write_text(json.dumps({"scene": scene, "factorisation": rows},
                                                    indent=1))
        print(f"no plot ({exc})", file=sys.stderr)
    return rows


def run(args) -> int:
    from sim.cli import resolve_scene
    from sim.scene import SceneError

    scene = str(resolve_scene(args.scene))
    out = Path(args.out or f"runs/study-{Path(scene).stem}")
    try:
        ref = None
        if args.reference:
            el, _, edge = args.reference.partition(":")
            if not edge:
                raise ValueError("--reference needs ELEMENT:EDGE, e.g. quadratic:0.0035")
            ref = (el, float(edge))
        plan = make_plan(scene, args.elements and args.elements.split(","),
                         args.levels and [float(v) for v in args.levels.split(",")], ref)
    except (SceneError, ValueError) as exc:
        print(f"q3t study: {exc}", file=sys.stderr)
        return 2
    if args.factorisation:
        factorisation_report(scene, plan.elements, plan.levels, args.repeat, out)
    else:
        study = run_study(plan, progress=lambda s: print(s, file=sys.stderr, flush=True))
        overhead = None
        if not args.no_overhead:
            edge = plan.levels[len(plan.levels) // 2]
            overhead = terms_overhead(scene, {"mesh.edge_length": edge}, args.repeat)
        write_study(study, overhead, out)
        print(_table(study["rows"], STUDY_COLS) + (overhead_md(overhead) if overhead else ""))
    print(f"wrote {out}/report.md, report.json and plots")
    return 0


def add_parser(sub) -> None:
    s = sub.add_parser("study", help="error against run time and DoFs under refinement")
    s.add_argument("scene", help="scene name in scenes/ or a TOML path")
    s.add_argument("--elements", help="comma-separated (default: the scene's study table)")
    s.add_argument("--levels", help="comma-separated mesh edge lengths in m")
    s.add_argument("--reference", metavar="ELEMENT:EDGE", help="e.g. quadratic:0.0035")
    s.add_argument("--factorisation", action="store_true",
                   help="time the Hessian factorisation instead (paper Fig. 7)")
    s.add_argument("--repeat", type=int, default=3, help="repeats for medians")
    s.add_argument("--no-overhead", action="store_true",
                   help="skip the lean-against-all-terms timing")
    s.add_argument("--out", help="output folder (default runs/study-<scene>)")
    s.set_defaults(func=run)

"""``q3t study``: accuracy against cost under refinement (paper Fig. 8), the factorisation
comparison of Fig. 7 (``--factorisation``), and what building only the needed terms saves.

Every (element, edge length) pair is one case, run as a Dask task through ``sim.sweep``'s
``run_tasks`` (a local cluster by default, ``--scheduler`` for an existing one). A study
measures run time, so by default one worker process with one thread (numba, OpenMP and MKL
pinned) runs one case at a time: cases running side by side on a 2-core machine would slow each
other down. Each worker first runs every element once on the coarsest level (a warm-up, not
timed), so numba's cache loading is not counted. ``report.md`` says how the cases ran.

The error of a case is that of the study's measure (``[study]`` table, sim.scene.StudySpec)
against the reference: a closed-form value (``analytic``, sim.analytic) when the scene has
one, else one numerical run (the quadratic element at ``reference_edge_length``, by default
half the finest level). Measures: the final probe (relative difference), the probe's curve
over the run or a section's profile (relative L2 or max difference on the common range).
"""

from __future__ import annotations

import json
import math
import os
import platform
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from sim.sweep import cluster_text, run_case, run_tasks

MARKERS = {"linear": "o", "q3t": "s", "quadratic": "^", "quartic": "D"}
FACTOR_REPEAT = 15  # factorisations per case: medians and minima of >= 10 calls
OVERHEAD_REPEAT = 3


class StudyError(RuntimeError):
    """The study cannot give errors: its reference run failed."""


@dataclass(frozen=True)
class Plan:
    scene: str
    probe: str  # what is measured, as the report names it
    measure: dict  # probe, measure, over, section, field, step, norm (sim.scene.StudySpec)
    elements: list[str]
    levels: list[float]  # mesh edge lengths (m), coarse to fine
    reference: tuple[str, float] | None  # (element, edge length) of a numerical reference
    analytic: dict | None = None  # {"name", "value", "about"} (sim.analytic)
    overrides: dict = field(default_factory=dict)  # applied to every case (--set)
    notes: list[str] = field(default_factory=list)  # which defaults were taken and why


def _label(m: dict) -> str:
    if m["measure"] == "final":
        return m["probe"]
    if m["measure"] == "curve":
        return f"{m['probe']} over {m['over']} ({m['norm']})"
    return f"{m['section']}.{m['field']} profile ({m['norm']})"


def make_plan(scene_path: str, elements: list[str] | None = None,
              levels: list[float] | None = None,
              reference: tuple[str, float] | None = None, overrides: dict | None = None,
              study: dict | None = None) -> Plan:
    """The scene's ``[study]`` table (validated with the scene, after ``overrides`` and the
    ``study`` keys given on the command line); without one, its first probe at 4, 2 and 1 times
    its own edge length."""
    from sim.elements import ELEMENTS
    from sim.scene import load_scene

    overrides = dict(overrides or {})
    sc = load_scene(scene_path, {**overrides, **{f"study.{k}": v for k, v in
                                                 (study or {}).items()}})
    st, notes = sc.study, []
    if sc.mesh.edge_length is None:
        raise ValueError(f"{sc.name}: mesh kind {sc.mesh.kind!r} has no edge_length to refine")
    if st is None:
        notes.append("scene has no [study] table: first probe, edge lengths 4x, 2x, 1x its own")
        if not sc.probes:
            raise ValueError(f"{sc.name}: no probe to study")
    elements = elements or (st.elements if st else ["linear", "q3t", "quadratic"])
    unknown = set(elements) - set(ELEMENTS)
    if unknown:
        raise ValueError(f"unknown element(s) {sorted(unknown)}; known: {sorted(ELEMENTS)}")
    e0 = sc.mesh.edge_length
    if not levels and not (st and st.edge_lengths):
        if st is not None:
            notes.append("no study.edge_lengths: 4x, 2x, 1x the mesh's own")
        levels = [4 * e0, 2 * e0, e0]
    levels = sorted(levels or st.edge_lengths, reverse=True)
    m = {"probe": sc.probes[0].name if sc.probes else None, "measure": "final", "over": "time",
         "section": None, "field": "thickness", "step": None, "norm": "l2"}
    if st is not None:
        m.update({k: getattr(st, k) for k in m if getattr(st, k) is not None})
    analytic = None
    if st is not None and st.analytic and reference is None:
        from sim.analytic import reference as formula

        analytic = formula(sc, st.analytic, m["probe"])
    elif reference is None:
        ref_edge = st.reference_edge_length if st and st.reference_edge_length else None
        if ref_edge is None:
            ref_edge = levels[-1] / 2
            notes.append(f"reference edge length: half the finest level ({ref_edge:.6g} m)")
        reference = (st.reference_element if st else "quadratic", ref_edge)
    if reference is not None and reference[0] not in ELEMENTS:
        raise ValueError(f"--reference: unknown element {reference[0]!r}")
    return Plan(str(scene_path), _label(m), m, list(elements), list(levels),
                tuple(reference) if reference else None, analytic, overrides, notes)


_WARM: set[str] = set()  # warm-ups done in this (worker) process


def study_case(scene_path: str, overrides: dict, warmup: dict) -> dict:
    """One timed case on a Dask worker: ``run_case`` with its series, after a warm-up run
    (``warmup`` overrides, once per worker process) that loads every kernel the element needs
    from numba's cache."""
    key = json.dumps([scene_path, warmup], sort_keys=True, default=str)
    if key not in _WARM:
        run_case(scene_path, warmup)
        _WARM.add(key)
    return run_case(scene_path, overrides, series=True)


def measured(r: dict, m: dict):
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


def curve_error(x, y, xr, yr, norm: str = "l2") -> float:
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


def case_error(r: dict, ref, m: dict) -> float:
    """Relative error of case ``r`` against the reference's ``measured`` value ``ref``."""
    if r.get("status") != "converged":
        return math.nan
    v = measured(r, m)
    if v is None:
        return math.nan
    if m["measure"] == "final":
        return abs(v - ref) / abs(ref)
    return curve_error(*v, *ref, m["norm"])


def _case(plan: Plan, element: str, edge: float) -> tuple:
    o = {**plan.overrides, "shell.element": element, "mesh.edge_length": edge}
    warm = {**plan.overrides, "shell.element": element, "mesh.edge_length": plan.levels[0]}
    return (study_case, plan.scene, o, warm)


def run_study(plan: Plan, progress=print, workers: int = 1, threads: int = 1,
              scheduler: str | None = None, timeout: float | None = None,
              overhead: dict | None = None) -> dict:
    """The reference run (unless analytic), then every element at every level, on Dask; rows
    carry the relative error. ``overhead``: also ``terms_overhead(**overhead)`` as the last
    task. Raises StudyError when the reference run fails."""
    m = plan.measure
    calls, labels = [], []
    if plan.reference:
        calls.append(_case(plan, *plan.reference))
        labels.append({"overrides": calls[-1][2]})
    grid = [(el, edge) for el in plan.elements for edge in plan.levels]
    calls += [_case(plan, el, edge) for el, edge in grid]
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
                     "error": case_error(r, ref_value, m),
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


def factorisation_case(scene_path: str, element: str, edge: float, repeat: int,
                       overrides: dict) -> dict:
    """Times of ``repeat`` calls of ``solver.factor`` on the Hessian at rest (paper Fig. 7)."""
    from sim.scene import load_scene
    from sim.simulation import Simulation

    sim = Simulation.from_scene(load_scene(scene_path, {**overrides, "shell.element": element,
                                                        "mesh.edge_length": edge}))
    P = sim.model.problem
    _, data = P.gradient_hessian(sim.model.shell.rest)
    times = []
    for _ in range(repeat + 1):  # the first includes one-off allocations: dropped
        t0 = time.perf_counter()
        P.solver.factor(data)
        times.append(time.perf_counter() - t0)
    c = sim.result()["counts"]
    t = np.array(times[1:])
    return {"element": element, "edge_length": edge, "elements": c["elements"],
            "nodes": c["nodes"], "dofs": c["dofs"], "nnz_upper": int(P.pattern.nnz),
            "solver": P.solver.name, "factorisation": float(np.median(t)),
            "factorisation_min": float(t.min()), "repeat": repeat, "status": "converged"}


def factorisation_times(scene_path: str, elements: list[str], levels: list[float],
                        repeat: int = FACTOR_REPEAT, overrides: dict | None = None,
                        workers: int = 1, threads: int = 1, scheduler: str | None = None,
                        timeout: float | None = None) -> list[dict]:
    """``factorisation_case`` of every element at every level, on Dask (one case at a time
    by default: the times are the point)."""
    calls = [(factorisation_case, scene_path, el, edge, repeat, dict(overrides or {}))
             for el in elements for edge in levels]
    labels = [{"element": el, "edge_length": edge} for el in elements for edge in levels]
    rows, _ = run_tasks(calls, labels, workers, threads, scheduler, timeout)
    return rows


FAR_TOOL = {"name": "far_plane", "shape": {"kind": "plane", "point": [0.0, 0.0, -1.0e3]}}


def all_terms_overrides(scene) -> dict:
    """Scene overrides that add, with no effect on the answer, the terms a scene can add
    through its file: a contact term with a plane 1 km below the sheet (every skin node is
    tested against it at every evaluation and none ever reaches it), and a zero gravity
    load."""
    o = {}
    if not scene.tools:
        o["tools"] = [FAR_TOOL]
    if not scene.loads:
        o["loads"] = [{"kind": "gravity", "vector": [0.0, 0.0, 0.0]}]
    return o


def all_terms_model(scene):
    """The model of ``scene`` (see ``all_terms_overrides``) with every other term too, each
    without effect and with the scene's own material law: plastic state under a yield stress
    of 1e30 Pa (never reached: the return map never flows, but runs at every commit and the
    element kernel maps through Fp^-1 at every quadrature point), and inertia with zero mass
    (its energy, gradient and Hessian are evaluated and are zero)."""
    from sim.materials.plasticity import PERFECT
    from sim.model import build_model, describe, lame
    from sim.terms.elasticity import Elasticity
    from sim.terms.inertia import Inertia

    m = build_model(scene)
    el = m.elasticity
    if not el.plastic:
        mu, lam = lame(scene.material.E, scene.material.nu)
        full = Elasticity(m.shell, el.rule, el.model, np.array([mu, lam, PERFECT, 1e30]),
                          m.pattern, el.project, plastic=True)
        m.terms[m.terms.index(el)] = full  # the list Problem sums
        m.elasticity = full
    if m.inertia is None:
        m.inertia = Inertia(np.zeros(len(m.x0)), m.pattern, m.x0)
        m.terms.append(m.inertia)
    m.built = describe(m)
    return m


def terms_overhead(scene_path: str, overrides: dict | None = None,
                   repeat: int = OVERHEAD_REPEAT) -> dict:
    """Run time of the scene as it is against the same scene with every term built
    (``all_terms_model``): the two interleaved, after one warm-up each, and the fastest of
    ``repeat`` (other processes on the machine only ever add time)."""
    from sim.model import build_model
    from sim.scene import load_scene
    from sim.simulation import Simulation

    base = dict(overrides or {})
    lean_scene = load_scene(scene_path, base)
    extra = all_terms_overrides(lean_scene)
    full_scene = load_scene(scene_path, {**base, **extra})
    variants = {"lean": lambda: build_model(lean_scene),
                "all_terms": lambda: all_terms_model(full_scene)}
    runs: dict[str, list] = {k: [] for k in variants}
    for i in range(repeat + 1):
        for name, build in variants.items():
            sim = Simulation(build())
            sim.run()
            if i:
                runs[name].append(sim)
    out = {"scene": Path(scene_path).stem, "overrides": base, "all_terms_overrides": extra,
           "repeat": repeat}
    for name, sims in runs.items():
        r = sims[0].result()
        out[name] = {"built": r["built"], "converged": r["converged"],
                     "wall": min(s.wall for s in sims),
                     "per_iteration": min(s.result()["timing"]["per_iteration"] for s in sims),
                     "iterations": r["timing"]["newton_iterations"],
                     "probes": r["steps"][-1]["probes"] if r["steps"] else {}}
    lean, full = out["lean"], out["all_terms"]
    out["added_terms"] = [t for t in full["built"]["terms"] if t not in lean["built"]["terms"]]
    out["added_state"] = sorted(set(full["built"]["state"]) - set(lean["built"]["state"]))
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
    for x_key, xlabel, stem in (("time", "run time [s]", "error_time"),
                                ("dofs", "degrees of freedom", "error_dofs")):
        fig, ax = plt.subplots(figsize=(5.5, 4))
        for el in study["plan"]["elements"]:
            rs = [r for r in study["rows"] if r["element"] == el
                  and math.isfinite(r["error"]) and r["error"] > 0]
            ax.loglog([r[x_key] for r in rs], [r["error"] for r in rs],
                      marker=MARKERS.get(el, "o"), label=el)
        ax.set(xlabel=xlabel, ylabel=f"relative error of {study['plan']['probe']}",
               title=f"reference: {study['reference_label']}")
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
            rs = [r for r in rows if r["element"] == el and "factorisation" in r]
            ax.loglog([r[key] for r in rs], [r["factorisation"] for r in rs],
                      marker=MARKERS.get(el, "o"), label=el)
        ax.set(xlabel=f"number of {key}", ylabel="factorisation time [s] (median)",
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
        lines.append("| " + " | ".join(format(r[k], f) if r.get(k) is not None else ""
                                       for k, _, f in cols) + " |")
    return "\n".join(lines) + "\n"


STUDY_COLS = [("element", "element", ""), ("edge_length", "edge [m]", ".5g"),
              ("elements", "triangles", "d"), ("dofs", "DoFs", "d"), ("probe", "probe", ".6g"),
              ("error", "rel. error", ".3e"), ("time", "time [s]", ".3f"),
              ("iterations", "Newton it.", "d"), ("status", "status", "")]
FACTOR_COLS = [("element", "element", ""), ("edge_length", "edge [m]", ".5g"),
               ("elements", "elements", "d"), ("nodes", "nodes", "d"), ("dofs", "DoFs", "d"),
               ("nnz_upper", "nnz (upper)", "d"), ("factorisation", "median [s]", ".4f"),
               ("factorisation_min", "min [s]", ".4f"), ("status", "status", "")]


def overhead_md(overheads: list[dict]) -> str:
    """One table for all scenes: each as it is against each with every term built."""
    rows = []
    for o in overheads:
        lean, full = o["lean"], o["all_terms"]
        probe = next(iter(lean["probes"]), None)
        for name, d in (("as the scene needs", lean), ("every term built", full)):
            rows.append({"scene": o["scene"], "run": name, "terms": ", ".join(d["built"]["terms"]),
                         "state": ", ".join(k for k in d["built"]["state"] if k != "positions")
                         or "-", "it": d["iterations"], "per_it": d["per_iteration"],
                         "wall": d["wall"],
                         "probe": f"{probe} = {d['probes'].get(probe, math.nan):.9g}"})
        rows.append({"scene": "", "run": "**saved**", "terms": "", "state": "", "it": None,
                     "per_it": None, "wall": None,
                     "probe": f"**{100 * o['saved_per_iteration']:.0f} % per iteration, "
                              f"{100 * o['saved_wall']:.0f} % of the run**"})
    cols = [("scene", "scene", ""), ("run", "run", ""), ("terms", "terms", ""),
            ("state", "state arrays", ""), ("probe", "probe", ""), ("it", "Newton it.", "d"),
            ("per_it", "per iteration [s]", ".4f"), ("wall", "total [s]", ".3f")]
    repeat = overheads[0]["repeat"] if overheads else 0
    return ("Every term built: a contact term with a plane 1 km below the sheet where a scene "
            "has no tool, a zero load where it has none, plastic state under a yield stress of "
            "1e30 Pa with the scene's own elastic law, inertia with zero mass: the same answer "
            "(the probes agree to round-off) with the work of every term done. The fastest of "
            f"{repeat} interleaved runs each.\n\n" + _table(rows, cols))


def _meta() -> str:
    return (f"{time.strftime('%Y-%m-%d')}, {platform.machine()} with {os.cpu_count()} cores, "
            f"Python {platform.python_version()}")


def _how(cluster: str, workers: int, scheduler: str | None) -> str:
    s = (f"Cases ran as Dask tasks on {cluster}; each worker ran every element once on the "
         "coarsest level first (warm-up, not timed). Times are build plus solve of one case.")
    if not scheduler and workers > 1 and workers * 1 >= (os.cpu_count() or 1):
        s += (f" {workers} cases ran at once on {os.cpu_count()} cores: they shared the cores, "
              "so the times are inflated and noisy; use --workers 1 for timings.")
    return s


def write_study(study: dict, overheads: list[dict], out: Path, workers: int = 1,
                scheduler: str | None = None) -> None:
    out.mkdir(parents=True, exist_ok=True)
    plots = plot_study(study, out)
    p, ref = study["plan"], study["reference"]
    notes = list(p["notes"])
    if p["reference"] and p["reference"][0] in p["elements"]:  # its rows converge to themselves
        notes.append(f"{p['reference'][0]} rows: error against the same element on a finer "
                     "mesh (self-convergence, an underestimate)")
    if not study["finished"]:
        notes.append("the study's --timeout ended it: unfinished cases are marked timeout")
    if study.get("overhead_failed"):
        notes.append(f"the lean against all-terms timing failed: {study['overhead_failed']}")
    if p["analytic"]:
        head = f"reference **{p['analytic']['name']} (analytic)**: {p['analytic']['about']}."
    else:
        el, edge = p["reference"]
        value = f": {ref['value']:.8g}" if "value" in ref else ""
        head = (f"reference **{el} at edge {edge:.6g} m** (a numerical run, {ref['dofs']} "
                f"DoFs){value}.")
    md = [f"# Refinement study: {Path(p['scene']).stem}\n\n", f"{_meta()}.\n\n",
          f"Measure `{p['probe']}`; {head}\n\n",
          _how(study["cluster"], workers, scheduler) + "\n\n",
          *[f"- overrides of every case: `{p['overrides']}`\n" for _ in [0] if p["overrides"]],
          *[f"- {n}\n" for n in notes], "\n" if notes or p["overrides"] else "",
          _table(study["rows"], STUDY_COLS), "\n",
          *[f"![{f}]({f})\n" for f in plots if f.endswith(".png")]]
    if overheads:
        md += ["\n## Leave out what a scene does not need\n\n", overhead_md(overheads)]
    (out / "report.md").write_text("".join(md))
    (out / "report.json").write_text(json.dumps({"study": study, "overhead": overheads},
                                                indent=1, default=float))


def write_overhead(overheads: list[dict], out: Path, cluster: str) -> None:
    out.mkdir(parents=True, exist_ok=True)
    md = (f"# Leave out what a scene does not need\n\n{_meta()}; ran on {cluster}.\n\n"
          + overhead_md(overheads))
    (out / "report.md").write_text(md)
    (out / "report.json").write_text(json.dumps({"overhead": overheads}, indent=1))


def write_factorisation(scene: str, rows: list[dict], out: Path, cluster: str = "") -> None:
    out.mkdir(parents=True, exist_ok=True)
    plots = plot_factorisation(rows, out)
    ok = [r for r in rows if "factorisation" in r]
    md = (f"# Factorisation of the Hessian at rest: {Path(scene).stem} (paper Fig. 7)\n\n"
          f"{_meta()}; solver {ok[0]['solver'] if ok else '-'}; median and minimum of "
          f"{ok[0]['repeat'] if ok else 0} `solver.factor` calls per case (after one dropped "
          f"call); ran on {cluster}.\n\n"
          + _table(rows, FACTOR_COLS) + "\n" + "".join(f"![{f}]({f})\n" for f in plots
                                                       if f.endswith(".png")))
    (out / "report.md").write_text(md)
    (out / "report.json").write_text(json.dumps({"scene": scene, "factorisation": rows},
                                                indent=1))


def _inputs(args) -> tuple[str, Plan]:
    """The plan from the command line; ValueError / SceneError on bad input."""
    from sim.cli import parse_sets, resolve_scene

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
    if args.timeout is not None and args.timeout <= 0:
        raise ValueError("--timeout must be positive (seconds)")
    if args.repeat is not None and args.repeat < 1:
        raise ValueError("--repeat must be at least 1")
    study = {k: v for k, v in (("probe", args.probe), ("measure", args.measure),
                               ("analytic", args.analytic)) if v}
    plan = make_plan(scene, args.elements and args.elements.split(","),
                     args.levels and [float(v) for v in args.levels.split(",")], ref,
                     parse_sets(args.set), study)
    return scene, plan


def run(args) -> int:
    """Exit 0 on success, 1 when the reference run failed (no errors to give), 2 on bad input
    (as ``q3t run``: 1 = a run failed, 2 = bad input)."""
    from sim.scene import SceneError

    try:
        scene, plan = _inputs(args)
    except (SceneError, ValueError) as exc:
        print(f"q3t study: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out or f"runs/study-{Path(scene).stem}")
    kw = {"workers": args.workers, "threads": args.threads, "scheduler": args.scheduler,
          "timeout": args.timeout}
    where = cluster_text(args.workers, args.threads, args.scheduler)
    if args.factorisation:
        rows = factorisation_times(scene, plan.elements, plan.levels,
                                   args.repeat or FACTOR_REPEAT, plan.overrides, **kw)
        print(_table(rows, FACTOR_COLS))
        write_factorisation(scene, rows, out, where)
    elif args.overhead_only:
        o = {"overrides": {**plan.overrides, "mesh.edge_length": plan.levels[-1]},
             "repeat": args.repeat or OVERHEAD_REPEAT}
        rows, _ = run_tasks([(terms_overhead, scene, o["overrides"], o["repeat"])], [{}],
                            **kw)
        if "lean" not in rows[0]:
            print(f"q3t study: the timing run ended {rows[0]['status']}: {rows[0]['reason']}",
                  file=sys.stderr)
            return 1
        write_overhead(rows, out, where)
        print(overhead_md(rows))
    else:
        overhead = None if args.no_overhead else {
            "overrides": {**plan.overrides, "mesh.edge_length":
                          plan.levels[len(plan.levels) // 2]},
            "repeat": args.repeat or OVERHEAD_REPEAT}
        try:
            study = run_study(plan, lambda s: print(s, file=sys.stderr, flush=True),
                              overhead=overhead, **kw)
        except StudyError as exc:
            print(f"q3t study: {exc}", file=sys.stderr)
            return 1
        overheads = [study["overhead"]] if study["overhead"] else []
        write_study(study, overheads, out, args.workers, args.scheduler)
        print(_table(study["rows"], STUDY_COLS) + (overhead_md(overheads) if overheads else ""))
    print(f"wrote {out}/report.md, report.json and plots")
    return 0


def add_parser(sub) -> None:
    s = sub.add_parser("study", help="error against run time and DoFs under refinement")
    s.add_argument("scene", help="scene name in scenes/ or a TOML path")
    s.add_argument("--elements", help="comma-separated (default: the scene's study table)")
    s.add_argument("--levels", help="comma-separated mesh edge lengths in m")
    s.add_argument("--reference", metavar="ELEMENT:EDGE",
                   help="a numerical reference run, e.g. quadratic:0.0035")
    s.add_argument("--analytic", help="closed-form reference: euler_bernoulli, springback")
    s.add_argument("--probe", help="the probe to measure (study.probe)")
    s.add_argument("--measure", choices=["final", "curve", "profile"],
                   help="study.measure: the final value, the curve over the run, a profile")
    s.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="a scene override for every case, e.g. material.nu=0 (repeatable)")
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
    s.add_argument("--out", help="output folder (default runs/study-<scene>)")
    s.set_defaults(func=run)

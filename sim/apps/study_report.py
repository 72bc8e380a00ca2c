"""``q3t study``'s outputs: report.md (tables), report.json, and the plots (PNG and SVG,
matplotlib): error against run time and DoFs, factorisation time against elements and nodes."""

from __future__ import annotations

import math
import os
import platform
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from sim.frames import results

if TYPE_CHECKING:
    from matplotlib.figure import Figure

MARKERS = {"linear": "o", "q3t": "s", "quadratic": "^", "quartic": "D"}


def _save(fig: Figure, out: Path, stem: str) -> list[str]:
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
                  and r["error"] is not None and r["error"] > 0]
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


def markdown_table(rows: list[dict], cols: list[tuple[str, str, str]]) -> str:
    lines = ["| " + " | ".join(c[1] for c in cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        lines.append("| " + " | ".join(format(r[k], f) if r.get(k) is not None else ""
                                       for k, _, f in cols) + " |")
    return "\n".join(lines) + "\n"


STUDY_COLS = [("element", "element", ""), ("edge_length", "edge [m]", ".5g"),
              ("elements", "triangles", "d"), ("dofs", "DoFs", "d"), ("probe", "probe", ".6g"),
              ("ratio", "probe / ref.", ".5f"), ("error", "rel. error", ".3e"),
              ("time", "time [s]", ".3f"),
              ("iterations", "Newton it.", "d"), ("status", "status", "")]
FACTOR_COLS = [("element", "element", ""), ("edge_length", "edge [m]", ".5g"),
               ("elements", "elements", "d"), ("nodes", "nodes", "d"), ("dofs", "DoFs", "d"),
               ("nnz_upper", "nnz (upper)", "d"), ("factorisation", "median [s]", ".4f"),
               ("factorisation_min", "min [s]", ".4f"), ("status", "status", "")]


RATES = (0.05, 8.0)  # fitted rates searched; a mesh error shrinking slower or faster is noise


def richardson(h: Sequence[float], w: Sequence[float]) -> tuple[float, float]:
    """Richardson extrapolation with a fitted rate: w(h) = w_0 + C h^r through three levels
    h[0] > h[1] > h[2] (any ratios); returns (w_0, r). ValueError when no rate in ``RATES``
    fits: the three values are not monotone, or not yet in their asymptotic range."""
    from scipy.optimize import brentq

    if w[2] == w[1] or (w[1] - w[0]) / (w[2] - w[1]) <= 0:
        raise ValueError("the values are not monotone")
    target = (w[1] - w[0]) / (w[2] - w[1])

    def mismatch(r: float) -> float:
        return (h[1] ** r - h[0] ** r) / (h[2] ** r - h[1] ** r) - target

    if mismatch(RATES[0]) * mismatch(RATES[1]) > 0:
        raise ValueError(f"the steps between them shrink at no rate in {RATES[0]:g}-"
                         f"{RATES[1]:g}")
    r = brentq(mismatch, *RATES)
    c = (w[2] - w[1]) / (h[2] ** r - h[1] ** r)
    return float(w[2] - c * h[2] ** r), float(r)


def _extrapolated(rows: list[dict], ref: float | None) -> dict:
    """One element's finest three converged ``rows`` (coarse to fine) extrapolated."""
    h, w = [r["edge_length"] for r in rows], [r["probe"] for r in rows]
    out = {"element": rows[0]["element"], "edges": ", ".join(f"{x:.5g}" for x in h)}
    try:
        limit, rate = richardson(h, w)
    except ValueError as exc:
        return {**out, "fit": f"none: {exc}"}
    return {**out, "rate": rate, "limit": limit, "fit": "",
            "ratio": limit / ref if ref else None}


def extrapolations(study: dict) -> list[dict]:
    """Each element's final probe extrapolated to zero edge length through its three finest
    converged levels (``richardson``), against the reference; none for a curve or profile
    measure or an element with fewer than three levels."""
    p = study["plan"]
    if p["measure"]["measure"] != "final":
        return []
    ref = p["analytic"]["value"] if p["analytic"] else study["reference"].get("value")
    out = []
    for el in p["elements"]:
        rows = sorted((r for r in study["rows"] if r["element"] == el
                       and r["status"] == "converged" and r["probe"] is not None),
                      key=lambda r: -r["edge_length"])[-3:]
        if len(rows) == 3:
            out.append(_extrapolated(rows, ref))
    return out


EXTRAPOLATION_COLS = [("element", "element", ""), ("edges", "levels [m]", ""),
                      ("rate", "rate r", ".3f"), ("limit", "limit", ".6g"),
                      ("ratio", "limit / ref.", ".4f"), ("fit", "fit", "")]


def extrapolation_md(rows: list[dict]) -> str:
    return ("Richardson extrapolation through each element's three finest levels, w(h) = w_0 + "
            "C h^r with the rate r fitted to them (a rate outside about 1-3 means the levels are "
            "not yet in their asymptotic range and the limit is noise):\n\n"
            + markdown_table(rows, [c for c in EXTRAPOLATION_COLS
                                    if c[0] != "fit" or any(r["fit"] for r in rows)]))


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
            f"{repeat} interleaved runs each.\n\n" + markdown_table(rows, cols))


def _meta() -> str:
    return (f"{time.strftime('%Y-%m-%d')}, {platform.machine()} with {os.cpu_count()} cores, "
            f"Python {platform.python_version()}")


def _how(cluster: str, workers: int, scheduler: str | None) -> str:
    s = (f"Cases ran as Dask tasks on {cluster}; each worker ran every element once on the "
         "coarsest level first (warm-up, not timed). Times are build plus solve of one case.")
    if not scheduler and workers > 1:
        s += (f" {workers} cases ran at once on {os.cpu_count()} cores: they shared the "
              "machine, so the times are inflated and noisy; use --workers 1 for timings.")
    return s


def study_md(study: dict, overheads: list[dict], workers: int = 1,
             scheduler: str | None = None) -> str:
    """The study below its title: reference, how the cases ran, notes, the table and the
    overhead (report.md, and ``q3t study --results``)."""
    p, ref = study["plan"], study["reference"]
    notes = list(p["notes"])
    if p["reference"] and p["reference"][0] in p["elements"]:  # its rows converge to themselves
        notes.append(f"{p['reference'][0]} rows: error against the same element on a finer "
                     "mesh (self-convergence, an underestimate)")
    if not study["finished"]:
        notes.append("the study's --timeout ended it: unfinished cases are marked timeout")
    if study.get("overhead_failed"):
        notes.append(f"the lean against all-terms timing failed: {study['overhead_failed']}")
    if study.get("changes"):
        notes.append("the scene as a run changed it: " + "; ".join(study["changes"]))
    if p["analytic"]:
        head = f"reference **{p['analytic']['name']} (analytic)**: {p['analytic']['about']}."
    else:
        el, edge = p["reference"]
        value = f": {ref['value']:.8g}" if "value" in ref else ""
        head = (f"reference **{el} at edge {edge:.6g} m** (a numerical run, {ref['dofs']} "
                f"DoFs){value}.")
    md = [f"Measure `{p['probe']}`; {head}\n\n",
          _how(study["cluster"], workers, scheduler) + "\n\n",
          *[f"- overrides of every case: `{p['overrides']}`\n" for _ in [0] if p["overrides"]],
          *[f"- {n}\n" for n in notes], "\n" if notes or p["overrides"] else "",
          markdown_table(study["rows"], STUDY_COLS)]
    if extrapolated := extrapolations(study):
        md += ["\n## Extrapolated to zero edge length\n\n", extrapolation_md(extrapolated)]
    if overheads:
        md += ["\n## Leave out what a scene does not need\n\n", overhead_md(overheads)]
    return "".join(md)


def _images(plots: list[str]) -> str:
    return "".join(f"![{f}]({f})\n" for f in plots if f.endswith(".png"))


def write_study(study: dict, overheads: list[dict], out: Path, workers: int = 1,
                scheduler: str | None = None) -> None:
    out.mkdir(parents=True, exist_ok=True)
    plots = plot_study(study, out)
    md = (f"# Refinement study: {Path(study['plan']['scene']).stem}\n\n{_meta()}.\n\n"
          + study_md(study, overheads, workers, scheduler) + "\n" + _images(plots))
    (out / "report.md").write_text(md)
    # renamed into place: a study ended mid-write (cancelled from the page) leaves the last
    # report whole, which the runs' estimates read
    tmp = out / ".report.json.tmp"
    tmp.write_text(results.dumps({"study": study, "overhead": overheads}, nulls=True,
                                 indent=1, default=float))
    os.replace(tmp, out / "report.json")


def overhead_report(overheads: list[dict], cluster: str) -> str:
    return f"Ran on {cluster}.\n\n" + overhead_md(overheads)


def write_overhead(overheads: list[dict], out: Path, cluster: str) -> None:
    out.mkdir(parents=True, exist_ok=True)
    md = (f"# Leave out what a scene does not need\n\n{_meta()}.\n\n"
          + overhead_report(overheads, cluster))
    (out / "report.md").write_text(md)
    (out / "report.json").write_text(results.dumps({"overhead": overheads}, nulls=True,
                                                   indent=1))


def factorisation_md(rows: list[dict], cluster: str = "") -> str:
    """The factorisation times below their title (report.md, ``--results``)."""
    ok = [r for r in rows if "factorisation" in r]
    return (f"Solver {ok[0]['solver'] if ok else '-'}; median and minimum of "
            f"{ok[0]['repeat'] if ok else 0} `solver.factor` calls per case (after one dropped "
            f"call); ran on {cluster}.\n\n" + markdown_table(rows, FACTOR_COLS))


def write_factorisation(scene: str, rows: list[dict], out: Path, cluster: str = "") -> None:
    out.mkdir(parents=True, exist_ok=True)
    plots = plot_factorisation(rows, out)
    md = (f"# Factorisation of the Hessian at rest: {Path(scene).stem} (paper Fig. 7)\n\n"
          f"{_meta()}.\n\n" + factorisation_md(rows, cluster) + "\n" + _images(plots))
    (out / "report.md").write_text(md)
    (out / "report.json").write_text(results.dumps({"scene": scene, "factorisation": rows},
                                                   nulls=True, indent=1))

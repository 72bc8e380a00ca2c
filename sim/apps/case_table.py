"""The measured table of ``q3t sweep --results`` and ``q3t run --results``: one column per
case, one row per quantity an engineer reads, each in the unit the page shows (kN, mm, MPa, %;
sim.frames.units).

A case is the small dict of ``sim.apps.cases.run_case`` (``row_of_result`` makes one of a
result.json). Its rows: the status; the run summary's quantities (sim.frames.summary); every
probe at the final state and, for a part that was released, also at the end of the stroke
(``loaded``) with the ratios asked for (``released / loaded``: the curvature a bent strip
retains); the plastic fields' mean and largest value; what the run cost.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

from sim.frames.probes import PROBES
from sim.frames.units import DISPLAY

# result.json's field statistics the table shows (sim.frames.fields.output_fields: vertex
# values, each the mean of its elements' quadrature points), SI unit
FIELDS = (("net_plastic_strain", "Net plastic strain (retained)", "1"),
          ("eq_plastic_strain", "Accumulated eq. plastic strain", "1"),
          ("von_mises", "Von Mises stress", "Pa"))

Row = tuple[str, list[str]]  # (quantity, one cell per case)


def shown(value: float | None, unit: str) -> str:
    """An SI value in the unit the page shows, 4 significant digits; blank when missing."""
    if value is None or not isinstance(value, (int, float)):
        return ""
    if not math.isfinite(value):
        return str(value)
    return f"{value * DISPLAY[unit][1] + 0.0:.4g}"  # + 0.0: a -0.0 reads 0


def _with_unit(label: str, unit: str) -> str:
    shown_unit = DISPLAY[unit][0]
    return f"{label} [{shown_unit}]" if shown_unit else label


def probe_units(scene: object) -> dict[str, str]:
    """Each probe's SI unit, from its kind (sim.frames.probes)."""
    return {p.name: PROBES[p.kind].unit for p in scene.probes}


def _summary_rows(cases: list[dict]) -> list[Row]:
    keys: dict[tuple, tuple[str, str]] = {}  # (name, tool) -> (label, unit), first-seen order
    for c in cases:
        for e in c.get("summary") or []:
            if not isinstance(e["value"], list):
                label = f"{e['label']} ({e['tool']})" if "tool" in e else e["label"]
                keys.setdefault((e["name"], e.get("tool")), (label, e["unit"]))
    values = [{(e["name"], e.get("tool")): e["value"] for e in c.get("summary") or []}
              for c in cases]
    return [(_with_unit(label, unit), [shown(v.get(key), unit) for v in values])
            for key, (label, unit) in keys.items()]


def _probe_rows(cases: list[dict], units: dict[str, str], ratios: Iterable[str]) -> list[Row]:
    released = any("loaded_probes" in c for c in cases)
    out = []
    for name, unit in units.items():
        if released:
            out.append((_with_unit(f"probe {name}, loaded", unit),
                        [shown((c.get("loaded_probes") or {}).get(name), unit) for c in cases]))
        label = f"probe {name}, released" if released else f"probe {name}"
        out.append((_with_unit(label, unit),
                    [shown(c.get("probes", {}).get(name), unit) for c in cases]))
    for name in ratios:
        out.append((f"probe {name}, released / loaded", [_ratio(c, name) for c in cases]))
    return out


def _ratio(case: dict, name: str) -> str:
    a, b = case.get("probes", {}).get(name), (case.get("loaded_probes") or {}).get(name)
    return f"{a / b:.4g}" if a is not None and b else ""


def _field_rows(cases: list[dict]) -> list[Row]:
    out = []
    for name, label, unit in FIELDS:
        stats = [(c.get("fields") or {}).get(name) for c in cases]
        if any(stats):
            out.append((_with_unit(f"{label}, vertex mean / max", unit),
                        [f"{shown(s['mean'], unit)} / {shown(s['max'], unit)}" if s else ""
                         for s in stats]))
    return out


def _cost_rows(cases: list[dict]) -> list[Row]:
    out = [("Newton iterations", [str(c.get("iterations", "")) for c in cases]),
           ("step cut-backs", [str(c.get("cutbacks", "")) for c in cases]),
           ("solver wall time [s]", [f"{c.get('wall', 0.0):.1f}" for c in cases]),
           ("elements", [str(c.get("elements") or "") for c in cases]),
           ("DoFs", [str(c.get("dofs") or "") for c in cases])]
    if any(c.get("reason") for c in cases):
        out.append(("reason", [(c.get("reason") or "").replace("|", "/")[:200] for c in cases]))
    return out


def table(cases: list[dict], keys: list[str], units: dict[str, str],
          ratios: Iterable[str] = ()) -> str:
    """Markdown: a column per case headed by its values of ``keys`` (the swept overrides), a
    row per quantity (see the module's doc)."""
    head = [" / ".join(keys) or "case",
            *[" / ".join(str(c["overrides"].get(k)) for k in keys) or "run" for c in cases]]
    rows = [("status", [c["status"] for c in cases]), *_summary_rows(cases),
            *_probe_rows(cases, units, ratios), *_field_rows(cases), *_cost_rows(cases)]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join([q, *cells]) + " |" for q, cells in rows]
    return "\n".join(lines) + "\n"


def row_of_result(result: dict, overrides: dict, stroke_steps: int) -> dict:
    """The case dict of a run's result.json (``q3t run``), as ``run_case`` returns one."""
    steps = result["steps"]
    loaded = [s for s in steps if s["step"] == stroke_steps]
    row = {"overrides": overrides, "status": "converged" if result["converged"] else "failed",
           "reason": (result.get("failure") or {}).get("reason"),
           "probes": steps[-1]["probes"] if steps else {}, "summary": result["summary"],
           "fields": result["fields"], "wall": result["timing"]["total"],
           "iterations": result["timing"]["newton_iterations"],
           "cutbacks": sum(s["cutbacks"] for s in steps),
           "elements": result["counts"]["elements"], "dofs": result["counts"]["dofs"]}
    if loaded and steps[-1]["step"] > stroke_steps:  # a release stage ran
        row["loaded_probes"] = loaded[-1]["probes"]
    return row


def history_table(result: dict, units: dict[str, str]) -> str:
    """Markdown: each probe over the run's steps, its final value and its extremes with the
    step they occur at (a punch force's peak, the deepest penetration)."""
    steps = result["steps"]
    lines = ["| probe | final | min (step) | max (step) |", "|---|---|---|---|"]
    for name, unit in units.items():
        vals = [(s["probes"].get(name), s["step"]) for s in steps]
        vals = [(v, k) for v, k in vals if isinstance(v, (int, float)) and math.isfinite(v)]
        if not vals:
            continue
        lo, hi = min(vals), max(vals)
        lines.append(f"| {_with_unit(name, unit)} | {shown(vals[-1][0], unit)} | "
                     f"{shown(lo[0], unit)} ({lo[1]}) | {shown(hi[0], unit)} ({hi[1]}) |")
    return "\n".join(lines) + "\n"


def sections_table(result: dict) -> str:
    """Markdown: each recorded section's thickness range at each of its steps (the radial
    section of a cup at the stages of its stroke); empty when the scene records none."""
    lines = []
    for name, recs in (result.get("sections") or {}).items():
        lines += [f"Section `{name}`:", "",
                  "| step | thickness min [mm] | max [mm] | at rest radius [mm] (min / max) |",
                  "|---|---|---|---|"]
        for r in recs:
            h, rest = r["thickness"], r["rest_radius"]
            i, j = h.index(min(h)), h.index(max(h))
            lines.append(f"| {r['step']} | {h[i] * 1e3:.4g} | {h[j] * 1e3:.4g} | "
                         f"{rest[i] * 1e3:.3g} / {rest[j] * 1e3:.3g} |")
        lines.append("")
    return "\n".join(lines)

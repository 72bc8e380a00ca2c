"""The data of the page's plots of a run, in the units an engineer reads (kN, mm, MPa, %):
each punch's force against its stroke, each probe against the step in its own unit, the
solver's residual and Newton iterations, the live-parameter changes (marks), and the thickness
along the scene's sections at their steps (result.json's, once the run has written it)."""

from __future__ import annotations

import numpy as np

from sim.frames import results
from sim.frames.probes import PROBES
from sim.frames.punch import punch_history
from sim.frames.units import measure
from sim.stepping.parameters import label

# the most steps a plot shows: a longer run's every k-th step and its last (a browser draws a
# few thousand points at once; the summary holds the exact peaks)
MAX_POINTS = 2000


def thinned(records: list[dict], most: int = MAX_POINTS) -> tuple[list[dict], int]:
    """Every k-th record and the last, at most about ``most``; and k."""
    k = max(1, -(-len(records) // most))
    if k == 1:
        return records, 1
    kept = records[k - 1::k]
    return (kept if kept[-1] is records[-1] else [*kept, records[-1]]), k


def plots(status: dict, result: dict | None) -> dict:
    """``status``: the run's status with all its records (RunManager.status); ``result``: its
    result.json, None before it is written."""
    records, stride = thinned(status["records"])
    out = {"run": status["id"], "step": status["step"], "stride": stride,
           "punches": punch_curves(records, status.get("punches") or {}),
           "probes": probe_series(records, status.get("probe_kinds") or {}),
           "solver": {"steps": [r["step"] for r in records],
                      "residual": [r["residual"] for r in records],
                      "iterations": [r["iterations"] for r in records]},
           "parameter_log": labelled(status.get("parameter_log") or []),
           "sheet": sheet_series(records),
           "sections": sections((result or {}).get("sections") or {}),
           "forming_limits": bool((result or {}).get("forming_limits"))}
    return results.finite(out)[0]  # JSON has no NaN: a missing value is null


def sheet_series(records: list[dict]) -> dict:
    """The sheet's least thickness (mm) and largest thinning (%) at each step (none for a
    run recorded before its steps held them)."""
    kept = [r for r in records if r.get("sheet")]
    return {"steps": [r["step"] for r in kept],
            "min_thickness": shown([r["sheet"]["min_thickness"] for r in kept], "m"),
            "max_thinning": shown([r["sheet"]["max_thinning"] for r in kept], "1")}


def labelled(log: list[dict]) -> list[dict]:
    """A run's live-parameter changes, each with the label the page's slider has (Friction ×)."""
    return [{**e, "label": label(e["name"])[0]} for e in log]


def shown(values: list | np.ndarray, unit: str) -> dict:
    """``{"unit", "values"}`` in the unit the page shows."""
    d = measure(values, unit)["display"]
    return {"unit": d["unit"], "values": d["value"]}


def punch_curves(records: list[dict], punches: dict[str, list[float]]) -> list[dict]:
    """Each punch's force (kN) against its stroke (mm) at the steps it is active; a punch that
    never moved has no stroke (null): its force is then plotted against the step."""
    out = []
    for tool, start in punches.items():
        rows = [(r["step"], r["tools"][tool]) for r in records if tool in (r.get("tools") or {})]
        if not rows:
            continue
        h = punch_history(rows, np.asarray(start, float))
        out.append({"tool": tool, "steps": h["steps"].tolist(), "force": shown(h["force"], "N"),
                    "stroke": None if h["stroke"] is None else shown(h["stroke"], "m")})
    return out


def probe_series(records: list[dict], kinds: dict[str, str]) -> list[dict]:
    """Each probe against the step, in the unit its kind says, as the page shows it (SI, unit
    unknown, for a run recorded before its probes' kinds were kept)."""
    names = list(records[-1]["probes"]) if records else []
    out = []
    for name in names:
        rows = [(r["step"], r["probes"].get(name)) for r in records]
        values = [np.nan if v is None else v for _, v in rows]
        kind = PROBES.get(kinds.get(name, ""))
        series = shown(values, kind.unit) if kind else {"unit": "", "values": values}
        out.append({"name": name, "kind": kinds.get(name) if kind else None,
                    "steps": [s for s, _ in rows], **series,
                    "si_unit": kind.unit if kind else None})
    return out


def probe_text(name: str, value: float, kind: str | None) -> str:
    """A probe's value as the page shows it, in its kind's unit, labelled: "punch_force =
    0.1517 kN" (a kind not known: the SI number, unlabelled)."""
    p = PROBES.get(kind or "")
    if p is None:
        return f"{name} = {value:.4g}"
    d = measure(value, p.unit)["display"]
    return f"{name} = {d['value']:.4g} {d['unit']}".rstrip()


def sections(found: dict[str, list[dict]]) -> list[dict]:
    """Each section's thickness (mm) against the rest radius (mm) at its steps, and its ray's
    angle from the x axis (deg; None for a run recorded before sections said it)."""
    return [{"name": name, "angle": rows[0].get("angle_deg") if rows else None,
             "steps": [{"step": s["step"], "position": shown(s["rest_radius"], "m"),
                        "thickness": shown(s["thickness"], "m")} for s in rows]}
            for name, rows in found.items()]

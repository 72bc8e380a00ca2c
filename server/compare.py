"""Runs side by side: what differs between them (scene, element, overrides, live parameter
changes), their force-stroke curves and probes on shared axes, their summaries with the
differences from the first run, and their final thickness on the formed part with the
difference where the meshes are the same. In the units an engineer reads (mm, kN, MPa, %).

The first run is the reference, "A"; the others are "B", "C", ... Everything is read from the
runs' folders (scene.toml, run.json via the run manager, result.json, final.npz): a run still
going is compared as far as it has got, and says so."""

from __future__ import annotations

import json
import string
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from server.plots import labelled, plots
from server.problems import Conflict, Invalid, NotFound
from server.records import ENDED
from server.scenediff import SHOWN, collapsed, flat_scene, shown, value_text
from sim.elements import ELEMENTS
from sim.frames import results
from sim.scene.load import SceneError, apply_override, read_toml, scene_from_toml, unit_of

if TYPE_CHECKING:
    from server.runs import RunManager

MAX_RUNS = len(string.ascii_uppercase)  # each run gets a letter
# a difference line names at most this many settings; the rest are in ``differs.items``
LINE_ITEMS = 6
# rest mid-surfaces closer than this (m) are the same mesh: far below any element size, far
# above the round-off of the same mesh built twice
SAME_MESH_TOL = 1e-9


@dataclass
class Loaded:
    """One run as the comparison reads it: its status with all its records, result.json
    (None before it is written) and its folder."""

    letter: str
    status: dict
    result: dict | None
    folder: Path

    @property
    def id(self) -> str:
        return self.status["id"]


def run_ids(text: str) -> list[str]:
    """The comma-separated run ids of ``?runs=``: at least two, each once (Invalid, 422)."""
    ids = [s.strip() for s in text.split(",") if s.strip()]
    if len(ids) < 2:
        raise Invalid(f"runs: {len(ids)} run(s) given; a comparison needs at least two "
                      "run ids, comma-separated")
    if len(ids) > MAX_RUNS:
        raise Invalid(f"runs: {len(ids)} runs given; at most {MAX_RUNS} at once")
    twice = sorted({i for i in ids if ids.count(i) > 1})
    if twice:
        raise Invalid(f"runs: {', '.join(twice)} named more than once")
    return ids


def load(manager: RunManager, ids: list[str]) -> list[Loaded]:
    """The runs named, in order; NotFound (404) naming every id that is no run."""
    known = set(manager.run_ids())
    unknown = [i for i in ids if i not in known]
    if unknown:
        raise NotFound(f"runs: no run {', '.join(repr(i) for i in unknown)}")
    out = []
    for letter, run_id in zip(string.ascii_uppercase, ids, strict=False):
        status = manager.status(run_id)
        folder = manager.files.dir(run_id)
        out.append(Loaded(letter, status, _result(folder, status), folder))
    return out


def _result(folder: Path, status: dict) -> dict | None:
    path = folder / "result.json"
    if status["state"] not in ENDED or not path.is_file():
        return None
    try:
        return json.loads(path.read_text())
    except ValueError:  # being written by a solver that outlived its server
        return None


def compare(runs: list[Loaded]) -> dict:
    """The comparison of ``runs`` (the first is the reference): see the module's doc."""
    drawn = [plots(r.status, r.result) for r in runs]
    out = {"runs": [_head(r, runs[0]) for r in runs],
           "differs": differences(runs),
           "punches": [{"run": r.id, "letter": r.letter, **p}
                       for r, d in zip(runs, drawn, strict=True) for p in d["punches"]],
           "probes": [{"run": r.id, "letter": r.letter, **p}
                      for r, d in zip(runs, drawn, strict=True) for p in d["probes"]],
           "summary": summary_rows(runs),
           "thickness": thickness_available(runs[0], runs[1])}
    return results.finite(out)[0]


def summary_csv(runs: list[Loaded]) -> str:
    """The comparison's summary table as CSV, as the page shows it: a row per quantity (its
    unit in its own column), each run's value (the header names the run and its element), then
    each later run's difference from A (in the row's unit:
    points for a %) and in % of A's value; six significant digits, empty where a run has none.
    A flagged value (a forming limit reached, the mesh's earing) says so in a last column."""
    import csv
    import io

    from sim.frames.export import DIGITS

    rows, letters = summary_rows(runs), [r.letter for r in runs]

    def num(v: float | None) -> str:
        return "" if v is None else f"{v:.{DIGITS}g}"

    head = ["quantity", "unit",
            *(f"{r.letter}: {r.id} ({r.status['element']}{_ended(r)})" for r in runs),
            *(f"{b} - A" for b in letters[1:]), *(f"{b} - A [% of A]" for b in letters[1:]),
            "flags"]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(head)
    for row in rows:
        flags = "; ".join(f"{x}: {f}" for x, f in zip(letters, row["flags"], strict=True) if f)
        w.writerow([row["label"] + (f" ({row['tool']})" if row["tool"] else ""), row["unit"],
                    *map(num, row["values"]), *map(num, row["delta"][1:]),
                    *map(num, row["delta_pct"][1:]), flags])
    # what the runs differ in, under the quantities (the table alone did not say which run
    # was which setting, a review): a row per setting, each run's value in the form's unit
    diff = differences(runs)
    if diff["items"] or any(diff["live"].values()):
        w.writerow([])
        w.writerow(["setting", "unit", *(f"{r.letter}: {r.id}" for r in runs)])
    for it in diff["items"]:
        label, factor = SHOWN.get(it.get("unit") or "", (it.get("unit") or "", 1.0))
        w.writerow([it["what"], label, *(value_text(v, factor, DIGITS) for v in it["values"])])
    if any(diff["live"].values()):
        w.writerow(["live changes", "", *("; ".join(
            f"{e['label']} {value_text(e['value'])} from step {e['step']}"
            for e in diff["live"].get(r.letter) or []) for r in runs)])
    return buf.getvalue()


def ended_at(r: Loaded) -> str:
    """Where a run ended: 'stopped at step 12 of 50'."""
    st = r.status
    return f"{st['state']} at step {st['step']}" + (f" of {st['n_steps']}"
                                                    if st.get("n_steps") else "")


def _ended(r: Loaded) -> str:
    """How a run that did not finish ended, for the CSV's head (its differences are empty)."""
    return "" if r.status["state"] == "finished" else f", {ended_at(r)}"


def _head(r: Loaded, a: Loaded) -> dict:
    """The run as the comparison's head shows it; ``comparable``: its summary is of the same
    stage as A's (``a``), so that differences from A are taken."""
    st = r.status
    if st["state"] not in ENDED:
        note = f"{st['state']}: compared up to step {st['step']}; its summary comes when it ends"
    elif r.result is None:
        note = "no result.json: no summary"
    else:
        note = st.get("reason")
    return {"id": r.id, "letter": r.letter, "scene": st["scene"], "element": st["element"],
            "state": st["state"], "step": st["step"], "n_steps": st.get("n_steps"),
            "overrides": st.get("overrides") or {}, "edited": bool(st.get("edited")),
            "result": r.result is not None, "note": note,
            "comparable": comparable(a, r)}


# ---- what differs --------------------------------------------------------------------------
def settings(r: Loaded) -> tuple[dict[str, object], dict[str, str]]:
    """The run's scene as it ran, flattened to dotted keys (``tools.punch.friction``): its
    scene.toml with its overrides, validated (so that defaults and number spellings compare
    equal); as written when it no longer validates (a mesh file since deleted, ...). And each
    key's schema path (``tools.0.friction``)."""
    path = r.folder / "scene.toml"
    text = path.read_text() if path.is_file() else ""
    overrides = r.status.get("overrides") or {}
    try:
        tree = scene_from_toml(text, overrides).model_dump(mode="json")
    except ValueError:  # SceneError is one
        tree = _as_written(text, overrides)
    return flat_scene(tree)


def _as_written(text: str, overrides: dict) -> dict:
    """The scene's TOML with the overrides set, not validated (an unreadable file: only the
    overrides)."""
    try:
        tree = read_toml(text)
    except SceneError:
        tree = {}
    for k, v in overrides.items():
        try:
            apply_override(tree, k, v)
        except SceneError:
            tree[k] = v
    return tree


def differences(runs: list[Loaded]) -> dict:
    """What differs between the runs: ``items`` [{what, values (one per run, null: not
    set)}] and ``line``, the sentence the page shows."""
    items = []
    scenes = [r.status["scene"] for r in runs]
    if len(set(scenes)) > 1:
        items.append({"what": "scene", "values": scenes})
    flat, paths = zip(*(settings(r) for r in runs), strict=True)
    every_path = {k: v for p in paths for k, v in p.items()}
    flat = collapsed(list(flat), every_path)
    keys = sorted({k for f in flat for k in f}, key=lambda k: (k != "shell.element", k))
    for k in keys:
        values = [f.get(k) for f in flat]
        if any(v != values[0] for v in values):
            items.append({"what": k, "values": values, "unit": unit_of(every_path[k])})
    edited = [r.letter for r in runs if r.status.get("edited")]
    live = {r.letter: labelled(r.status.get("parameter_log") or []) for r in runs}
    return {"items": items, "live": live, "edited": edited,
            "line": _line(runs, items, live, edited)}


def _line(runs: list[Loaded], items: list[dict], live: dict, edited: list[str]) -> str:
    letters = "/".join(r.letter for r in runs)
    parts = [shown(it) for it in items[:LINE_ITEMS]]
    if len(items) > LINE_ITEMS:
        parts.append(f"and {len(items) - LINE_ITEMS} more settings")
    changes = [f"{letter}: {e['label']} {value_text(e['value'])} from step {e['step']}"
               for letter, log in live.items() for e in log]
    if changes:
        parts.append("live changes " + "; ".join(changes))
    if edited:
        parts.append(f"{', '.join(edited)} ran unsaved edits of the scene")
    if not parts:
        return (f"{letters}: same scene, element, settings and no live changes: "
                "the differences are the solver's repeatability")
    return f"{letters} differ in: " + "; ".join(parts)


# ---- the summaries side by side ----------------------------------------------------------------
def summary_rows(runs: list[Loaded]) -> list[dict]:
    """One row per summary quantity (and tool) found in any run: each run's display value,
    and each run's difference from the first (``delta``, in the row's unit; ``delta_pct``,
    relative to the first's value); null where a run has no such quantity or result, and
    ``delta_pct`` null on a row in % (a thinning, a margin: its difference is in points, and
    a share of a share near zero read "-3000 %")."""
    rows: dict[tuple, dict] = {}
    for i, r in enumerate(runs):
        for e in _entries(r.result):
            row = rows.setdefault((e["name"], e.get("tool")), {
                "name": e["name"], "label": e["label"], "tool": e.get("tool"),
                "unit": e["display"]["unit"], "values": [None] * len(runs),
                "at": [None] * len(runs), "flags": [None] * len(runs),
                "note": e.get("note")})
            v = e["display"]["value"]
            row["flags"][i] = e.get("flag")
            row["values"][i] = v if isinstance(v, (int, float)) else None
            row["at"][i] = _at(e.get("at") or {})
    unlike = [not comparable(runs[0], r) for r in runs]
    for row in rows.values():
        a = row["values"][0]
        # the part of a run that ended early is the part at its last step: no difference
        # from a formed part ("punch force at the end +290 %" of a run that failed halfway);
        # the mesh's size still compares
        skip = [u and row["name"] not in SIZE_ROWS for u in unlike]
        row["delta"] = [None if a is None or v is None or k else v - a
                        for v, k in zip(row["values"], skip, strict=True)]
        row["delta_pct"] = [None if a in (None, 0) or v is None or row["unit"] == "%" or k
                            else 100 * (v - a) / abs(a)
                            for v, k in zip(row["values"], skip, strict=True)]
    return list(rows.values())


SIZE_ROWS = ("elements", "dofs")  # what a run's end does not change


def comparable(a: Loaded, b: Loaded) -> bool:
    """Whether the two runs' summaries are of the same stage of the process: both finished,
    or both ended at the same step of as many."""
    sa, sb = a.status, b.status
    done = (sa["state"] == "finished", sb["state"] == "finished")
    if all(done):
        return True
    return not any(done) and (sa["step"], sa.get("n_steps")) == (sb["step"], sb.get("n_steps"))


def _entries(result: dict | None) -> list[dict]:
    """The run's summary entries, then its size and cost."""
    if result is None:
        return []
    c, t = result.get("counts") or {}, result.get("timing") or {}
    cost = [("elements", "Elements", c.get("elements")), ("dofs", "Degrees of freedom",
                                                          c.get("dofs")),
            ("newton_iterations", "Newton iterations", t.get("newton_iterations"))]
    extra = [{"name": n, "label": label, "display": {"value": v, "unit": ""}}
             for n, label, v in cost if v is not None]
    if t.get("total") is not None:
        extra.append({"name": "solver_time", "label": "Solver wall time",
                      "display": {"value": t["total"], "unit": "s"}})
    return [*(result.get("summary") or []), *extra]


def _at(at: dict) -> str | None:
    """Where or when a quantity was found, as the page's cards say it."""
    if "stroke" in at:
        return f"at {at['stroke']['display']['value']:.3g} mm stroke"
    if "step" in at:
        return f"at step {at['step']}"
    return None


# ---- thickness on the formed part ------------------------------------------------------------
def final_state(r: Loaded) -> dict:
    """The run's mid-surface at rest and formed (m, ``(n_v, 3)``), its triangles and its
    thickness (m, ``(n_v,)``), from final.npz. Conflict (409) when the run has none yet."""
    path = r.folder / "final.npz"
    if r.status["state"] not in ENDED:
        raise Conflict(f"run {r.id!r} is {r.status['state']}: its final state is written "
                       "when it ends")
    if not path.is_file():
        raise Conflict(f"run {r.id!r} ({r.status['state']}) has no final state (final.npz): "
                       "it has not run, or ended before its first result was written")
    element = ELEMENTS.get(r.status["element"])
    try:
        with np.load(path) as f:
            data = {k: f[k] for k in ("rest", "deformed", "faces", "thickness")}
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:  # damaged
        raise Conflict(f"run {r.id!r}: its final.npz cannot be read ({exc})") from None
    if element is None:
        raise Conflict(f"run {r.id!r}: its element {r.status['element']!r} is not known here")
    n_v = len(data["thickness"])
    q = element.q
    n_plane = len(data["rest"]) // (q + 1)
    skins = np.array([np.arange(n_v), q * n_plane + np.arange(n_v)])  # bottom, top
    return {"rest": data["rest"][skins].mean(0), "formed": data["deformed"][skins].mean(0),
            "faces": data["faces"], "thickness": data["thickness"]}


def same_mesh(a: dict, b: dict, tol: float = SAME_MESH_TOL) -> str | None:
    """None when the two states are on the same mid-surface mesh (rest vertices within
    ``tol``, m), else why not."""
    na, nb = len(a["rest"]), len(b["rest"])
    if na != nb or a["faces"].shape != b["faces"].shape:
        return (f"the meshes differ: A has {na} mid-surface vertices and {len(a['faces'])} "
                f"triangles, B {nb} and {len(b['faces'])}")
    if not np.array_equal(a["faces"], b["faces"]):
        return "the meshes differ: the same counts, other triangles"
    gap = float(np.abs(a["rest"] - b["rest"]).max()) if na else 0.0
    if gap > tol:
        return f"the meshes differ: the blanks' vertices are up to {1e3 * gap:.3g} mm apart"
    return None


def thickness_available(a: Loaded, b: Loaded) -> dict:
    """Whether A and B have a thickness-difference map, and why not."""
    try:
        why = same_mesh(final_state(a), final_state(b)) or other_stage(a, b)
    except Conflict as exc:
        why = str(exc)
    return {"a": a.id, "b": b.id, "available": why is None, "reason": why}


def other_stage(a: Loaded, b: Loaded) -> str | None:
    """Why A - B of two final states is no difference of formed parts: one ended early."""
    if comparable(a, b):
        return None
    early = [f"{r.letter} {ended_at(r)}" for r in (a, b) if r.status["state"] != "finished"]
    return (f"{' and '.join(early)}: its part is not the formed one, and A − B would be the "
            "stroke's difference; the views at the same punch stroke below compare them")


def thickness(a: Loaded, b: Loaded) -> dict:
    """Each run's mid-surface at rest and formed (mm) with its triangles and thickness (mm),
    and A - B (mm, on A's vertices) where the meshes are the same; the colour range both
    share."""
    fa, fb = final_state(a), final_state(b)
    why = same_mesh(fa, fb) or other_stage(a, b)
    both = np.concatenate([fa["thickness"], fb["thickness"]])

    def part(r: Loaded, f: dict) -> dict:
        return {"id": r.id, "letter": r.letter, "faces": f["faces"].tolist(),
                "rest": np.round(1e3 * f["rest"], 4).tolist(),
                "formed": np.round(1e3 * f["formed"], 4).tolist(),
                "thickness": np.round(1e3 * f["thickness"], 5).tolist()}

    diff = None if why else np.round(1e3 * (fa["thickness"] - fb["thickness"]), 6)
    return {"unit": "mm", "a": part(a, fa), "b": part(b, fb),
            "range": [round(1e3 * float(both.min()), 5), round(1e3 * float(both.max()), 5)],
            "difference": {"available": why is None, "reason": why,
                           "values": None if diff is None else diff.tolist(),
                           "max_abs": None if diff is None else float(np.abs(diff).max())}}

"""Error estimate and cost of a finished run, from a ``q3t study`` report of its scene.

``q3t study SCENE`` writes ``runs/study-SCENE/report.json``: ``{"study": {"plan": {scene, probe,
elements, levels, reference: [element, edge] or null}, "reference": {..., "value"}, "analytic":
{name, value, about} or null, "rows": [{element, edge_length, dofs, probe, error (null when the
case has none), time, iterations, status}, ...]}, "overhead": ...}``. The
estimate of a run is the row of its element at its mesh edge length (or the nearest level, said
so), with the row's relative error and the reference it was measured against, next to the run's
own cost from its ``result.json``.

An analytic reference in the report is used instead of the numerical one: ``study.analytic``
(or ``study.reference.analytic``) as ``{"name": ..., "value": ...}`` or a bare number; a row's
error against it is its ``error_analytic`` when given, else ``|probe - value| / |value|``.
"""

from __future__ import annotations

import json
import math
import re
import threading
import time
from pathlib import Path

from server.records import Run
from sim.scene.load import Scene, scene_from_toml
from sim.text import mm

# the command that studies a scene whose mesh is refined by its edge length; a patch refined by
# cells per side is the shell obstacle course's (``q3t study SCENE`` refuses it, naming --course)
BY_EDGE = "q3t study {scene}"
COURSE = "q3t study --course"
DATE = re.compile(r"^(\d{4}-\d{2}-\d{2})\b", re.M)
SAME_EDGE = 1e-3  # relative: levels are written with 5-6 significant digits


def _stem(path: str | Path) -> str:
    return Path(str(path)).stem


_cache: dict[Path, tuple[int, object]] = {}


def _read(path: Path) -> object:
    """The report's JSON, None when unreadable. Cached by modification time."""
    try:
        mtime = path.stat().st_mtime_ns
    except OSError:
        return None
    hit = _cache.get(path)
    if hit and hit[0] == mtime:
        return hit[1]
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        data = None
    _cache[path] = (mtime, data)
    return data


def _load(path: Path) -> dict | None:
    """The report's ``study`` part, or None when it is not a refinement study (a factorisation
    report, an unreadable file)."""
    data = _read(path)
    study = data.get("study") if isinstance(data, dict) else None
    if not (isinstance(study, dict) and isinstance(study.get("rows"), list)
            and isinstance(study.get("plan"), dict)):
        return None
    return study if "date" in study else {**study, "date": data.get("date") or _date(path)}


def _date(report: Path) -> str:
    """The day of the study: the first line of report.md's header, else the file's mtime."""
    md = report.with_name("report.md")
    try:
        m = DATE.search(md.read_text()[:2000])
        if m:
            return m.group(1)
    except OSError:
        pass
    return time.strftime("%Y-%m-%d", time.localtime(report.stat().st_mtime))


def find_study(root: Path, scene: str) -> tuple[Path, dict] | None:
    """``root/study-<scene>/report.json`` first, else the newest ``root/study*/report.json``
    whose plan names the scene."""
    first = root / f"study-{scene}" / "report.json"
    study = _load(first)
    if study is not None and _stem(study["plan"].get("scene", scene)) == scene:
        return first, study
    found = []
    for p in root.glob("study*/report.json"):
        s = _load(p)
        if s is not None and _stem(s["plan"].get("scene", "")) == scene:
            found.append((p.stat().st_mtime, p, s))
    if not found:
        return None
    _, p, s = max(found, key=lambda t: t[0])
    return p, s


def find_course(root: Path, scene: str) -> tuple[Path, list[dict]] | None:
    """The newest ``q3t study --course`` report (``root/*course*/report.json``: a row per
    case, ``{scene, element, cells, ratio (probe / published), status, ...}``) with rows of
    ``scene``, and those rows."""
    found = []
    for p in root.glob("*course*/report.json"):
        data = _read(p)
        rows = [r for r in data if isinstance(r, dict) and r.get("scene") == scene] \
            if isinstance(data, list) else []
        if rows:
            found.append((p.stat().st_mtime, p, rows))
    return max(found, key=lambda t: t[0])[1:] if found else None


def seconds(s: float) -> str:
    if s < 0.1:
        return f"{1000 * s:.2g} ms"
    return f"{s:.2f} s" if s < 1 else f"{s:.1f} s" if s < 10 else f"{s:.0f} s"


def percent(e: float) -> str:
    return f"{100 * e:.2g} %"


def reference_of(study: dict) -> dict:
    ref = study.get("reference") or {}
    an = study.get("analytic", ref.get("analytic") if isinstance(ref, dict) else None)
    if isinstance(an, (int, float)) and not isinstance(an, bool):
        an = {"value": float(an)}
    if isinstance(an, dict) and isinstance(an.get("value"), (int, float)):
        name = an.get("name") or "analytic solution"
        return {"kind": "analytic", "name": name, "value": float(an["value"]),
                "label": f"{name} (analytic)"}
    el, edge = (study["plan"].get("reference") or [None, None])[:2]
    return {"kind": "numerical", "element": el, "edge_length": edge,
            "value": ref.get("value") if isinstance(ref, dict) else None,
            "label": f"{el} at {mm(edge)}" if edge else str(el)}


def row_error(row: dict, ref: dict) -> float | None:
    if ref["kind"] == "analytic":
        if isinstance(row.get("error_analytic"), (int, float)):
            return float(row["error_analytic"])
        p = row.get("probe")
        if isinstance(p, (int, float)) and ref["value"]:
            return abs(p - ref["value"]) / abs(ref["value"])
        return None
    e = row.get("error")
    return float(e) if isinstance(e, (int, float)) else None


def cost_of(result: dict | None) -> dict | None:
    if not result:
        return None
    t = result.get("timing") or {}
    c = result.get("counts") or {}
    return {"wall_s": t.get("total"), "newton_iterations": t.get("newton_iterations"),
            "per_iteration_s": t.get("per_iteration"), "dofs": c.get("dofs"),
            "steps": len(result.get("steps") or [])}


def cost_text(cost: dict | None) -> str:
    if not cost or cost.get("wall_s") is None:
        return ""
    s = f"cost {seconds(cost['wall_s'])}"
    if cost.get("newton_iterations") is not None:
        s += f", {cost['newton_iterations']} Newton iterations"
        if cost.get("per_iteration_s"):
            s += f" ({seconds(cost['per_iteration_s'])} per iteration)"
    return s


def study_command(scene: Scene) -> str | None:
    """The command whose report gives ``scene`` its estimate (a template of ``scene``, the
    file's name), or None when no study refines its mesh (a mesh read from a file). A patch
    refined by cells per side with a published value is one of the shell obstacle course's."""
    if hasattr(scene.mesh, "cells"):
        st = scene.study
        return COURSE if st is not None and st.cells and st.published is not None else None
    return BY_EDGE if getattr(scene.mesh, "edge_length", None) is not None else None


def estimate(root: Path, scene: str, element: str, edge_length: float | None,
             result: dict | None, changes: list[str] | None = None,
             command: str | None = BY_EDGE, cells: int | None = None) -> dict:
    """What the page shows for a finished run: ``available``, ``text`` and the numbers.
    ``changes``: what the run changed of its saved scene, in words, less what a study varies
    itself (server.records.Run.changes); ``command``: what studies the scene
    (:func:`study_command`); ``cells``: a course scene's cells per side."""
    cost = cost_of(result)
    out: dict = {"available": False, "scene": scene, "element": element,
                 "edge_length": edge_length, "cost": cost, "notes": []}
    changes = list(changes or [])
    if command == COURSE:
        head = _course(out, root, scene, element, cells)
        studied: list[str] = []  # the course runs its scenes as saved
    else:
        command = command.format(scene=scene) if command is not None else None
        head = _compare(out, root, scene, element, edge_length, command)
        studied = list((out.pop("studied", None)) or [])
    if out["available"] and changes != studied:
        # a study of a run's edits gives its scene's other runs their estimates too: each
        # says what it ran that the study did not, or the other way round
        said = [f"the scene with {'; '.join(c)}" if c else "the scene as saved"
                for c in (studied, changes)]
        out["notes"].append(f"the study ran {said[0]}; this run ran {said[1]}")
    out["text"] = "; ".join(s for s in (head, cost_text(cost)) if s)
    return out


def _course(out: dict, root: Path, scene: str, element: str, cells: int | None) -> str:
    """Fill ``out`` from the shell obstacle course's row of the run's element and cells per
    side: its error against the published value; returns the head line, or why there is none
    (then ``out["reason"]`` says so in a word)."""
    found = find_course(root, scene)
    if found is None:
        out["reason"] = "no_study"
        return f"no study for this scene: run `{COURSE}` (each of its scenes against its " \
               "published value)"
    path, rows = found
    when = f"shell obstacle course of {_date(path)}"
    row = next((r for r in rows if r.get("element") == element and r.get("cells") == cells),
               None)
    if row is None or not isinstance(row.get("ratio"), (int, float)):
        out["reason"] = "element_not_studied" if row is None else "no_error"
        return (f"the {when} has no {element} result at {cells} cells: run "
                f"`{COURSE} --elements {element} --cells {cells}`")
    err = abs(row["ratio"] - 1)
    out["study"] = {"path": str(path), "date": _date(path)}
    out["reference"] = {"kind": "published", "label": "the published value",
                        "value": row["probe"] / row["ratio"] if row["ratio"] else None}
    out.update(available=True, relative_error=err, row=row, match="exact")
    return f"error estimate: {percent(err)} vs the published value ({when})"


def _compare(out: dict, root: Path, scene: str, element: str, edge_length: float | None,
             command: str | None) -> str:
    """Fill ``out`` from the study row of the run's element and edge length; returns the
    head line, or why there is no estimate (then ``out["reason"]`` says so in a word)."""
    found = find_study(root, scene) if command is not None else None
    if found is None:
        out["reason"] = "no_study"
        if command is None:
            return "no study for this scene: no study refines its mesh (read from a file)"
        return f"no study for this scene: run `{command}`"
    path, study = found
    ref = reference_of(study)
    plan = study["plan"]
    out["study"] = {"path": str(path), "date": study.get("date"), "probe": plan.get("probe"),
                    "elements": plan.get("elements"), "levels": plan.get("levels")}
    out["reference"] = ref
    out["studied"] = study.get("changes") or []  # what the study ran of a run's changes
    when = f"study of {study.get('date')}"
    row, missing = _nearest_row(study, command, element, edge_length, when)
    if row is None:
        out["reason"], head = missing
        return head
    exact = abs(row["edge_length"] / edge_length - 1) <= SAME_EDGE
    err = row_error(row, ref)
    if err is None:
        out["reason"] = "no_error"
        return f"the {when} has no error for {element} at {mm(row['edge_length'])}"
    out.update(available=True, relative_error=err, row=row,
               match="exact" if exact else "nearest")
    out["notes"] += _notes(row, ref, element, edge_length, exact)
    head = f"error estimate: {percent(err)} vs {ref['label']}"
    if not exact:
        head += f" at the nearest studied level {mm(row['edge_length'])}"
    return head + f" ({when})"


def _nearest_row(study: dict, command: str, element: str, edge_length: float | None,
                 when: str) -> tuple[dict | None, tuple[str, str]]:
    """The study's row of ``element`` nearest to ``edge_length`` (on a log scale), or None
    with (reason, text); ``command`` studies the scene."""
    rows = [r for r in study["rows"] if r.get("element") == element
            and isinstance(r.get("edge_length"), (int, float)) and r["edge_length"] > 0]
    if not rows:
        studied = ", ".join(sorted({str(r.get("element")) for r in study["rows"]}))
        return None, ("element_not_studied",
                      f"the {when} has no {element} rows (it has {studied}): run "
                      f"`{command} --elements {element}`")
    if edge_length is None or edge_length <= 0:
        return None, ("no_edge_length", f"the run's mesh has no edge length to match the {when}")
    return min(rows, key=lambda r: abs(math.log(r["edge_length"] / edge_length))), ("", "")


def _notes(row: dict, ref: dict, element: str, edge_length: float, exact: bool) -> list[str]:
    """What qualifies the estimate: a level not the run's, a study run that did not
    converge, self-convergence."""
    notes = []
    if not exact:
        notes.append(f"nearest studied level: {mm(row['edge_length'])} (the run used "
                     f"{mm(edge_length)})")
    if row.get("status") not in (None, "converged"):
        notes.append(f"the study's run at this level ended {row['status']}")
    if ref["kind"] == "numerical" and ref.get("element") == element:
        notes.append(f"{element} against {element} on a finer mesh: self-convergence, "
                     "an underestimate")
    return notes


class EstimateCache:
    """Each finished run's estimate, kept until a study report of its scene appears or
    changes. Reads files: never call it holding the run lock."""

    def __init__(self, root: Path):
        self.root = root
        self._lock = threading.Lock()
        self._facts: dict[str, tuple] = {}  # run id -> (edge, result.json, command, cells)
        self._keys: dict[str, tuple | None] = {}  # run id -> the study report it used

    def get(self, run: Run, finished: bool = False) -> dict | None:
        """The estimate of ``run``, stored on it; None unless it is
        finished. ``finished``: the run is finishing (its state is set after this)."""
        if run.state != "finished" and not finished:
            return None
        with self._lock:
            try:
                found = find_study(self.root, run.scene) or find_course(self.root, run.scene)
                key = (str(found[0]), found[0].stat().st_mtime_ns) if found else None
                if run.estimate is None or self._keys.get(run.id, "?") != key:
                    edge, result, command, cells = self._facts_of(run)
                    run.estimate = estimate(self.root, run.scene, run.element, edge, result,
                                            run.changes(studied=True), command, cells)
                    self._keys[run.id] = key
            except Exception as exc:  # never let the estimate break a status request
                run.estimate = {"available": False, "reason": "error",
                                "text": f"no error estimate: {exc}", "notes": []}
            return run.estimate

    def forget(self, run_id: str) -> None:
        with self._lock:
            self._facts.pop(run_id, None)
            self._keys.pop(run_id, None)

    def _facts_of(self, run: Run) -> tuple[float | None, dict | None, str | None,
                                           int | None]:
        """The run's edge length, the command that studies it and its cells per side (from
        its scene.toml), and its result.json; read once."""
        if run.id not in self._facts:
            d = self.root / run.id
            try:
                sc = scene_from_toml((d / "scene.toml").read_text(), run.overrides)
                # a mesh file or a patch refined by cells has no edge length
                edge, command = getattr(sc.mesh, "edge_length", None), study_command(sc)
                cells = getattr(sc.mesh, "cells", None)
            except (OSError, ValueError):
                edge, command, cells = None, BY_EDGE, None
            try:
                result = json.loads((d / "result.json").read_text())
            except (OSError, ValueError):
                result = None
            self._facts[run.id] = (edge, result, command, cells)
        return self._facts[run.id]

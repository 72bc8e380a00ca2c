"""The cases of a ``q3t sweep`` opened as runs, to compare them on the page.

A sweep written inside the runs folder (``q3t sweep SCENE --grid ... --out runs/NAME``) holds
``sweep.json`` and a folder per case that ran (``cases/NNN``: scene.toml, result.json,
final.npz, case.json, the frames it saved; sim.apps.cases.write_case). Importing it copies
each such case into a run folder of its own with a run.json, as a finished (or failed) run
(its frames too: it compares at a stroke); the sweep's folder is left as it is. A sweep is
named by its path inside the runs folder, so a request can make the server read nothing
outside it. A case imported before keeps its run (importing again adds only what is new); a
case whose folder is incomplete (killed over its budget) is skipped with the reason."""

from __future__ import annotations

import json
import os
import re
import secrets
import shutil
from pathlib import Path, PurePosixPath

from server.problems import Invalid, NotFound
from server.records import Run
from server.settings import RUN_ID_MAX, check_name
from server.store import atomic_write
from sim.frames import results, series

CASE_FILES = ("scene.toml", "result.json", "final.npz")


def sweep_folder(runs_dir: Path, path: str) -> Path:
    """The sweep folder ``path`` names inside ``runs_dir`` (one or two folder names, as
    ``find`` lists them): Invalid (422) for any other path or one that leads out of it,
    NotFound (404) when there is no sweep.json there."""
    parts = path.split("/")
    if len(parts) > 2 or not all(_is_name(p) for p in parts):
        raise Invalid(f"path: {path[:100]!r} must be a sweep folder inside the runs folder, "
                      "relative to it: one or two folder names (letters, digits, '_', '-', "
                      "'.'), no '..', '\\' or absolute path")
    root = runs_dir.resolve()
    full = (root / path).resolve()
    if not full.is_relative_to(root):
        raise Invalid(f"path: {path!r} leads out of the runs folder")
    if not (full / "sweep.json").is_file():
        raise NotFound(f"path: no sweep in {path!r} (no sweep.json there; write one with "
                       f"q3t sweep ... --out {runs_dir.name}/{path})")
    return full


def _is_name(text: str) -> bool:
    try:
        return bool(check_name(text, "path"))
    except Invalid:
        return False


def find(runs_dir: Path, known: set[str]) -> list[dict]:
    """The sweeps in the runs folder (sweep.json up to two folders deep): path, scene, grid,
    cases that ran, and how many of them are runs already (``known``: the run ids)."""
    out = []
    for p in sorted([*runs_dir.glob("*/sweep.json"), *runs_dir.glob("*/*/sweep.json")]):
        try:
            head = json.loads(p.read_text())
        except (OSError, ValueError):
            continue
        rel = p.parent.relative_to(runs_dir).as_posix()
        folders = [c["folder"] for c in head.get("cases", []) if c.get("folder")]
        out.append({"path": rel, "scene": Path(str(head.get("scene", ""))).stem,
                    "grid": head.get("grid") or {}, "complete": bool(head.get("complete")),
                    "cases": len(head.get("cases", [])), "with_results": len(folders),
                    "imported": sum(run_id(rel, f) in known for f in folders)})
    return out


def run_id(sweep: str, folder: str) -> str:
    """The run id of a sweep's case: ``sweep-<path>-<case>``, within the run id rule."""
    text = re.sub(r"[^A-Za-z0-9_-]+", "-", f"{sweep}-{PurePosixPath(folder).name}").strip("-")
    return f"sweep-{text}"[-RUN_ID_MAX:].lstrip("-_") or "sweep"


def case_run(run_id: str, case_dir: Path) -> Run:
    """A finished (or failed) run of a case's folder, as run.json holds it."""
    res = json.loads((case_dir / "result.json").read_text())
    case = json.loads((case_dir / "case.json").read_text())
    steps = res.get("steps") or []
    failure, stopped = res.get("failure"), res.get("stopped")
    state = "finished" if res.get("converged") else "stopped" if stopped else "failed"
    reason = None if state == "finished" else (
        stopped or (failure or {}).get("reason") or case.get("reason"))
    ended = (case_dir / "result.json").stat().st_mtime
    wall = float((res.get("timing") or {}).get("total") or 0.0)
    return Run(run_id, res["scene"], res["element"], case.get("overrides") or {},
               created=ended - wall, state=state, reason=reason,
               step=steps[-1]["step"] if steps else 0,
               n_steps=steps[-1]["step"] if state == "finished" and steps else None,
               counts=res.get("counts"), probes=list(case.get("probe_kinds") or {}),
               tools=sorted({t for s in steps for t in (s.get("tools") or {})}),
               parameter_log=res.get("parameters") or [], records=steps,
               punches=case.get("punches") or {}, probe_kinds=case.get("probe_kinds") or {},
               stepping_s=wall, ended=ended)


def import_sweep(runs_dir: Path, path: str, known: set[str]) -> tuple[list[Run], dict]:
    """Each case of the sweep at ``path`` with a complete folder, as a new run folder in
    ``runs_dir`` (made under a temporary name, then renamed: never half a run). Returns the
    new runs and the report: ``imported``, ``present`` (run ids) and ``skipped`` [{case,
    reason}]."""
    folder = sweep_folder(runs_dir, path)
    rel = folder.relative_to(runs_dir.resolve()).as_posix()
    cases = json.loads((folder / "sweep.json").read_text()).get("cases", [])
    new, report = [], {"sweep": rel, "imported": [], "present": [], "skipped": []}
    for i, row in enumerate(cases):
        case = row.get("folder")
        why = _incomplete(folder, case, row)
        if why:
            report["skipped"].append({"case": i, "reason": why})
            continue
        rid = run_id(rel, case)
        run = None if rid in known else _copy(runs_dir, rid, folder / case)
        if run is None:
            report["present"].append(rid)
            continue
        new.append(run)
        report["imported"].append(rid)
    return new, report


def _incomplete(sweep: Path, case: str | None, row: dict) -> str | None:
    if not case:
        return f"{row.get('status', 'no result')}: {row.get('reason') or 'no case folder'}"
    where = (sweep / case).resolve()
    if not where.is_relative_to(sweep):
        return f"its folder {case!r} is outside the sweep"
    missing = [f for f in (*CASE_FILES, "case.json") if not (where / f).is_file()]
    return f"{case}: no {', '.join(missing)}" if missing else None


def _copy(runs_dir: Path, rid: str, case_dir: Path) -> Run | None:
    """The case as the run ``rid``; None when that run exists (imported before, or by an
    import at the same time: the rename of the second fails)."""
    if (runs_dir / rid).exists():
        return None
    run = case_run(rid, case_dir)
    tmp = runs_dir / f".import-{rid}-{secrets.token_hex(4)}"
    tmp.mkdir()
    try:
        for name in CASE_FILES:
            shutil.copyfile(case_dir / name, tmp / name)
        if (case_dir / series.FOLDER).is_dir():  # a case from before sweeps saved frames: none
            shutil.copytree(case_dir / series.FOLDER, tmp / series.FOLDER)
        atomic_write(tmp / "run.json", results.dumps(run.snapshot(), indent=1))
        os.rename(tmp, runs_dir / rid)  # onto a folder of that name: OSError, nothing changed
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        if (runs_dir / rid).is_dir():
            return None
        raise
    return run

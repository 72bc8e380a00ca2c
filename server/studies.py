"""Refinement studies started from the page: ``q3t study`` of a finished run's scene, for
/api/studies.

A study runs each element of its plan at each mesh level, and a reference: minutes to hours
(the cup's default plan has the quadratic prism at 1 mm over the whole stroke). So the page
shows the plan first, each case's size from the mesh parameters alone (sim.model.size: DoFs and
the build's memory, nothing built) and its time predicted from the run it was asked from; a
case over the server's memory limit is refused there, naming the field. Then the study runs as
the command line's ``q3t study`` in a process of its own (its Dask worker inside it: the
server never steps a solver), one study at a time (a study times its cases: two side by side
would skew both). Its progress is the command's line per case, read from its stderr; a cancel
ends its process group (the command and its Dask workers). Its report is written at its end,
renamed into place (runs/study-SCENE/report.json), where the runs' estimates
(server.estimate) read it; a study cancelled or failed leaves the last report as it was.
"""

from __future__ import annotations

import collections
import dataclasses
import math
import os
import re
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from server.problems import Conflict, Invalid
from sim.text import mm

if TYPE_CHECKING:
    from sim.refinement import Plan

# a case's time: the run's, scaled by its DoFs to this power and by the element's weight,
# the same steps and Newton iterations taken. Per iteration, over whole runs: the cup with
# q3t_ans from 858 to 6,798 DoFs and Q3T from there to 121,716 (bench.md) 0.77-1.12, the
# convergence scene from 567 to 21,744 DoFs 1.09 (small models carry a fixed cost per
# iteration, large ones a factorisation that grows faster). So it errs high scaling up from a
# small run (the cup's 2 mm cases predicted 1.6 times their time from the 6 mm run), within
# a factor of two either way on both (tests/unit/test_study_prediction.py), which is what tells
# minutes from hours. Weights per iteration at equal DoFs (bench.md, bench-ans.md, the 2 mm
# cup): linear 0.8, Q3T 1, q3t_ans and the quadratic prism 1.5, the quartic 4
DOF_POWER = 1.1
ELEMENT_WEIGHT = {"linear": 0.8, "q3t": 1.0, "q3t_ans": 1.5, "quadratic": 1.5, "quartic": 4.0}
# the command's line per case (sim.apps.study.run_study's progress), edges in m
REFERENCE_LINE = re.compile(r"^reference (\S+) h=(\S+): (\d+) DoFs, ([\d.]+) s")
CASE_LINE = re.compile(r"^(\S+)\s+h=(\S+)\s+(\d+) DoFs\s+(\S+)\s+([\d.]+) s")
KEEP_LINES = 12  # the command's last other lines kept: why it failed
STOP_S = 10.0  # s a cancelled study has to end before its processes are killed
SAME_EDGE = 1e-6  # relative: a level the run's own


def weight(element: str) -> float:
    return ELEMENT_WEIGHT.get(element.split(":")[0], 1.0)


def predicted(basis: dict, element: str, dofs: int) -> float:
    """Seconds a case of ``element`` with ``dofs`` DoFs takes, from the run ``basis`` (its
    element, DoFs and seconds): the same steps and Newton iterations, each scaled."""
    return (basis["seconds"] * (dofs / basis["dofs"]) ** DOF_POWER
            * weight(element) / weight(basis["element"]))


def make(scene_path: Path, name: str, basis: dict, overrides: dict, max_bytes: float,
         elements: list[str] | None = None, levels_mm: list[float] | None = None,
         reference: tuple[str, float] | None = None, runs_dir: Path | None = None) -> dict:
    """The plan of a study of the scene at ``scene_path`` (named ``name``; ``overrides``: the
    solver's full paths of the files it reads) as the page shows it: the cases with their
    DoFs, memory and predicted seconds, the command it runs. ``basis``: the run asked from
    (run, element, dofs, seconds, edge: its mesh edge in m; changes: what it changed of the
    saved scene that the study runs too, live: what it does not; scene_arg and sets: the scene
    and the --set the command shown names); its element and its level are added to the
    scene's defaults. ``levels_mm`` and
    ``reference`` (element, mm) default to the scene's. Invalid names the field: an unknown
    element, a level not positive or one the scene refuses, a reference no finer than the
    finest level, a case over ``max_bytes``. ``runs_dir``: where a study's report would be
    replaced (said in the notes)."""
    from sim.refinement import case_sizes
    from sim.scene.load import SceneError

    p = _plan_of(scene_path, name, basis, overrides, *_asked(elements, levels_mm, reference))
    try:
        sizes = case_sizes(p)
    except (SceneError, ValueError) as exc:  # a level the scene refuses (too coarse)
        raise Invalid(f"levels_mm: {exc}") from None
    rows = []
    for c in sizes:
        if c["bytes"] > max_bytes:
            what = "reference.edge_mm" if c["reference"] else "levels_mm"
            raise Invalid(f"{what}: {c['element']} at {mm(c['edge_length'])} would have "
                          f"{c['dofs']:,} DoFs and need about {c['bytes'] / 2**30:.3g} GiB to "
                          f"build, above the server's limit of {max_bytes / 2**30:.3g} GiB: a "
                          "coarser level")
        # the run's own case has the run's DoFs: an outline's mesh is counted from its area
        # before it is built (the cup's 7,776 DoFs above the run's 8,004, a review)
        own = (not c["reference"] and c["element"] == basis["element"] and basis.get("edge")
               and abs(c["edge_length"] / basis["edge"] - 1) <= SAME_EDGE)
        dofs = int(basis["dofs"]) if own else c["dofs"]
        rows.append({"element": c["element"], "edge_mm": 1e3 * c["edge_length"],
                     "reference": c["reference"], "dofs": dofs, "asking_run": bool(own),
                     "memory_gib": c["bytes"] / 2**30,
                     "predicted_s": predicted(basis, c["element"], dofs)})
    # each Dask worker first runs every element once at the coarsest level, untimed
    warm = sum(r["predicted_s"] for r in rows
               if not r["reference"] and r["edge_mm"] == 1e3 * p.levels[0])
    args = ["--elements", ",".join(p.elements), "--levels", ",".join(f"{v:g}" for v in p.levels)]
    if p.reference:
        args += ["--reference", f"{p.reference[0]}:{p.reference[1]:g}"]
    # what the study runs of the run's changes, in its report: the run's estimate compares
    shown = [*args, *(a for k, v in (basis.get("sets") or {}).items()
                      for a in ("--set", f"{k}={_toml(v)}"))]
    args += [a for c in basis.get("changes") or () for a in ("--changes", c)]
    return {"scene": name, "probe": p.probe, "elements": p.elements,
            "levels_mm": [1e3 * v for v in p.levels],
            "reference": {"element": p.reference[0], "edge_mm": 1e3 * p.reference[1]}
            if p.reference else None,
            "analytic": p.analytic, "cases": rows,
            "predicted_s": sum(r["predicted_s"] for r in rows) + warm,
            "largest_gib": max(r["memory_gib"] for r in rows),
            "basis": {k: basis[k] for k in ("run", "element", "dofs", "seconds")},
            "notes": [*map(_in_mm, p.notes), *_notes(basis, name, runs_dir)],
            "command": f"q3t study {basis.get('scene_arg') or name} {' '.join(shown)}",
            "args": args}


def _asked(elements: list[str] | None, levels_mm: list[float] | None,
           reference: tuple[str, float] | None) -> tuple:
    """The request's elements (each once), levels (m, each once, coarse to fine) and
    reference (element, m), checked: Invalid naming the field."""
    from sim.elements import ELEMENTS
    from sim.refinement import element_overrides

    try:
        for spec in elements or ():
            element_overrides(spec)
    except ValueError as exc:
        raise Invalid(f"elements: {exc}") from None
    if reference and reference[0] not in ELEMENTS:
        raise Invalid(f"reference.element: unknown element {reference[0]!r}; known: "
                      f"{sorted(ELEMENTS)}")
    try:
        levels = sorted({_positive(v, "levels_mm") / 1e3 for v in levels_mm}, reverse=True) \
            if levels_mm else None
        ref = (reference[0], _positive(reference[1], "reference.edge_mm") / 1e3) \
            if reference else None
    except ValueError as exc:
        raise Invalid(str(exc)) from None
    return list(dict.fromkeys(elements)) if elements else None, levels, ref


def _plan_of(scene_path: Path, name: str, basis: dict, overrides: dict,
             elements: list[str] | None, levels: list[float] | None,
             ref: tuple[str, float] | None) -> Plan:
    """sim.apps.study's plan, with the run's element and level where the defaults lack them;
    Invalid when the scene has no mesh to refine or the reference is coarser than a level."""
    from sim.refinement import make_plan
    from sim.scene.load import SceneError

    try:
        p = make_plan(str(scene_path), elements, levels, ref, overrides)
        added, own = [], basis.get("edge")
        if elements is None and basis["element"] not in p.elements:
            added.append(f"the run's element ({basis['element']}) added to the scene's")
        if levels is None and own and not any(abs(v / own - 1) <= SAME_EDGE for v in p.levels):
            added.append(f"the run's level ({mm(own)}) added to the scene's")
        if added:
            first = p
            p = make_plan(str(scene_path), list(dict.fromkeys([*p.elements, basis["element"]]))
                          if elements is None else p.elements,
                          sorted({*p.levels, own}, reverse=True) if levels is None and own
                          else p.levels, ref, overrides)
            p = dataclasses.replace(p, notes=[*first.notes, *added])
    except (SceneError, ValueError) as exc:  # the scene's own: no mesh to refine
        raise Invalid(f"run: its scene {name!r}: {exc}") from None
    if p.reference and p.reference[1] > min(p.levels) * (1 + SAME_EDGE):
        raise Invalid(f"reference.edge_mm: {mm(p.reference[1])} is coarser than the finest "
                      f"level ({mm(min(p.levels))}): every case's error is measured against "
                      "the reference, which needs a mesh at least as fine as any of them")
    return p


def _positive(v: float, name: str) -> float:
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"{name}: {v:g} mm: a mesh edge length is a positive number of mm")
    return v


def _in_mm(note: str) -> str:
    """The command line's note with its lengths in m given in mm, as the page shows them."""
    return re.sub(r"\(([\d.]+(?:e-?\d+)?) m\)", lambda m: f"({mm(float(m.group(1)))})", note)


def _notes(basis: dict, name: str, runs_dir: Path | None) -> list[str]:
    out = [f"times predicted from run {basis['run']} ({basis['element']}, {basis['dofs']:,} "
           f"DoFs, the solver's {basis['seconds']:.3g} s), scaled by DoFs^{DOF_POWER:g} and by "
           "element: within about a factor of two, high rather than low scaling up from a "
           "small run",
           "runs stepping meanwhile slow its cases and skew the times it reports"]
    if basis.get("changes"):
        out.append(f"the study runs what the run ran: {'; '.join(basis['changes'])}")
    if basis.get("live"):
        out.append(f"not the run's live changes ({'; '.join(basis['live'])}): a study runs "
                   "the scene's own parameters")
    if runs_dir is not None:
        from server.estimate import find_study

        found = find_study(runs_dir, name)
        if found is not None:
            out.append(f"replaces the study of {found[1].get('date')} "
                       f"({len(found[1]['rows'])} cases): the scene's runs take their "
                       "estimates from the newest")
    return out


@dataclass
class Study:
    """The study running or last run: its plan, its process, and what it has said."""

    scene: str
    plan: dict
    proc: subprocess.Popen | None = None
    state: str = "running"  # running, finished, failed, cancelled
    finished: list[dict] = field(default_factory=list)  # its cases done, as the command said
    log: collections.deque = field(default_factory=lambda: collections.deque(
        maxlen=KEEP_LINES))  # its other lines: why it failed
    started: float = field(default_factory=time.time)
    ended: float | None = None
    reason: str | None = None
    had_report: bool = False  # a report of the scene was there before it

    def shown(self) -> dict:
        end = self.ended if self.ended is not None else time.time()
        cases, done = self.plan["cases"], len(self.finished)
        # the command runs the cases in the plan's order, one at a time (sim.apps.study)
        now = cases[done] if self.state == "running" and done < len(cases) else None
        return {"scene": self.scene, "state": self.state, "done": done, "cases": len(cases),
                "elapsed_s": end - self.started, "predicted_s": self.plan["predicted_s"],
                "now": now, "finished": list(self.finished), "reason": self.reason,
                "had_report": self.had_report, "command": self.plan["command"]}

    def heard(self, line: str) -> None:
        """A line of the command's: a case done, or one of its other lines."""
        if m := REFERENCE_LINE.match(line):
            el, edge, dofs, secs = m.groups()
            status = "converged"
        elif m := CASE_LINE.match(line):
            el, edge, dofs, status, secs = m.groups()
        else:
            if line:
                self.log.append(line)
            return
        self.finished.append({"element": el, "edge_mm": 1e3 * float(edge),
                              "reference": line.startswith("reference "), "dofs": int(dofs),
                              "status": status, "seconds": float(secs)})


class Studies:
    """One study at a time, in a process of its own."""

    def __init__(self, runs_dir: Path):
        self.runs_dir = runs_dir
        self._lock = threading.Lock()
        self.current: Study | None = None

    def start(self, scene_path: Path, plan: dict, overrides: dict) -> dict:
        """Starts ``q3t study`` of ``plan``; Conflict while another study runs."""
        with self._lock:
            if self.current is not None and self.current.state == "running":
                c = self.current
                raise Conflict(f"a study of {c.scene!r} is running ({len(c.finished)} of "
                               f"{len(c.plan['cases'])} cases done): cancel it or wait")
            out = self.runs_dir / f"study-{plan['scene']}"
            sets = [a for k, v in overrides.items() for a in ("--set", f"{k}={_toml(v)}")]
            cmd = [sys.executable, "-m", "sim.apps", "study", str(scene_path), "--out",
                   str(out), "--no-overhead", *plan["args"], *sets]
            study = Study(plan["scene"], plan, had_report=(out / "report.json").is_file())
            study.proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL,
                                          stderr=subprocess.PIPE, text=True, bufsize=1,
                                          start_new_session=True,
                                          cwd=Path(__file__).resolve().parents[1])
            self.current = study
        threading.Thread(target=self._follow, args=(study,), daemon=True,
                         name="q3t-study").start()
        return study.shown()

    def _follow(self, study: Study) -> None:
        """In a thread: the command's lines onto the study, then how it ended."""
        for line in study.proc.stderr:
            with self._lock:
                study.heard(line.rstrip())
        code = study.proc.wait()
        with self._lock:
            study.ended = time.time()
            if study.state == "cancelled":
                return
            study.state = "finished" if code == 0 else "failed"
            if code != 0:
                said = [ln for ln in study.log if ln.startswith("q3t study:")]
                study.reason = (said[-1] if said else
                                f"q3t study exited {code}: {' / '.join(list(study.log)[-3:])}")

    def shown(self) -> dict | None:
        with self._lock:
            return self.current.shown() if self.current else None

    def cancel(self) -> dict:
        """Ends the running study's processes; Conflict when none runs."""
        with self._lock:
            study = self.current
            if study is None or study.state != "running":
                raise Conflict("no study is running")
            study.state, study.reason = "cancelled", "cancelled from the page"
        _end(study.proc)
        with self._lock:
            study.ended = study.ended or time.time()
            return study.shown()

    def close(self) -> None:
        with self._lock:
            study = self.current
        if study is not None and study.proc is not None and study.proc.poll() is None:
            with self._lock:
                study.state, study.reason = "cancelled", "the server stopped"
            _end(study.proc)


def _end(proc: subprocess.Popen) -> None:
    """SIGTERM to the study's process group, SIGKILL after STOP_S."""
    for sig, wait in ((signal.SIGTERM, STOP_S), (signal.SIGKILL, STOP_S)):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            return
        try:
            proc.wait(wait)
            return
        except subprocess.TimeoutExpired:
            continue


def _toml(v: object) -> str:
    """A value as --set reads it (TOML): strings quoted, lists and true/false as JSON's,
    which TOML reads alike."""
    import json

    return json.dumps(v)

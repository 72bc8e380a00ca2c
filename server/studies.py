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

from server.problems import Conflict, Invalid
from sim.text import mm

# a case's time: the run's, scaled by its DoFs to this power (the refinement study of the
# convergence scene: per iteration 1.23-1.25 within an element from 6,561 to 83,979 DoFs) and
# by the element's weight (per iteration over DoFs^1.3 on the cup at 80,000-120,000 DoFs,
# docs/results/bench.md and bench-ans.md: linear 0.78, the assumed-strain prism 1.5, the
# quadratic prism 1.5, under a projected Hessian up to 4: a prediction within a factor of two
# or three, which is what a plan needs to tell minutes from hours)
DOF_POWER = 1.3
ELEMENT_WEIGHT = {"linear": 0.8, "q3t": 1.0, "q3t_ans": 1.5, "quadratic": 1.5, "quartic": 4.0}
CASE_LINE = re.compile(r"^(reference \S+ h=|\S+\s+h=\S+\s+\d+ DoFs)")
KEEP_LINES = 12  # the command's last lines kept: its progress, and why it failed
STOP_S = 10.0  # s a cancelled study has to end before its processes are killed


def weight(element: str) -> float:
    return ELEMENT_WEIGHT.get(element.split(":")[0], 1.0)


def predicted(basis: dict, element: str, dofs: int) -> float:
    """Seconds a case of ``element`` with ``dofs`` DoFs takes, from the run ``basis`` (its
    element, DoFs and seconds): the same steps and Newton iterations, each scaled."""
    return (basis["seconds"] * (dofs / basis["dofs"]) ** DOF_POWER
            * weight(element) / weight(basis["element"]))


def make(scene_path: Path, name: str, basis: dict, overrides: dict, max_bytes: float,
         elements: list[str] | None = None, levels_mm: list[float] | None = None,
         reference: tuple[str, float] | None = None) -> dict:
    """The plan of a study of the scene at ``scene_path`` (named ``name``; ``overrides``: the
    solver's full paths of the files it reads) as the page shows it: the cases with their
    DoFs, memory and predicted seconds, the command it runs. ``elements`` default to the
    scene's study table's and the run's own; ``levels_mm`` and ``reference`` (element, mm)
    to the scene's. Invalid names the field: an unknown element, a level not positive, a case
    over ``max_bytes``."""
    from sim.apps.cases import element_overrides
    from sim.apps.study import case_sizes, make_plan
    from sim.elements import ELEMENTS
    from sim.scene.load import SceneError

    try:
        for spec in elements or ():
            element_overrides(spec)
    except ValueError as exc:
        raise Invalid(f"elements: {exc}") from None
    if reference and reference[0] not in ELEMENTS:
        raise Invalid(f"reference.element: unknown element {reference[0]!r}; known: "
                      f"{sorted(ELEMENTS)}")
    try:
        levels = [_positive(v, "levels_mm") / 1e3 for v in levels_mm] if levels_mm else None
        ref = (reference[0], _positive(reference[1], "reference.edge_mm") / 1e3) \
            if reference else None
    except ValueError as exc:
        raise Invalid(str(exc)) from None
    try:
        p = make_plan(str(scene_path), elements, levels, ref, overrides)
        if elements is None and basis["element"] not in p.elements:
            p = make_plan(str(scene_path), [*p.elements, basis["element"]], levels, ref,
                          overrides)
    except (SceneError, ValueError) as exc:  # the scene's own: no mesh to refine
        raise Invalid(f"run: its scene {name!r}: {exc}") from None
    try:
        sizes = case_sizes(p)
    except ValueError as exc:
        raise Invalid(f"run: its scene {name!r}: {exc}") from None
    rows = []
    for c in sizes:
        if c["bytes"] > max_bytes:
            what = "reference.edge_mm" if c["reference"] else "levels_mm"
            raise Invalid(f"{what}: {c['element']} at {mm(c['edge_length'])} would have "
                          f"{c['dofs']:,} DoFs and need about {c['bytes'] / 2**30:.3g} GiB to "
                          f"build, above the server's limit of {max_bytes / 2**30:.3g} GiB: a "
                          "coarser level")
        rows.append({"element": c["element"], "edge_mm": 1e3 * c["edge_length"],
                     "reference": c["reference"], "dofs": c["dofs"],
                     "memory_gib": c["bytes"] / 2**30,
                     "predicted_s": predicted(basis, c["element"], c["dofs"])})
    # each Dask worker first runs every element once at the coarsest level, untimed
    warm = sum(r["predicted_s"] for r in rows
               if not r["reference"] and r["edge_mm"] == 1e3 * p.levels[0])
    total = sum(r["predicted_s"] for r in rows) + warm
    args = ["--elements", ",".join(p.elements), "--levels", ",".join(f"{v:g}" for v in p.levels)]
    if p.reference:
        args += ["--reference", f"{p.reference[0]}:{p.reference[1]:g}"]
    return {"scene": name, "probe": p.probe, "elements": p.elements,
            "levels_mm": [1e3 * v for v in p.levels],
            "reference": {"element": p.reference[0], "edge_mm": 1e3 * p.reference[1]}
            if p.reference else None,
            "analytic": p.analytic, "cases": rows, "predicted_s": total,
            "basis": basis, "notes": [*map(_in_mm, p.notes), *_notes(basis)],
            "command": f"q3t study {name} {' '.join(args)}", "args": args}


def _positive(v: float, name: str) -> float:
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"{name}: {v:g} mm: a mesh edge length is a positive number of mm")
    return v


def _in_mm(note: str) -> str:
    """The command line's note with its lengths in m given in mm, as the page shows them."""
    return re.sub(r"\(([\d.]+(?:e-?\d+)?) m\)", lambda m: f"({mm(float(m.group(1)))})", note)


def _notes(basis: dict) -> list[str]:
    return [f"times predicted from run {basis['run']} ({basis['element']}, {basis['dofs']:,} "
            f"DoFs, {basis['seconds']:.3g} s), scaled by DoFs^{DOF_POWER:g} and by element: "
            "within a factor of two or three",
            "runs stepping meanwhile slow its cases and skew the times it reports"]


@dataclass
class Study:
    """The study running or last run: its plan, its process, and what it has said."""

    scene: str
    plan: dict
    proc: subprocess.Popen | None = None
    state: str = "running"  # running, finished, failed, cancelled
    done: int = 0  # cases finished, the reference among them
    lines: collections.deque = field(default_factory=lambda: collections.deque(
        maxlen=KEEP_LINES))
    started: float = field(default_factory=time.time)
    ended: float | None = None
    reason: str | None = None

    def shown(self) -> dict:
        end = self.ended if self.ended is not None else time.time()
        return {"scene": self.scene, "state": self.state, "done": self.done,
                "cases": len(self.plan["cases"]), "elapsed_s": end - self.started,
                "predicted_s": self.plan["predicted_s"], "lines": list(self.lines),
                "reason": self.reason, "command": self.plan["command"]}


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
                raise Conflict(f"a study of {c.scene!r} is running ({c.done} of "
                               f"{len(c.plan['cases'])} cases done): cancel it or wait")
            out = self.runs_dir / f"study-{plan['scene']}"
            sets = [a for k, v in overrides.items() for a in ("--set", f"{k}={_toml(v)}")]
            cmd = [sys.executable, "-m", "sim.apps", "study", str(scene_path), "--out",
                   str(out), "--no-overhead", *plan["args"], *sets]
            study = Study(plan["scene"], plan)
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
            line = line.rstrip()
            with self._lock:
                if CASE_LINE.match(line):
                    study.done += 1
                if line:
                    study.lines.append(line)
        code = study.proc.wait()
        with self._lock:
            study.ended = time.time()
            if study.state == "cancelled":
                return
            study.state = "finished" if code == 0 else "failed"
            if code != 0:
                said = [ln for ln in study.lines if ln.startswith("q3t study:")]
                study.reason = (said[-1] if said else
                                f"q3t study exited {code}: {' / '.join(list(study.lines)[-3:])}")

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
    import json

    return json.dumps(v) if isinstance(v, str) else str(v)

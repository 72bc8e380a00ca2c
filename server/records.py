"""Run records: the ``Run`` a request reads, and its folder ``runs/<id>/`` (scene.toml,
run.json, result.json, run.rrd).

``run.json`` is written at a run's start and end only. A run the server lost track of (it died
during the run) is rebuilt from what the solver left on disk when the next server loads the
folder: result.json when it was written (a solver whose server died finishes its run), else the
steps its recording holds, after the recording is repaired.
"""

from __future__ import annotations

import copy
import json
import shutil
import threading
import time
from dataclasses import dataclass, field, fields
from pathlib import Path

from server.scenediff import override_text
from server.settings import check_run_id
from server.store import atomic_write
from sim.frames import results
from sim.scene.load import unit_of
from sim.stepping.parameters import label

ACTIVE = {"starting", "building", "running", "paused"}
# waits for a free solver process (``RunManager.queue``); then starts, or is cancelled
QUEUED = "queued"
CANCELLED = "cancelled"  # ended while queued: it never ran
ENDED = {"finished", "failed", "stopped", CANCELLED}  # a run in one of these is over
LOST = "the server stopped during the run"
# the result.json summary entries the Runs table shows (sim.frames.summary), each by its
# display value (kN, mm, %) and flag (a forming limit reached); of several punches the largest
# peak force
TABLED = ("peak_punch_force", "min_thickness", "max_thinning", "forming_limit_margin")
NOT_RUN = "not run: the server stopped before its turn"
AS_WRITTEN = 1.0  # every live parameter multiplies a value of the scene: 1 runs it as written


@dataclass
class Run:
    id: str
    scene: str
    element: str
    overrides: dict
    created: float
    # the scene it ran is not the saved file: the page's unsaved edits (scene.toml holds it),
    # and what they changed of it in words (server.scenediff.edits)
    edited: bool = False
    edits: list[str] = field(default_factory=list)
    state: str = QUEUED
    place: int | None = None  # its place in the queue (1: next to start) while queued
    reason: str | None = None
    step: int = 0
    n_steps: int | None = None
    counts: dict | None = None
    probes: list[str] = field(default_factory=list)
    tools: list[str] = field(default_factory=list)
    timing: dict = field(default_factory=dict)  # build_s, tool_meshes_s, first_frame_s, ...
    parameters: dict = field(default_factory=dict)
    given: dict = field(default_factory=dict)  # the live parameters given at the start
    # each frame field's (lo, hi) over every step the solver framed, once it ended: the scale
    # a view of its kept frames colours on (sim.frames.output.result's field_ranges)
    field_ranges: dict = field(default_factory=dict)
    # the scene's own element when the run took another (None: the scene's)
    scene_element: str | None = None
    # what each live parameter multiplies (sim's Simulation.scaled): the page shows the result
    scaled: dict = field(default_factory=dict)
    # %, the material card's excessive-thinning limit (flc.max_thinning): the viewer's thinning
    # bands start from it, the run's recording replayed too (the recording does not hold it)
    thinning_limit: float | None = None
    parameter_log: list[dict] = field(default_factory=list)
    # frames made and dropped (queue full) by the solver; received and pushed to the viewer here
    frames: dict = field(default_factory=dict)
    records: list[dict] = field(default_factory=list)
    # commands sent to the solver that it has not done yet, in order (pause, step, set, ...):
    # empty once it has acted on every request (a step asked for is then made)
    pending: list[str] = field(default_factory=list)
    # finished runs: error estimate from a study of the scene, and the run's cost
    estimate: dict | None = None
    # what the plots need that the records do not say: each punch's start translation (m),
    # each probe's kind (from the solver's meta)
    punches: dict[str, list[float]] = field(default_factory=dict)
    probe_kinds: dict[str, str] = field(default_factory=dict)
    stepping_s: float = 0.0  # wall time the solver spent in the steps made
    paced_s: float = 0.0  # the pauses after them (``q3t serve --step-delay``)
    started: float | None = None  # Unix time it left the queue for a solver process
    ended: float | None = None  # Unix time it ended
    # the view (a browser's page, server.views) that started it; "default": a script
    started_by: str | None = None
    # Pause/Resume/Step/Stop and parameter changes from a view other than the starter's
    touched: list[dict] = field(default_factory=list)

    def summary(self) -> dict:
        """Everything but the records, copied (the bridge may change the run meanwhile), its
        progress and what it changed of its scene (with each override's SI unit, so a page
        can show it in its own)."""
        return self._fields() | {"progress": self.progress(time.time()),
                                 "changes": self.changes(), "controls": self.controls(),
                                 "override_units": {k: unit_of(k) for k in self.overrides}}

    def controls(self) -> list[str]:
        """The commands that act on it now, for the page's and the viewer's buttons: Pause
        while it runs, Resume while it is paused or a pause is on its way to the solver (the
        later of the two it has not acted on decides), Step either way; Stop while it is
        active, or queued (which cancels it)."""
        if self.state not in ACTIVE:
            return ["stop"] if self.state == QUEUED else []
        last = [c for c in self.pending if c in ("pause", "resume")][-1:]
        paused = last == ["pause"] if last else self.state == "paused"
        return ["resume" if paused else "pause", "step", "stop"]

    def unsaved(self) -> list[str]:
        """The page's unsaved edits it ran, in words (each setting from the saved value to the
        edited one)."""
        return list(self.edits or ["unsaved edits of the scene"]) if self.edited else []

    def changes(self, studied: bool = False, live: bool = True) -> list[str]:
        """What this run changed of its saved scene, in words: the page's unsaved edits, the
        overrides (the element is a column of its own), the live parameters given at the
        start (from step 1) and those changed while it ran, from the step each applied.
        ``studied``: what a refinement study does not vary itself (not the element, not the
        mesh's edge length); ``live``: with the live parameters (a study runs the edits and
        the overrides, not those)."""
        out = self.unsaved()
        if self.scene_element and not studied:  # a column of its own, but a change
            out.append(f"element {self.element} (the scene's {self.scene_element})")
        out += [f"{k} = {override_text(k, v)}" for k, v in self.studied_overrides(
            ("shell.element", "mesh.edge_length") if studied else ("shell.element",)).items()]
        if not live:
            return out
        # the live parameters as the page's sliders name them (Friction × 0.5)
        out += [f"{label(k)[0]} {v:.4g} from step 1" for k, v in self.given.items()
                if v != AS_WRITTEN]
        out += [f"{label(e['name'])[0]} {e['value']:.4g} from step {e['step']}"
                for e in self.parameter_log]
        return out

    def studied_overrides(self, varied: tuple[str, ...] = ("shell.element",
                                                           "mesh.edge_length")) -> dict:
        """The run's overrides less those ``varied`` (a study's own: element and mesh)."""
        return {k: v for k, v in self.overrides.items() if k not in varied}

    def _fields(self) -> dict:
        return {f.name: copy.deepcopy(getattr(self, f.name)) for f in fields(self)
                if f.name != "records"}

    def progress(self, now: float) -> dict:
        """Steps done of all, the wall time since it left the queue (to the end, once it
        ended; None for a run that never started) and the time the steps left need at the
        mean cost of those done, their pauses included (0 once finished; None before the first
        step, or for a run that ended early and will not go on)."""
        done, steps = self.step, self.n_steps
        left = None
        if self.state == "finished":
            left = 0.0
        elif self.state in ACTIVE and done and steps:
            left = (self.stepping_s + self.paced_s) / done * max(steps - done, 0)
        # a run saved before runs were queued started when it was created
        start = self.started if self.started is not None else \
            None if self.state in (QUEUED, CANCELLED) else self.created
        end = self.ended if self.ended is not None else None if self.state not in ACTIVE \
            else now
        return {"step": done, "steps": steps,
                "fraction": min(done / steps, 1.0) if steps else None,
                "elapsed_s": None if end is None or start is None else max(end - start, 0.0),
                "remaining_s": left}

    def line(self) -> str:
        """The viewer's status line (markdown)."""
        edited = "  \nran the page's unsaved edits of its scene" if self.edited else ""
        reason = f"  \n{self.reason}" if self.reason else ""
        state = f"queued, {ordinal(self.place)} in the queue" if self.place else self.state
        return (f"Run `{self.id}` ({self.element})  \n{state}, step {self.step}/"
                f"{self.n_steps if self.n_steps is not None else '?'}{edited}{reason}")

    def snapshot(self) -> dict:
        """What run.json holds: the summary and the step records."""
        return {**self._fields(), "records": list(self.records)}


def _tabled(entries: list) -> dict:
    """The ``TABLED`` entries of a result summary by name, their display values; of a
    quantity given per punch the largest."""
    out: dict[str, dict] = {}
    for e in entries:
        try:
            name, shown = e["name"], {"value": float(e["display"]["value"]),
                                      "unit": e["display"]["unit"]}
        except (KeyError, TypeError, ValueError):  # not one number: not a table's value
            continue
        if name in TABLED and (name not in out or shown["value"] > out[name]["value"]):
            out[name] = shown | ({"flag": e["flag"]} if e.get("flag") else {})
    return out


def ordinal(n: int) -> str:
    """1st, 2nd, 3rd, 4th, ..., 11th, 12th, 13th, 21st."""
    suffix = "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"{n}{suffix}"


def repair_recording(path: Path) -> str:
    """Make the recording of a run whose recording process was killed verifiable again.
    Returns what to add to the run's reason ("" when all went well)."""
    from server import recording  # imports rerun: only the solver needs it otherwise

    try:
        recording.repair(path)
        return ""
    except Exception as exc:
        return f"; recording unreadable: {exc}"


class RunFiles:
    """The runs' folder, one subfolder per run. Every file is written atomically."""

    def __init__(self, root: Path):
        self.root = root
        self.root.mkdir(parents=True, exist_ok=True)
        self._write_lock = threading.Lock()  # two saves of one run: the later one wins
        self._tabled: dict[str, tuple[int, dict]] = {}  # run id -> (mtime, its values)

    def tabled(self, run_id: str) -> dict:
        """The run's ``TABLED`` values from its result.json (``{name: {"value", "unit"}}``,
        display units), read once per version of the file; {} without one. Reads files:
        never call it holding the run lock."""
        path = self.dir(run_id) / "result.json"
        try:
            mtime = path.stat().st_mtime_ns
        except OSError:
            return {}
        cached = self._tabled.get(run_id)
        if cached is None or cached[0] != mtime:
            try:
                entries = json.loads(path.read_text()).get("summary") or []
            except (OSError, ValueError, AttributeError):
                entries = []
            cached = self._tabled[run_id] = (mtime, _tabled(entries))
        return cached[1]

    def dir(self, run_id: str) -> Path:
        return self.root / check_run_id(run_id)

    def recording(self, run_id: str) -> Path:
        return self.dir(run_id) / "run.rrd"

    def create(self, run: Run, scene_text: str) -> Path:
        """A new run's folder with its scene and run.json; the folder must not exist yet."""
        out = self.dir(run.id)
        out.mkdir(parents=True)
        atomic_write(out / "scene.toml", scene_text)
        atomic_write(out / "run.json", results.dumps(run.snapshot(), indent=1))
        return out

    def save(self, run_id: str, snapshot: dict) -> None:
        """Write ``Run.snapshot()`` (taken under the run lock) to run.json."""
        text = results.dumps(snapshot, indent=1)
        with self._write_lock:
            atomic_write(self.dir(run_id) / "run.json", text)

    def delete(self, run_id: str) -> None:
        shutil.rmtree(self.dir(run_id), ignore_errors=True)
        self._tabled.pop(run_id, None)

    def load(self) -> dict[str, Run]:
        """Every run with a readable run.json; one the server lost during its run is rebuilt
        (``recover``) and saved. Nothing else holds the runs yet: no lock is taken."""
        runs = {}
        for p in sorted(self.root.glob("*/run.json")):
            try:
                run = Run(**json.loads(p.read_text()))
            except (ValueError, TypeError):
                continue
            runs[run.id] = run
            if run.state == QUEUED and not self._began(run.id):
                # not started again: a restart is often made to change the server (its
                # solvers, its limits, its code), and a run nobody waits for any more would
                # take a solver process from those who do. Start it again from the page.
                run.state, run.reason, run.place, run.ended = CANCELLED, NOT_RUN, None, None
                self.save(run.id, run.snapshot())
            elif run.state in ACTIVE or run.state == QUEUED:  # the server died during it
                self.recover(run, repair_recording(self.recording(run.id)))
                self.save(run.id, run.snapshot())
        return runs

    def _began(self, run_id: str) -> bool:
        """Whether a solver process began the run: run.json says queued until the solver's
        first event is booked, and a server may die in between."""
        d = self.dir(run_id)
        return (d / "result.json").is_file() or (d / "run.rrd").is_file()

    def recover(self, run: Run, note: str) -> None:
        """The status of a run the server lost track of, rebuilt from result.json when the
        solver wrote it, else from the steps the recording holds. ``note``: what the
        recording's repair said."""
        state, reason = "failed", LOST
        try:
            result = json.loads((self.dir(run.id) / "result.json").read_text())
            run.records, run.counts = result["steps"], result["counts"]
            run.field_ranges = result.get("field_ranges") or {}
            if result["converged"]:
                state, reason = "finished", None
            elif result["failure"]:
                reason = result["failure"]["reason"]
        except (OSError, ValueError, KeyError, TypeError):
            note += self._steps_from_recording(run)
        run.step = run.records[-1]["step"] if run.records else 0
        run.state, run.reason = state, ((reason or "") + note).removeprefix("; ") or None
        run.pending.clear()
        run.place = None

    def _steps_from_recording(self, run: Run) -> str:
        """Fill ``run.records`` from its recording; returns a note when it cannot be read."""
        from server.recording import read_steps  # imports rerun: see repair_recording

        path = self.recording(run.id)
        try:  # none when the server died before the solver began the recording
            run.records = read_steps(path) if path.is_file() else []
        except Exception as exc:  # an unreadable recording: the run keeps no records
            return f"; its steps could not be read: {exc}"
        return ""

    def result_if_missing(self, run_id: str, scene: str, element: str, reason: str,
                          steps: list[dict]) -> str | None:
        """A run whose solver ended without writing result.json (killed while building or
        stepping) gets one from what the server knows. Returns why writing it failed, if it
        did."""
        path = self.dir(run_id) / "result.json"
        if path.exists():
            return None
        try:
            results.write(path, results.interrupted(scene, element, reason, steps))
        except (OSError, ValueError) as exc:
            return f"writing result.json failed: {exc}"
        return None

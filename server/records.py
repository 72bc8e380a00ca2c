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

from server.settings import check_run_id
from server.store import atomic_write
from sim.frames import results

ACTIVE = {"starting", "building", "running", "paused"}
LOST = "the server stopped during the run"


@dataclass
class Run:
    id: str
    scene: str
    element: str
    overrides: dict
    created: float
    # the scene it ran is not the saved file: the page's unsaved edits (scene.toml holds it)
    edited: bool = False
    state: str = "starting"
    reason: str | None = None
    step: int = 0
    n_steps: int | None = None
    counts: dict | None = None
    probes: list[str] = field(default_factory=list)
    tools: list[str] = field(default_factory=list)
    timing: dict = field(default_factory=dict)  # build_s, tool_meshes_s, first_frame_s, ...
    parameters: dict = field(default_factory=dict)
    # what each live parameter multiplies (sim's Simulation.scaled): the page shows the result
    scaled: dict = field(default_factory=dict)
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
    ended: float | None = None  # Unix time it ended

    def summary(self) -> dict:
        """Everything but the records, copied (the bridge may change the run meanwhile), and
        its progress."""
        return self._fields() | {"progress": self.progress(time.time())}

    def _fields(self) -> dict:
        return {f.name: copy.deepcopy(getattr(self, f.name)) for f in fields(self)
                if f.name != "records"}

    def progress(self, now: float) -> dict:
        """Steps done of all, the wall time since the start (to the end, once it ended) and
        the time the steps left need at the mean cost of those done (0 once finished; None
        before the first step, or for a run that ended early and will not go on)."""
        done, steps = self.step, self.n_steps
        left = None
        if self.state == "finished":
            left = 0.0
        elif self.state in ACTIVE and done and steps:
            left = self.stepping_s / done * max(steps - done, 0)
        end = self.ended if self.ended is not None else None if self.state not in ACTIVE \
            else now
        return {"step": done, "steps": steps,
                "fraction": min(done / steps, 1.0) if steps else None,
                "elapsed_s": None if end is None else max(end - self.created, 0.0),
                "remaining_s": left}

    def line(self) -> str:
        """The viewer's status line (markdown)."""
        edited = "  \nran the page's unsaved edits of its scene" if self.edited else ""
        reason = f"  \n{self.reason}" if self.reason else ""
        return (f"Run `{self.id}` ({self.element})  \n{self.state}, step {self.step}/"
                f"{self.n_steps if self.n_steps is not None else '?'}{edited}{reason}")

    def snapshot(self) -> dict:
        """What run.json holds: the summary and the step records."""
        return {**self._fields(), "records": list(self.records)}


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
            if run.state in ACTIVE:  # the server died during the run
                self.recover(run, repair_recording(self.recording(run.id)))
                self.save(run.id, run.snapshot())
        return runs

    def recover(self, run: Run, note: str) -> None:
        """The status of a run the server lost track of, rebuilt from result.json when the
        solver wrote it, else from the steps the recording holds. ``note``: what the
        recording's repair said."""
        state, reason = "failed", LOST
        try:
            result = json.loads((self.dir(run.id) / "result.json").read_text())
            run.records, run.counts = result["steps"], result["counts"]
            if result["converged"]:
                state, reason = "finished", None
            elif result["failure"]:
                reason = result["failure"]["reason"]
        except (OSError, ValueError, KeyError, TypeError):
            note += self._steps_from_recording(run)
        run.step = run.records[-1]["step"] if run.records else 0
        run.state, run.reason = state, ((reason or "") + note).removeprefix("; ") or None
        run.pending.clear()

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

"""What a browser's viewer controls do (``viewer.Actions``): Pause, Resume, Step and Stop of the
run it shows (the page's controls, in its words), the live-parameter sliders, the time slider,
and the "Run" dropdown, which selects the run shown in that browser's view (its viewer and its
page). Each goes through the run manager's requests, as the API does, and answers with the
line the viewer shows as its status: a refused request is that line, never an exception in
viser's callback thread; an action on a run another browser started is done, and says so.
None of them starts a run."""

from __future__ import annotations

from server import replay
from server.problems import Conflict, Invalid, NotFound, NotReady
from server.records import ACTIVE, CANCELLED, QUEUED
from server.runs import RunManager
from sim.stepping.parameters import label


class ViewerActions:
    def __init__(self, manager: RunManager):
        self.m = manager

    def command(self, view: str, run_id: str | None, cmd: str) -> str:
        """pause, resume, step or stop the run shown (refused unless it is active)."""
        if run_id is None:
            return "No run selected"
        try:
            out = f"{cmd}: {self.m.command(run_id, cmd)['id']}"
            notice = self.m.views.acted(self.m.get(run_id), cmd, view)
        except (Conflict, NotFound) as exc:
            return str(exc)
        return f"{out}  \n{notice}" if notice else out

    def select(self, view: str, run_id: str) -> str:
        """Show ``run_id`` in ``view``; "" when done (the viewer then shows the run's own
        line), else why not (a run deleted meanwhile)."""
        try:
            self.m.views.select(view, run_id)
        except (Invalid, NotFound) as exc:
            return str(exc)
        return ""

    def set_parameter(self, view: str, run_id: str | None, name: str, value: float) -> str:
        if run_id is None:
            return "No run selected"
        try:
            r = self.m.set_parameter(run_id, name, value)
            notice = self.m.views.acted(self.m.get(run_id), f"set {name}", view,
                                        f" to {value:g}")
        except (Conflict, Invalid, NotFound, NotReady) as exc:
            return str(exc)
        when = f"from step {r['applies_from_step']}" if r["applied"] else "from the next step"
        out = f"{label(name)[0]} {value:.4g} {when}"
        return f"{out}  \n{notice}" if notice else out

    def scaled(self, run_id: str | None) -> dict:
        """What each live parameter of the run multiplies (sim's ``Simulation.scaled``)."""
        with self.m.lock:
            run = self.m.runs.get(run_id or "")
            return dict(run.scaled) if run is not None else {}

    def shows_step(self, view: str, run_id: str | None, step: int | None) -> None:
        self.m.views.shows_step(view, run_id, step)

    def connected(self, view: str) -> None:
        self.m.views.connected(view)

    def scrub(self, run_id: str | None, step: int) -> tuple[dict | None, str]:
        """The kept frame of the run to show for the time slider, or why none (a running run
        streams)."""
        run = self.m.runs.get(run_id or "")
        history = self.m.history.get(run.id) if run is not None else None
        if run is None or history is None:
            return None, "No run to scrub"
        if run.state in ("starting", "building", "running"):
            return None, f"Run `{run.id}` is {run.state}: pause it to scrub"
        frame = history.at(step)
        if frame is None:
            return None, "No frames yet"
        return frame, (f"Run `{run.id}` ({run.state})  \nshowing step {frame['step']}/"
                       f"{run.n_steps} (kept every {history.stride})")

    def recording(self, run_id: str) -> tuple[replay.Replay | None, str]:
        """A run's recording to replay, with the status line; or None and why not."""
        run = self.m.runs.get(run_id)
        if run is None:
            return None, f"No run `{run_id}`"
        if run.state in ACTIVE:
            return None, f"Run `{run_id}` is {run.state}: its recording is still being written"
        if run.state in (QUEUED, CANCELLED):
            return None, "It has not run (yet): no recording"
        path = self.m.files.recording(run.id)
        if not path.is_file():
            return None, "It has no recording (it ended before its first frame)"
        try:
            rep = replay.load(path)
        except Exception as exc:
            return None, f"Cannot read its recording: {exc}"
        if not rep.steps or rep.faces is None:
            return None, "Its recording holds no sheet mesh"
        rep.thinning_limit = run.thinning_limit
        rep.ranges = dict(run.field_ranges or {})
        colours = "" if rep.fields[-1] else " (coloured by thickness, as recorded)"
        return rep, (f"Recording: {len(rep.steps)} frames, steps {rep.steps[0]}-"
                     f"{rep.steps[-1]}{colours}")

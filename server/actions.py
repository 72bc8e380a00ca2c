"""What the viewer's controls do (``viewer.Actions``): Play, Pause, Step, Reset, the live
parameter sliders, the time slider and the recordings dropdown. Each goes through the run
manager's requests, as the API does, and answers with the line the viewer shows as its status:
a refused request is that line, never an exception in viser's callback thread."""

from __future__ import annotations

import time

from server import replay
from server.problems import Conflict, Invalid, NotFound, NotReady
from server.runs import RunManager
from sim.scene.load import SceneError

STOP_WAIT_S = 10.0  # Reset: how long the stopped run may take to end before the new one starts


class ViewerActions:
    def __init__(self, manager: RunManager):
        self.m = manager

    def command(self, cmd: str) -> str:
        """pause, resume or step the active run; resume without one starts a run (Play)."""
        try:
            if self.m.active is None:
                if cmd != "resume":
                    return "No active run"
                return self.reset(None)
            return f"{cmd}: {self.m.command(self.m.active, cmd)['id']}"
        except (Conflict, NotFound) as exc:
            return str(exc)

    def reset(self, element: str | None) -> str:
        """Stop the active run and start the latest run's scene and overrides again, with
        ``element`` (else the latest run's)."""
        m = self.m
        last = max(m.runs.values(), key=lambda r: r.created, default=None)
        scene = last.scene if last else m.settings.default_scene
        try:
            if m.active:
                m.command(m.active, "stop")
                deadline = time.time() + STOP_WAIT_S
                while m.active and time.time() < deadline:
                    time.sleep(0.05)
            run = m.start_run(scene, element or (last.element if last else None),
                              last.overrides if last else None)
            return f"Started `{run.id}`"
        except (Conflict, NotFound, NotReady, SceneError, Invalid) as exc:
            return f"Cannot start: {exc}"

    def set_parameter(self, name: str, value: float) -> str:
        if self.m.active is None:
            return "No active run"
        try:
            r = self.m.set_parameter(self.m.active, name, value)
            when = (f"from step {r['applies_from_step']}" if r["applied"]
                    else "from the next step")
            return f"{name} = {value:.4g} {when}"
        except (Conflict, Invalid, NotFound, NotReady) as exc:
            return str(exc)

    def scrub(self, step: int) -> tuple[dict | None, str]:
        """The kept frame to show for the time slider, or why none (a running run streams)."""
        history = self.m.history
        run = self.m.runs.get(history.run or "")
        if run is None:
            return None, "No run to scrub"
        if run.state in ("starting", "building", "running"):
            return None, f"Run `{run.id}` is {run.state}: pause it to scrub"
        frame = history.at(step)
        if frame is None:
            return None, "No frames yet"
        return frame, (f"Run `{run.id}` ({run.state})  \nshowing step {frame['step']}/"
                       f"{run.n_steps} (kept every {history.stride})")

    def recording(self, run_id: str) -> tuple[replay.Replay | None, str]:
        """An older run's recording to replay, with the status line; or None and why not."""
        run = self.m.runs.get(run_id)
        if run is None:
            return None, f"No run `{run_id}`"
        if run.id == self.m.active:
            return None, f"Run `{run_id}` is {run.state}: its recording is still being written"
        try:
            rep = replay.load(self.m.files.recording(run.id))
        except Exception as exc:
            return None, f"Cannot read the recording of `{run_id}`: {exc}"
        if not rep.steps or rep.faces is None:
            return None, f"The recording of `{run_id}` holds no sheet mesh"
        return rep, (f"Recording of `{run_id}` ({run.state}): {len(rep.steps)} frames, steps "
                     f"{rep.steps[0]}-{rep.steps[-1]} (coloured by thickness, as recorded)")

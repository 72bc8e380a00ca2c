"""One browser's viewer: its own GUI and scene on viser's per-client handles (``ClientHandle
.gui``, ``.scene``), so its run, colour mode, time slider, section, opacity and camera are its
own. It shows the run its view selects (``server.views``: the page's Runs table, its own "Run"
dropdown, a new run it started): live while the run is one of the latest (frames as the bridge
pushes them; the time slider follows the live step, and when the run is paused or over moving
it shows a kept frame), an older run from its recording (``run.rrd``, read in the background:
the slider scrubs its recorded frames), or a scene's preview before any run. Where the slider
was moved is told to the view, so the page marks that step in its plots.

The buttons and the live-parameter sliders act on the run shown, with the page's words (Pause,
Resume, Step, Stop); they are disabled while it is not active; beside each multiplier what it
makes of the scene's value (friction 0.1 × 2 = 0.2). Nothing here starts a run. What is drawn,
its colours and the controls of how are the canvas's (server.canvas). The control panel is
docked to the right, so it narrows the view instead of hiding the part. Every method is called
under the viewer's lock (the controls' callbacks take it themselves).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import viser

from server.canvas import Canvas
from server.colormap import EVERY_STEP, RUN_SUBJECT
from server.replay import Replay
from sim.stepping import parameters as live

# the page's run controls and what each sends, in the page's order and words
COMMANDS = {"Pause": "pause", "Resume": "resume", "Step": "step", "Stop": "stop"}
PANEL_WIDTH = 220
# s between the frames Play shows: a browser drawing in software keeps up, and a cup's
# recording (a frame every few steps) plays in a few seconds
PLAY_INTERVAL = 0.4
NO_RUN = "(no runs yet)"  # the "Run" dropdown's one option before any run (viser needs one)
# the scene's value a multiplier scales, in the units engineers read (as the page shows it)
SCALED_UNITS = {"m/step": ("mm/step", 1e3), "N": ("kN", 1e-3), "Pa": ("MPa", 1e-6),
                "m/s^2": ("m/s²", 1.0), "1": ("", 1.0)}


def scaled_text(items: list[dict], value: float, others: dict[str, float]) -> str:
    """``friction 0.1 × 2 = 0.2`` for each thing a multiplier scales; the other multipliers of
    the same value (``also``: a tool's friction, run-wide and its own) as ``others`` holds
    them, where they are not 1 (``die 0.1 × 2 × 1.5 = 0.3``), as the page writes it."""
    parts = []
    for it in items:
        unit, f = SCALED_UNITS.get(it["unit"], (it["unit"], 1.0))
        factors = [value, *(a for a in (others.get(k, 1.0) for k in it.get("also", ()))
                            if a != 1.0)]
        base = it["value"] * f
        parts.append(f"{it['what']} {base:.4g} × {' × '.join(f'{a:.4g}' for a in factors)} = "
                     f"{base * math.prod(factors):.4g}" + (f" {unit}" if unit else ""))
    return "; ".join(parts)


class Actions(Protocol):
    """What the controls call (``server.actions.ViewerActions``); each answers with the status
    line to show. ``view``: the browser's view that acts."""

    def command(self, view: str, run_id: str | None, cmd: str) -> str: ...
    def select(self, view: str, run_id: str) -> str: ...  # "" once selected, else why not
    def set_parameter(self, view: str, run_id: str | None, name: str, value: float) -> str: ...
    def scrub(self, run_id: str | None, step: int) -> tuple[dict | None, str]: ...
    def recording(self, run_id: str) -> tuple[Replay | None, str]: ...
    def scaled(self, run_id: str | None) -> dict: ...  # what each live parameter multiplies
    def shows_step(self, view: str, run_id: str | None, step: int | None) -> None: ...
    def connected(self, view: str) -> None: ...  # a browser's viewer of ``view`` is up


class Shared(Protocol):
    """What a browser's view reads of the viewer (``server.viewer.Viewer``)."""

    server: viser.ViserServer
    actions: Actions
    lock: threading.RLock
    colour_period: float
    lives: dict  # run id -> the viewer's ``Live``: a latest run's faces, tools, newest frame

    def from_code(self) -> AbstractContextManager[None]: ...
    def by_user(self, action: Callable[[], object]) -> Callable[[object], None]: ...


@dataclass
class Gui:
    status: viser.GuiMarkdownHandle
    sliders: dict  # live parameter -> slider
    results: dict  # live parameter -> markdown: what the slider makes of the scene's values
    time: viser.GuiSliderHandle
    run: viser.GuiDropdownHandle
    buttons: dict  # label -> button handle (Pause, Resume, Step, Stop: the page's words)
    play: viser.GuiCheckboxHandle  # the shown run played from the step shown to its end


class ClientView:
    def __init__(self, viewer: Shared, client: viser.ClientHandle, view: str):
        self.v, self.client, self.view = viewer, client, view
        self.actions, self.lock = viewer.actions, viewer.lock
        self.selected: str | None = None  # the run shown (its view's selection)
        self.line = ""  # its status line
        self.active = False  # whether it is active (its own colour ranges still grow)
        self.parameters: dict[str, float] = {}  # its live parameters
        self.scaled: dict[str, list[dict]] = {}  # what each multiplies (the scene's values)
        self.last_colour = 0.0
        self.scrubbed = False  # the time slider was moved by the user (the view knows where)
        # what is drawn: "live" (a latest run's frames), "replay" (a recording), "preview"
        # (a scene's rest state) or "none"
        self.mode = "none"
        self.replay: Replay | None = None  # a recorded run being shown
        self.replay_step = 0  # the recorded step it shows
        self.plays = 0  # Play's ticks: only the newest one's thread moves the slider
        self.previewed: str | None = None  # the scene previewed
        self.canvas: Canvas  # what is drawn: made with the GUI, its folders after ours
        self.gui = self._build_gui()

    # ---- the GUI ------------------------------------------------------------------------------
    def _build_gui(self) -> Gui:
        g, by_user = self.client.gui, self.v.by_user
        g.main_panel.dock_right()  # docked: it narrows the view instead of covering the part
        # px: under a third of the page's centre column at 1400 px, the view keeps the rest
        g.main_panel.set_width(PANEL_WIDTH)
        status = g.add_markdown("No run yet")
        buttons = {}
        with g.add_folder("Run"):
            run = g.add_dropdown("Run", (NO_RUN,), initial_value=NO_RUN,
                                 hint="the run shown here and on this browser's page (its "
                                      "Runs table picks it too)")
            for label, cmd in COMMANDS.items():
                buttons[label] = g.add_button(label, disabled=True)
                buttons[label].on_click(lambda _e, c=cmd: self.status(
                    self.actions.command(self.view, self.selected, c)))
        with g.add_folder("Time"):
            time_slider = g.add_slider("Step", min=0, max=1, step=1, initial_value=0,
                                       hint="pause the run (or let it finish), then drag")
            play = g.add_checkbox("Play", initial_value=False, disabled=True,
                                  hint="the run played back from the step shown to its end "
                                       "(a run that has ended, or is paused)")
        run.on_update(by_user(lambda: self._choose_run(run.value)))
        time_slider.on_update(by_user(self._scrub))
        play.on_update(by_user(self._play))
        self.param_folder = g.add_folder("Live parameters")
        with self.param_folder:  # what they act on: the run, never a scene previewed
            self.subject = g.add_markdown("")
        self.canvas = Canvas(self.client, self.v.server.initial_camera, self.lock, self.status,
                             by_user, self.v.from_code,
                             lambda: self.mode == "live" and self.active)
        return Gui(status, {}, {}, time_slider, run, buttons, play)

    def add_parameters(self, parameters: dict[str, tuple[float, float]]) -> None:
        """One slider per live parameter, each showing the shown run's value, and what it
        makes of the scene's values below it."""
        g = self.client.gui
        with self.param_folder:
            for name, (lo, hi) in parameters.items():
                if name in self.gui.sliders:
                    continue
                value = self.parameters.get(name, 1.0)  # no run shown: as written
                label, hint = live.label(name)
                # about 1000 steps of a round size: 1 (as written) is one of them
                step = 10.0 ** math.floor(math.log10((hi - lo) / 1000))
                s = g.add_slider(label, min=lo, max=hi, step=step,
                                 initial_value=min(max(value, lo), hi),
                                 disabled=not self.active, hint=f"{name}: {hint}")
                s.on_update(self.v.by_user(lambda n=name, h=s: self._on_slider(n, h)))
                self.gui.sliders[name] = s
                self.gui.results[name] = g.add_markdown("")
        self._show_results()

    def _say_subject(self) -> None:
        """Above the live parameters and under the run buttons: the run they act on, and that
        a scene previewed is not it (a scene changes only what the page's Start runs)."""
        text = ("<small>no run shown: they act on a running run</small>"
                if self.selected is None else f"<small>of run `{self.selected}`</small>")
        if self.selected is not None and self.mode == "preview":
            text = (f"<small>of run `{self.selected}`, not of the scene `{self.previewed}` "
                    "previewed</small>")
        if self.subject.content != text:
            self.subject.content = text

    def _show_results(self) -> None:
        """Beside each multiplier, what it makes of the scene's values (friction 0.1 × 2)."""
        values = {n: float(h.value) for n, h in self.gui.sliders.items()}
        for name, md in self.gui.results.items():
            text = scaled_text(self.scaled.get(name) or [], values[name], values)
            text = f"<small>{text}</small>" if text else ""
            if md.content != text:
                md.content = text

    def _choose_run(self, run_id: str) -> None:
        """A user picked a run: selected in this view, which shows it here (``show_run``) and
        on the page."""
        refused = self.actions.select(self.view, run_id)
        if refused:
            self.status(refused)

    def status(self, text: str) -> None:
        self.gui.status.content = text

    def _on_slider(self, name: str, handle: viser.GuiSliderHandle) -> None:
        with self.lock:
            self._show_results()
        self.status(self.actions.set_parameter(self.view, self.selected, name,
                                               float(handle.value)))

    def set_parameter_value(self, run_id: str, name: str, value: float) -> None:
        """A live parameter of ``run_id`` changed: its slider follows if the run is shown."""
        if run_id != self.selected:
            return
        self.parameters[name] = value
        if name in self.gui.sliders:
            with self.v.from_code():
                self.gui.sliders[name].value = value
            self._show_results()

    def _show_parameters(self, values: dict[str, float]) -> None:
        """The sliders show the shown run's values; its per-tool multipliers (Friction × die)
        have a slider each while it is shown, after the run-wide ones, as on the page."""
        self.parameters = dict(values)
        self.scaled = self.actions.scaled(self.selected)
        tools = live.per_tool_of(values)
        for name in [n for n in live.per_tool_of(self.gui.sliders) if n not in tools]:
            self.gui.sliders.pop(name).remove()
            self.gui.results.pop(name).remove()
        self.add_parameters(tools)
        with self.v.from_code():
            for name, s in self.gui.sliders.items():
                if name in values:
                    s.value = min(max(values[name], s.min), s.max)
        self._show_results()

    def _enable(self, active: bool, controls: Sequence[str]) -> None:
        """The live parameters act on the shown run while it is active; each button while
        its command does (the page's rule: ``Run.controls``)."""
        self.active = active
        for h in self.gui.sliders.values():
            h.disabled = not active
        for label, cmd in COMMANDS.items():
            self.gui.buttons[label].disabled = cmd not in controls
        # a running run's slider follows it; paused or ended, it plays back
        running = active and "pause" in controls
        self.gui.play.disabled = running
        if running:
            self._stop_play()

    def set_runs(self, run_ids: tuple[str, ...]) -> None:
        options = run_ids or (NO_RUN,)
        if tuple(self.gui.run.options) == options:
            return
        with self.v.from_code():  # viser keeps the value while offered, else the first
            self.gui.run.options = options
            self.gui.run.value = self.selected if self.selected in options else options[0]

    # ---- what is shown ------------------------------------------------------------------------
    def show_run(self, run_id: str | None, parameters: dict[str, float], active: bool,
                 controls: Sequence[str], line: str) -> None:
        """Show the view's run: live if it is one of the latest, else its recording (loaded
        in the background: a large one takes seconds); nothing else meanwhile."""
        with self.lock:
            self.selected, self.scrubbed, self.line = run_id, False, line
            if run_id is not None and run_id in self.gui.run.options:
                with self.v.from_code():
                    self.gui.run.value = run_id
            self._show_parameters(parameters)
            self._enable(active, controls)
            if run_id is not None and run_id in self.v.lives:
                if self.mode == "live":
                    self.status(line)
                    self._say_subject()
                else:
                    self._show_live(line)
                return
            self._clear(line)
            if run_id is None or active:
                return  # an active run not built yet: its meta (``new_run``) shows it
            self.status(f"{line}  \nloading its recording…")
        threading.Thread(target=self._load, args=(run_id, line), daemon=True,
                         name="q3t-viewer-load").start()

    def run_status(self, run_id: str, line: str, active: bool,
                   controls: Sequence[str]) -> None:
        if run_id != self.selected:
            return
        self.line = line
        if self.mode != "preview":
            self.status(line)
        was = self.active
        self._enable(active, controls)
        if was and not active and self.mode == "live":
            self.canvas.recolour()  # the legend: the run's range, no longer growing

    def left_live(self, run_id: str) -> None:
        """An ended run is no longer one of the latest (its kept frames are gone): shown from
        its recording from now on."""
        if run_id != self.selected or self.mode != "live":
            return
        self._clear(f"{self.line}  \nloading its recording…")
        threading.Thread(target=self._load, args=(run_id, self.line), daemon=True,
                         name="q3t-viewer-load").start()

    def new_run(self, run_id: str, line: str, parameters: dict[str, float]) -> None:
        """A latest run is built: shown if it is this view's run."""
        if run_id == self.selected:
            self._show_parameters(parameters)
            self._show_live(line)

    def show_preview(self, scene: str, faces: np.ndarray, tools: list[dict], frame: dict,
                     line: str) -> None:
        """A scene's rest state before any run: its blank (``frame``: the solver's frame of the
        built model at step 0) and its tools at their start positions."""
        with self.lock:
            self.mode, self.replay, self.previewed = "preview", None, scene
            self.canvas.set_scene(np.asarray(faces, np.uint32),
                                  [(t["name"], t["vertices"], t["faces"]) for t in tools])
            self.canvas.palette.ranges.show({}, f"the blank of scene {scene} at rest (no run)")
            self.canvas.palette.ranges.add(frame["fields"])
            with self.v.from_code():
                self.gui.time.value, self.gui.time.max = 0, 1
            self.canvas.draw(frame, colour=True)
            self.status(line)
            self._say_subject()

    def clear(self, line: str) -> None:
        with self.lock:
            self._clear(line)

    def _clear(self, line: str) -> None:
        self._stop_play()
        self.mode, self.replay, self.previewed = "none", None, None
        self.canvas.clear()
        self.status(line)
        self._say_subject()

    def _load(self, run_id: str, line: str) -> None:
        """Read ``run_id``'s recording and show it, unless another run was selected since."""
        rep, message = self.actions.recording(run_id)
        with self.lock:
            if self.selected != run_id or self.mode != "none":
                return
            if rep is None:
                self.status(f"{line}  \n{message}")
                return
            self.replay = rep
            self.canvas.set_scene(rep.faces, [(n, V, F) for n, (V, F) in rep.tools.items()])
            # a recorded run is over: its range is known at once, over every step when its
            # record has it (the recording keeps every N-th), else over the frames kept
            ranges = self.canvas.palette.ranges
            ranges.show({}, EVERY_STEP if rep.ranges else RUN_SUBJECT)
            self.canvas.card_thinning(rep.thinning_limit)
            for fields in rep.fields:
                ranges.add(fields)
            ranges.add({k: np.asarray(v, float) for k, v in rep.ranges.items()})
            with self.v.from_code():
                self.gui.time.max = max(1, rep.steps[-1])
                self.gui.time.value = rep.steps[-1]
            self._show_recorded(rep.steps[-1], f"{line}  \n{message}")
            self.mode = "replay"  # last: a reader outside the lock finds it all drawn

    def _show_live(self, line: str) -> None:
        """The shown (live) run's sheet and tools, and its latest frame."""
        self.mode, self.replay, self.previewed = "live", None, None
        self._say_subject()
        live = self.v.lives[self.selected]
        self.canvas.set_scene(live.faces, [(t["name"], t["vertices"], t["faces"])
                                           for t in live.tools])
        self.canvas.palette.ranges.show(live.seen)
        self.canvas.card_thinning(live.thinning_limit)
        with self.v.from_code():
            self.gui.time.value, self.gui.time.max = 0, 1
        if live.frame is not None:
            self.show(live.frame, line, final=True)
        else:
            self.status(line)

    def _show_recorded(self, step: int, message: str, forward: bool = False) -> int:
        """The recorded frame at ``step`` or the nearest before it (``forward``: after it, so
        that a slider moved on by one step from a recorded frame reaches the next one); returns
        its step."""
        rep = self.replay
        if forward:
            i = min(int(np.searchsorted(rep.steps, step, side="left")), len(rep.steps) - 1)
        else:
            i = max(int(np.searchsorted(rep.steps, step, side="right")) - 1, 0)
        self.replay_step = int(rep.steps[i])
        with self.client.atomic():
            self.canvas.draw(rep.frame(i), colour=True)
            self.status(f"{message}  \nshowing recorded step {rep.steps[i]}")
        return int(rep.steps[i])

    def _set_time(self, step: int) -> None:
        """Move the time slider to the live step (its end grows with the run)."""
        with self.v.from_code():
            self.gui.time.max = max(1, int(step), int(self.gui.time.max))
            self.gui.time.value = int(step)

    def _play(self) -> None:
        """Play ticked: the time slider moves on by itself, a frame every PLAY_INTERVAL, as
        a user's drag would (``_scrub`` draws each), from the step shown (from the start when
        that is the last) to the run's last step; then Play unticks itself."""
        with self.lock:
            self.plays += 1
            if not self.gui.play.value:
                return
            if self.mode not in ("live", "replay"):  # nothing shown to play back
                self._stop_play()
                return
            gen = self.plays
        if self.gui.time.value >= self.gui.time.max:
            self.gui.time.value = 0  # as a drag back to the start: its frame drawn
        threading.Thread(target=self._playing, args=(gen,), daemon=True,
                         name="q3t-viewer-play").start()

    def _stop_play(self) -> None:
        """Play unticked by the code (under lock): its end, or the run shown changed."""
        self.plays += 1
        if self.gui.play.value:
            with self.v.from_code():
                self.gui.play.value = False

    def _playing(self, gen: int) -> None:
        run = self.selected
        while True:
            time.sleep(PLAY_INTERVAL)
            with self.lock:
                if gen != self.plays:  # unticked, ticked again, or stopped by the code
                    return
                now, end = int(self.gui.time.value), int(self.gui.time.max)
                if (self.selected != run or self.mode not in ("live", "replay")
                        or now >= end):
                    self._stop_play()
                    return
                if self.mode == "replay":  # the next recorded frame
                    steps = self.replay.steps
                    i = int(np.searchsorted(steps, now, side="right"))
                    target = int(steps[min(i, len(steps) - 1)])
                else:  # a live run's kept frames: about 40 of them over the run
                    target = min(end, now + max(1, end // 40))
            # as a drag: the slider's callback draws the frame and tells the page
            self.gui.time.value = target

    def _scrub(self) -> None:
        """A user moved the time slider: the frame at that step, and the view told."""
        step = int(self.gui.time.value)
        with self.lock:
            run, mode = self.selected, self.mode
            if mode == "replay":
                asked, step = step, self._show_recorded(step, f"Recording of `{run}`",
                                                        forward=step > self.replay_step)
                if step != asked:  # the box says the step drawn, not the one asked
                    with self.v.from_code():
                        self.gui.time.value = step
        if mode == "replay":
            self.scrubbed = True
            self.actions.shows_step(self.view, run, step)
        if mode != "live":
            return
        frame, message = self.actions.scrub(run, step)
        if frame is None:
            self.status(message)
            live = self.v.lives.get(run or "")
            if live is not None and live.frame is not None:
                self._set_time(live.frame["step"])
            return
        self.show(frame, message, final=True, live=False)
        self.scrubbed = True
        self.actions.shows_step(self.view, run, int(frame["step"]))

    def show(self, frame: dict, status: str, final: bool = False, live: bool = True) -> None:
        """Draw one frame of the shown run: positions always, colours when due or final. A
        live frame also moves the time slider; a scrubbed one (``live=False``) leaves it where
        the user put it."""
        with self.lock:
            if self.canvas.faces is None or self.mode != "live" or (
                    live and frame["run"] != self.selected):
                return  # another run is shown here
            now = time.perf_counter()
            if live and self.scrubbed:  # the run goes on: the slider follows it again
                self.scrubbed = False
                self.actions.shows_step(self.view, self.selected, None)
            with self.client.atomic():
                if live:
                    self._set_time(frame["step"])
                due = final or now - self.last_colour >= self.v.colour_period
                self.canvas.draw(frame, colour=due)
                if due:
                    self.last_colour = now
                self.status(status)

"""The viser viewer: the selected run's sheet coloured by a field on a fixed scale, a legend that
stays in view, the tools (translucent, or cut by a section plane), a scene's preview, and the
page's run controls mirrored.

It never sees the solver: the bridge hands it frames (dicts of arrays), the run manager tells it
which run is selected (or which scene to preview), and it calls back into the run manager
through ``Actions``. What is drawn, its colours and the controls of how are the canvas's
(server.canvas); here, which frames it draws: the coloured surface at most ``colour_hz`` times a
second (a glTF of the whole sheet), always the last frame of a run, positions in between. The
control panel is docked to the right, so it narrows the view instead of hiding the part.

It shows the run selected on the server (``server.views``: the page's Runs table, its own
"Run" dropdown, a new run), the same one the page shows. The latest runs (one per solver
process) are shown live: frames as the bridge pushes them, and the time slider follows the live
step; when the run is paused or over, moving it shows a kept frame (``RunManager.history``).
The frames of a latest run not selected are kept, not drawn. An older run is shown from its
recording (``run.rrd``, read with ``server.replay`` in the background): the slider scrubs its
recorded frames. A scene chosen on the page is previewed (``show_preview``): its blank and tools
at the start, built by the solver process before any run. The buttons and the live-parameter
sliders act on the selected run, with the page's words (Pause, Resume, Step, Stop); they are
disabled while it is not active. Nothing here starts a run: that is the page's Start.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import viser

from server.canvas import Canvas
from server.colormap import grow
from server.replay import Replay
from sim.stepping.parameters import LABELS


class Actions(Protocol):
    """What the controls call (``server.actions.ViewerActions``); each answers with the status
    line to show."""

    def command(self, cmd: str) -> str: ...
    def select(self, run_id: str) -> str: ...  # "" once selected, else why not
    def set_parameter(self, name: str, value: float) -> str: ...
    def scrub(self, step: int) -> tuple[dict | None, str]: ...
    def recording(self, run_id: str) -> tuple[Replay | None, str]: ...


@dataclass
class Gui:
    status: viser.GuiMarkdownHandle
    sliders: dict
    time: viser.GuiSliderHandle
    run: viser.GuiDropdownHandle
    buttons: dict  # label -> button handle (Pause, Resume, Step, Stop: the page's words)


@dataclass
class Live:
    """A latest run, shown live when selected: its sheet's faces, its tools (meshes sent
    once), its newest frame and its fields' ranges so far."""

    faces: np.ndarray
    tools: list[dict]
    frame: dict | None = None
    seen: dict[str, tuple[float, float]] = field(default_factory=dict)
    ended: bool = False  # the run is over: its place may go to a newer run


# the page's run controls and what each sends, in the page's order and words
COMMANDS = {"Pause": "pause", "Resume": "resume", "Step": "step", "Stop": "stop"}
NO_RUN = "(no runs yet)"  # the "Run" dropdown's one option before any run (viser needs one)


class Viewer:
    def __init__(self, host: str, port: int, actions: Actions, colour_hz: float = 4.0,
                 live_runs: int = 1):
        """``live_runs``: how many of the latest runs are kept live (one per solver)."""
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        # embedded in the page's centre column the panel took half the view: the narrow one,
        # and no share button (a share link would expose the run's controls)
        self.server.gui.configure_theme(control_width="small", show_share_button=False)
        self.actions = actions
        self.colour_period = 1.0 / colour_hz
        self.lock = threading.RLock()  # viser runs update callbacks in the assigning thread
        self.last_colour = 0.0
        self._code = threading.local()  # .on while this thread's GUI changes are the code's
        self.selected: str | None = None  # the run shown (the server's selection)
        self.active = False  # whether it is active (its own colour ranges still grow)
        self.parameters: dict[str, float] = {}  # its live parameters
        self.live_run: str | None = None  # the latest run built
        self.lives: dict[str, Live] = {}  # the latest runs built, oldest first
        self.live_runs = max(1, live_runs)
        # what is drawn: "live" (the latest run's frames), "replay" (a recording), "preview"
        # (a scene's rest state) or "none"
        self.mode = "none"
        self.replay: Replay | None = None  # a recorded run being shown
        self.previewed: str | None = None  # the scene previewed
        self.canvas: Canvas  # what is drawn: made with the GUI, its folders after ours
        self.gui = self._build_gui()

    @property
    def port(self) -> int:
        return self.server.get_port()

    @contextmanager
    def _from_code(self) -> Iterator[None]:
        """GUI values set inside are the code's, not a user's: their callbacks do nothing.
        viser runs the callbacks of a value set in code at once, in the thread that set it, so
        the mark is per thread: a user's change arriving meanwhile (in viser's threads, or a
        test's) is still the user's."""
        before = getattr(self._code, "on", False)
        self._code.on = True
        try:
            yield
        finally:
            self._code.on = before

    def _by_user(self, action: Callable[[], object]) -> Callable[[object], None]:
        """An ``on_update`` callback that runs ``action()`` for a user's change only."""
        return lambda _e: None if getattr(self._code, "on", False) else action()

    # ---- the GUI ------------------------------------------------------------------------------
    def _build_gui(self) -> Gui:
        g = self.server.gui
        # docked, the control panel narrows the view instead of covering the part
        g.main_panel.dock_right()
        status = g.add_markdown("No run yet")
        buttons = {}
        with g.add_folder("Run"):
            run = g.add_dropdown("Run", (NO_RUN,), initial_value=NO_RUN,
                                 hint="the run shown here and on the page (its Runs table "
                                      "picks it too)")
            for label, cmd in COMMANDS.items():
                buttons[label] = g.add_button(label, disabled=True)
                buttons[label].on_click(lambda _e, c=cmd: self._status(
                    self.actions.command(c)))
        with g.add_folder("Time"):
            time_slider = g.add_slider("Step", min=0, max=1, step=1, initial_value=0,
                                       hint="pause the run (or let it finish), then drag")
        run.on_update(self._by_user(lambda: self._choose_run(run.value)))
        time_slider.on_update(self._by_user(self._scrub))
        self.param_folder = g.add_folder("Live parameters")
        self.canvas = Canvas(self.server, self.lock, self._status, self._by_user,
                             self._from_code, lambda: self.mode == "live" and self.active)
        return Gui(status, {}, time_slider, run, buttons)

    def add_parameters(self, parameters: dict[str, tuple[float, float]]) -> None:
        """One slider per live parameter, once the solver process has said which exist; each
        shows the selected run's value."""
        with self.lock, self.param_folder:
            active = not self.gui.buttons["Pause"].disabled
            for name, (lo, hi) in parameters.items():
                value = self.parameters.get(name, 1.0)  # no run shown: as written
                label, hint = LABELS.get(name, (name, ""))
                # about 1000 steps of a round size: 1 (as written) is one of them
                step = 10.0 ** math.floor(math.log10((hi - lo) / 1000))
                s = self.server.gui.add_slider(label, min=lo, max=hi, step=step,
                                               initial_value=min(max(value, lo), hi),
                                               disabled=not active, hint=f"{name}: {hint}")
                s.on_update(self._by_user(lambda n=name, h=s: self._on_slider(n, h)))
                self.gui.sliders[name] = s

    def _choose_run(self, run_id: str) -> None:
        """A user picked a run: selected on the server, which shows it here (``show_run``)."""
        refused = self.actions.select(run_id)
        if refused:
            self._status(refused)

    def _status(self, text: str) -> None:
        self.gui.status.content = text

    def _on_slider(self, name: str, handle: viser.GuiSliderHandle) -> None:
        self._status(self.actions.set_parameter(name, float(handle.value)))

    def set_parameter_value(self, run_id: str, name: str, value: float) -> None:
        """A live parameter of ``run_id`` changed: its slider follows if the run is shown."""
        with self.lock:
            if run_id != self.selected:
                return
            self.parameters[name] = value
            if name in self.gui.sliders:
                with self._from_code():
                    self.gui.sliders[name].value = value

    def _show_parameters(self, values: dict[str, float]) -> None:
        """The sliders show the selected run's values (under lock)."""
        self.parameters = dict(values)
        with self._from_code():
            for name, s in self.gui.sliders.items():
                if name in values:
                    s.value = min(max(values[name], s.min), s.max)

    def _enable(self, active: bool) -> None:
        """Run controls act on the selected run: only while it is active (under lock)."""
        self.active = active
        for h in (*self.gui.buttons.values(), *self.gui.sliders.values()):
            h.disabled = not active

    def set_runs(self, run_ids: list[str]) -> None:
        """The runs the "Run" dropdown offers (newest first)."""
        with self.lock:
            options = tuple(run_ids) or (NO_RUN,)
            if tuple(self.gui.run.options) == options:
                return
            with self._from_code():  # viser keeps the value while offered, else the first
                self.gui.run.options = options
                self.gui.run.value = self.selected if self.selected in options else options[0]

    def show_run(self, run_id: str | None, parameters: dict[str, float], active: bool,
                 line: str) -> None:
        """Show the selected run: live if it is the latest, else its recording (loaded in the
        background: a large one takes seconds); nothing else meanwhile. ``line``: its status
        line; ``active``: whether the run controls act on it."""
        with self.lock:
            self.selected = run_id
            if run_id is not None and run_id in self.gui.run.options:
                with self._from_code():
                    self.gui.run.value = run_id
            self._show_parameters(parameters)
            self._enable(active)
            if run_id is not None and run_id in self.lives:
                if self.mode == "live":
                    self.gui.status.content = line
                else:
                    self._show_live(line)
                return
            self._clear(line)
            if run_id is None or active:
                return  # an active run not built yet: its meta (``new_run``) shows it
            self.gui.status.content = f"{line}  \nloading its recording…"
        threading.Thread(target=self._load, args=(run_id, line), daemon=True,
                         name="q3t-viewer-load").start()

    def run_status(self, run_id: str, line: str, active: bool) -> None:
        """A run's state changed: its line and whether the controls act on it, if it is shown."""
        with self.lock:
            if run_id in self.lives:
                self.lives[run_id].ended = not active
            if run_id == self.selected and self.mode != "preview":
                self.gui.status.content = line
            if run_id == self.selected:
                was = self.active
                self._enable(active)
                if was and not active and self.mode == "live":
                    self.canvas.recolour()  # the legend: the run's range, no longer growing

    def new_run(self, run_id: str, faces: np.ndarray, tools: list[dict], line: str,
                parameters: dict[str, float]) -> None:
        """A run is built: its sheet's faces and its tools (meshes sent once), kept live in
        place of the oldest live run that is over and not shown, and shown when it is the
        selected run."""
        with self.lock:
            self.live_run = run_id
            self.lives[run_id] = Live(np.asarray(faces, np.uint32), list(tools))
            for old in [r for r, v in self.lives.items() if v.ended and r != self.selected]:
                if len(self.lives) <= self.live_runs:
                    break
                del self.lives[old]
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
            self.canvas.palette.ranges.seen = {}
            self.canvas.palette.ranges.add(frame["fields"])
            with self._from_code():
                self.gui.time.value, self.gui.time.max = 0, 1
            self.canvas.draw(frame, colour=True)
            self.gui.status.content = line

    def preview_status(self, line: str) -> None:
        """Why a preview is not shown (yet): building, or its build failed."""
        with self.lock:
            self.gui.status.content = line

    def _clear(self, line: str) -> None:
        """Nothing drawn, the line shown (under lock)."""
        self.mode, self.replay, self.previewed = "none", None, None
        self.canvas.clear()
        self.gui.status.content = line

    def _load(self, run_id: str, line: str) -> None:
        """Read ``run_id``'s recording and show it, unless another run was selected since."""
        rep, message = self.actions.recording(run_id)
        with self.lock:
            if self.selected != run_id or self.mode != "none":
                return
            if rep is None:
                self.gui.status.content = f"{line}  \n{message}"
                return
            self.replay = rep
            self.canvas.set_scene(rep.faces, [(n, V, F) for n, (V, F) in rep.tools.items()])
            self.canvas.palette.ranges.seen = {}
            for fields in rep.fields:  # a recorded run is over: its range is known at once
                self.canvas.palette.ranges.add(fields)
            with self._from_code():
                self.gui.time.max = max(1, rep.steps[-1])
                self.gui.time.value = rep.steps[-1]
            self._show_recorded(rep.steps[-1], f"{line}  \n{message}")
            self.mode = "replay"  # last: a reader outside the lock finds it all drawn

    def _show_live(self, line: str) -> None:
        """The selected (live) run's sheet and tools, and its latest frame (under lock)."""
        self.mode, self.replay, self.previewed = "live", None, None
        live = self.lives[self.selected]
        self.canvas.set_scene(live.faces, [(t["name"], t["vertices"], t["faces"])
                                           for t in live.tools])
        self.canvas.palette.ranges.seen = live.seen
        with self._from_code():
            self.gui.time.value, self.gui.time.max = 0, 1
        if live.frame is not None:
            self.show(live.frame, line, final=True)
        else:
            self.gui.status.content = line

    def _show_recorded(self, step: int, message: str) -> None:
        """The recorded frame at ``step`` or the nearest before it (under lock)."""
        rep = self.replay
        i = max(int(np.searchsorted(rep.steps, step, side="right")) - 1, 0)
        with self.server.atomic():
            self.canvas.draw(rep.frame(i), colour=True)
            self.gui.status.content = f"{message}  \nshowing recorded step {rep.steps[i]}"

    def _set_time(self, step: int) -> None:
        """Move the time slider to the live step (its end grows with the run)."""
        with self._from_code():
            self.gui.time.max = max(1, int(step), int(self.gui.time.max))
            self.gui.time.value = int(step)

    def _scrub(self) -> None:
        with self.lock:
            if self.mode == "replay":
                self._show_recorded(int(self.gui.time.value),
                                    f"Recording of `{self.selected}`")
                return
            if self.mode != "live":
                return
        frame, message = self.actions.scrub(int(self.gui.time.value))
        if frame is None:
            self._status(message)
            live = self.lives.get(self.selected or "")
            if live is not None and live.frame is not None:
                self._set_time(live.frame["step"])
            return
        self.show(frame, message, final=True, live=False)

    def show(self, frame: dict, status: str, final: bool = False, live: bool = True) -> None:
        """Push one frame: positions always, colours when due or final. A live frame also moves
        the time slider; a scrubbed one (``live=False``) leaves it where the user put it."""
        with self.lock:
            run = self.lives.get(frame.get("run") or "")
            if live and run is None:
                return  # a frame of an earlier run, pushed late
            if live:
                run.frame = frame
            self.live_seen_add(frame)
            if self.canvas.faces is None or self.mode != "live" or (
                    live and frame["run"] != self.selected):
                return  # another run is shown: the live run is kept, not drawn
            now = time.perf_counter()
            with self.server.atomic():
                if live:
                    self._set_time(frame["step"])
                due = final or now - self.last_colour >= self.colour_period
                self.canvas.draw(frame, colour=due)
                if due:
                    self.last_colour = now
                self.gui.status.content = status

    def live_seen_add(self, frame: dict) -> None:
        """A live run's colour ranges hold every frame of it shown or kept for showing."""
        live = self.lives.get(frame.get("run") or "")
        if live is not None:
            grow(live.seen, frame["fields"])

    def stop(self) -> None:
        self.server.stop()

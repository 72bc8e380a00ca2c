"""The viser viewer: the selected run's sheet coloured by a field, a legend, the tools, and the
page's run controls mirrored.

It never sees the solver: the bridge hands it frames (dicts of arrays), the run manager tells it
which run is selected, and it calls back into the run manager through ``Actions``. Positions
stream to a wireframe every push (about 0.1 ms at 40k vertices); the coloured surface is a glTF
re-sent at most ``colour_hz`` times a second (about 10 ms and 1.5 MB at 40k vertices), always on
the last frame of a run. Each tool is one single-colour, semi-transparent mesh sent once per
run; frames only move it (``.position``). The colour dropdown offers every field the frames carry.

It shows the run selected on the server (``RunManager.select``: the page's Runs table, its own
"Run" dropdown, a new run), the same one the page shows. The latest run is shown live: frames as
the bridge pushes them, and the time slider follows the live step; when the run is paused or
over, moving it shows a kept frame (``RunManager.history``). An older run is shown from its
recording (``run.rrd``, read with ``server.replay`` in the background): the slider scrubs its
recorded frames, coloured by thickness as recorded. The buttons and the live-parameter sliders
act on the selected run, with the page's words (Pause, Resume, Step, Stop); they are disabled
while it is not active. Nothing here starts a run: that is the page's Start.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Collection, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import trimesh
import viser

from server.colormap import MIN_SPAN, colorize, legend_html, tool_colour, value_range
from server.replay import Replay
from sim.stepping.parameters import LABELS

# field key -> (label, unit); the dropdown shows "label (unit)"
FIELDS = {"thickness_mm": ("Thickness", "mm"), "thinning_pct": ("Thinning", "%"),
          "eq_plastic_strain": ("Equivalent plastic strain", "-"),
          "von_mises_MPa": ("von Mises stress", "MPa"),
          "major_strain": ("Major true strain", "-"), "minor_strain": ("Minor true strain", "-")}
DEFAULT_FIELD = "thickness_mm"


def field_label(key: str) -> str:
    label, unit = FIELDS.get(key, (key, ""))
    return f"{label} ({unit})" if unit else label


def field_options(keys: Collection[str]) -> dict[str, str]:
    """Dropdown label -> field key for the fields a frame carries, known fields first."""
    ordered = [k for k in FIELDS if k in keys] + sorted(k for k in keys if k not in FIELDS)
    return {field_label(k): k for k in ordered}


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
    field: viser.GuiDropdownHandle
    legend: viser.GuiHtmlHandle
    sliders: dict
    time: viser.GuiSliderHandle
    run: viser.GuiDropdownHandle
    buttons: dict  # label -> button handle (Pause, Resume, Step, Stop: the page's words)


# the page's run controls and what each sends, in the page's order and words
COMMANDS = {"Pause": "pause", "Resume": "resume", "Step": "step", "Stop": "stop"}
NO_RUN = "(no runs yet)"  # the "Run" dropdown's one option before any run (viser needs one)


class Viewer:
    def __init__(self, host: str, port: int, actions: Actions, colour_hz: float = 4.0):
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.actions = actions
        self.colour_period = 1.0 / colour_hz
        self.lock = threading.RLock()  # viser runs update callbacks in the assigning thread
        self.faces: np.ndarray | None = None
        self.surface = self.wire = None
        self.tools: dict[str, object] = {}  # tool name -> viser mesh handle
        self.options = field_options(FIELDS)  # dropdown label -> field key
        self.last_colour = 0.0
        self.frame: dict | None = None
        self._code = threading.local()  # .on while this thread's GUI changes are the code's
        self.selected: str | None = None  # the run shown (the server's selection)
        self.parameters: dict[str, float] = {}  # its live parameters
        self.live_run: str | None = None  # the latest run, whose frames the bridge pushes
        self.live_faces: np.ndarray | None = None
        self.live_tools: list[dict] = []
        # what is drawn: "live" (the latest run's frames), "replay" (a recording) or "none"
        self.mode = "none"
        self.replay: Replay | None = None  # a recorded run being shown
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

    def _build_gui(self) -> Gui:
        g = self.server.gui
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
        with g.add_folder("Colour"):
            field = g.add_dropdown("Colour by", tuple(field_options(FIELDS)),
                                   initial_value=field_label(DEFAULT_FIELD))
            legend = g.add_html("")
        field.on_update(self._by_user(self._recolour))
        return Gui(status, field, legend, {}, time_slider, run, buttons)

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
            if run_id is not None and run_id == self.live_run:
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
            if run_id == self.selected:
                self.gui.status.content = line
                self._enable(active)

    def new_run(self, run_id: str, faces: np.ndarray, tools: list[dict], line: str,
                parameters: dict[str, float]) -> None:
        """The latest run is built: its sheet's faces and its tools (meshes sent once), shown
        live when it is the selected run."""
        with self.lock:
            self.live_run = run_id
            self.live_faces = np.asarray(faces, np.uint32)
            self.live_tools = list(tools)
            self.frame = None
            if run_id == self.selected:
                self._show_parameters(parameters)
                self._show_live(line)

    def _clear(self, line: str) -> None:
        """Nothing drawn, the line shown (under lock)."""
        self.mode, self.replay = "none", None
        self._set_scene(None, [])
        self.gui.legend.content = ""
        self.gui.status.content = line

    def _set_scene(self, faces: np.ndarray | None, tools: list[tuple]) -> None:
        """Replace the sheet's faces (None: no sheet) and the tool meshes ``[(name, V, F)]``
        (under lock)."""
        for h in (self.surface, self.wire, *self.tools.values()):
            if h is not None:
                h.remove()
        self.surface = self.wire = None
        self.faces = faces
        self.tools = {}
        for i, (name, V, F) in enumerate(tools):
            rgb, alpha = tool_colour(i)
            self.tools[name] = self.server.scene.add_mesh_simple(
                f"/tools/{name}", np.asarray(V, np.float32), np.asarray(F, np.uint32),
                color=rgb, opacity=alpha, side="double", cast_shadow=False,
                receive_shadow=False)

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
            self._set_scene(rep.faces, [(n, V, F) for n, (V, F) in rep.tools.items()])
            with self._from_code():
                self.gui.time.max = max(1, rep.steps[-1])
                self.gui.time.value = rep.steps[-1]
            self._show_recorded(rep.steps[-1], f"{line}  \n{message}")
            self._aim(rep.positions[-1])
            self.mode = "replay"  # last: a reader outside the lock finds it all drawn

    def _show_live(self, line: str) -> None:
        """The latest run's sheet and tools, and its latest frame (under lock)."""
        self.mode, self.replay = "live", None
        self._set_scene(self.live_faces, [(t["name"], t["vertices"], t["faces"])
                                          for t in self.live_tools])
        with self._from_code():
            self.gui.time.value, self.gui.time.max = 0, 1
        if self.frame is not None:
            self.show(self.frame, line, final=True)
        else:
            self.gui.status.content = line

    def _show_recorded(self, step: int, message: str) -> None:
        """The recorded frame at ``step`` or the nearest before it (under lock)."""
        rep = self.replay
        i = max(int(np.searchsorted(rep.steps, step, side="right")) - 1, 0)
        k = rep.steps[i]
        rgba = np.c_[rep.colors[i], np.full(len(rep.colors[i]), 255, np.uint8)]
        mesh = trimesh.Trimesh(rep.positions[i], rep.faces, process=False, vertex_colors=rgba)
        with self.server.atomic():
            self.surface = self.server.scene.add_mesh_trimesh("/sheet/surface", mesh)
            for name, h in self.tools.items():
                h.position = np.asarray(rep.pose(name, k), np.float64)
                h.wxyz = rep.rotation(name, k)
            self.gui.legend.content = ("<div class='q3t-legend'><b>Thickness</b>, colours as "
                                       "recorded (each frame's min to max)</div>")
            self.gui.status.content = f"{message}  \nshowing recorded step {k}"

    def _set_fields(self, keys: Collection[str]) -> None:
        """Offer exactly the fields this frame carries; keep the choice when still offered."""
        options = field_options(keys)
        if options == self.options:
            return
        current = self.options.get(self.gui.field.value, DEFAULT_FIELD)
        self.options = options
        keep = next((lab for lab, k in options.items() if k == current),
                    next((lab for lab, k in options.items() if k == DEFAULT_FIELD),
                         next(iter(options))))
        with self._from_code():
            self.gui.field.options = tuple(options)
            self.gui.field.value = keep

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
            if self.mode == "none":
                return
        frame, message = self.actions.scrub(int(self.gui.time.value))
        if frame is None:
            self._status(message)
            live = self.frame
            if live is not None:
                self._set_time(live["step"])
            return
        self.show(frame, message, final=True, live=False)

    def _move_tools(self, frame: dict) -> None:
        for name, pose in (frame.get("tools") or {}).items():
            h = self.tools.get(name)
            if h is not None:
                h.position = np.asarray(pose, np.float64)
        for name, wxyz in (frame.get("tool_rotations") or {}).items():
            h = self.tools.get(name)
            if h is not None:
                h.wxyz = np.asarray(wxyz, np.float64)

    def show(self, frame: dict, status: str, final: bool = False, live: bool = True) -> None:
        """Push one frame: positions always, colours when due or final. A live frame also moves
        the time slider; a scrubbed one (``live=False``) leaves it where the user put it."""
        with self.lock:
            if live and frame.get("run") != self.live_run:
                return  # a frame of an earlier run, pushed late
            if live:
                self.frame = frame
            if self.faces is None or self.mode != "live":
                return  # another run is shown: the live run is kept, not drawn
            self.frame = frame
            now = time.perf_counter()
            with self.server.atomic():
                self._set_fields(frame["fields"])
                self._move_tools(frame)
                if live:
                    self._set_time(frame["step"])
                if self.wire is None:
                    self.wire = self.server.scene.add_mesh_simple(
                        "/sheet/wire", frame["positions"], self.faces, wireframe=True,
                        color=(60, 60, 60), opacity=0.25)
                    self._aim(frame["positions"])
                else:
                    self.wire.vertices = frame["positions"]
                if final or self.surface is None or now - self.last_colour >= self.colour_period:
                    self._send_surface(frame)
                    self.last_colour = now
                self.gui.status.content = status

    def _recolour(self) -> None:
        with self.lock:
            if self.frame is not None and self.faces is not None and self.mode == "live":
                self._send_surface(self.frame)

    def _send_surface(self, frame: dict) -> None:
        key = self.options.get(self.gui.field.value, DEFAULT_FIELD)
        if key not in frame["fields"]:
            key = next(iter(frame["fields"]))
        values = frame["fields"][key]
        lo, hi = value_range(values, MIN_SPAN.get(key, 1e-6))
        rgb = colorize(values, lo, hi)
        mesh = trimesh.Trimesh(frame["positions"], self.faces, process=False,
                               vertex_colors=np.c_[rgb, np.full(len(rgb), 255, np.uint8)])
        self.surface = self.server.scene.add_mesh_trimesh("/sheet/surface", mesh)
        label, unit = FIELDS.get(key, (key, ""))
        self.gui.legend.content = legend_html(label, unit, lo, hi)

    def _aim(self, positions: np.ndarray) -> None:
        lo, hi = positions.min(0), positions.max(0)
        centre, size = (lo + hi) / 2, float(np.linalg.norm(hi - lo)) or 1.0
        eye = centre + size * np.array([0.1, -0.9, 0.6])
        cam = self.server.initial_camera
        cam.look_at, cam.position, cam.up = tuple(centre), tuple(eye), (0.0, 0.0, 1.0)
        for client in self.server.get_clients().values():
            # a client camera's position setter drags look_at along with it: place the eye
            # first, then aim (the other order leaves the sheet out of view)
            try:
                client.camera.up_direction = (0.0, 0.0, 1.0)
                client.camera.position = tuple(eye)
                client.camera.look_at = tuple(centre)
            except AssertionError:
                pass  # its camera state has not arrived yet; initial_camera places it

    def stop(self) -> None:
        self.server.stop()

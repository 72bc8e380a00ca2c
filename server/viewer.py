"""The viser viewer: the selected run's sheet coloured by a field on a fixed scale, a legend that
stays in view, the tools (translucent, or cut by a section plane), a scene's preview, and the
page's run controls mirrored.

It never sees the solver: the bridge hands it frames (dicts of arrays), the run manager tells it
which run is selected (or which scene to preview), and it calls back into the run manager
through ``Actions``. Positions stream to a wireframe every push (about 0.1 ms at 40k vertices);
the coloured surface is a glTF re-sent at most ``colour_hz`` times a second (about 10 ms and
1.5 MB at 40k vertices), always on the last frame of a run. Each tool is one single-colour mesh
sent once per run; frames only move it (``.position``).

Colours (server.palette, server.colormap): every field has a named scale that gives a value the
same colour in every frame: continuous fields over the run's own range (the range of every
frame of it shown so far, fixed once the run is over) or a range the user fixed, kept across
runs; thinning in bands at user-set limits; the FLD zones in one colour each. The legend and the
"Colour by" choice sit in a small panel of their own, floated over the bottom-left corner of the
view, and the control panel is docked to the right: neither hides the part, and the legend is
in view whatever is folded.

It shows the run selected on the server (``RunManager.select``: the page's Runs table, its own
"Run" dropdown, a new run), the same one the page shows. The latest run is shown live: frames as
the bridge pushes them, and the time slider follows the live step; when the run is paused or
over, moving it shows a kept frame (``RunManager.history``). An older run is shown from its
recording (``run.rrd``, read with ``server.replay`` in the background): the slider scrubs its
recorded frames. A scene chosen on the page is previewed (``show_preview``): its blank and tools
at the start, built by the solver process before any run. The buttons and the live-parameter
sliders act on the selected run, with the page's words (Pause, Resume, Step, Stop); they are
disabled while it is not active. Nothing here starts a run: that is the page's Start.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Collection, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import trimesh
import viser

from server.colormap import TOOL_OPACITY, grow, tool_colour
from server.palette import DEFAULT_FIELD, FIELDS, Palette, field_label, field_options
from server.replay import Replay
from server.section import AXES, Section


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
    colour: dict  # "range", "min", "max", "marginal", "failure": the colour settings
    view: dict  # "opacity", "section", "at": tools and the section plane


# the page's run controls and what each sends, in the page's order and words
COMMANDS = {"Pause": "pause", "Resume": "resume", "Step": "step", "Stop": "stop"}
NO_RUN = "(no runs yet)"  # the "Run" dropdown's one option before any run (viser needs one)
RUN_RANGE, FIXED_RANGE = "this run's", "fixed"
NO_SECTION = "off"
SECTIONS = {NO_SECTION: None, "x plane (keep x ≥ at)": "x", "y plane (keep y ≥ at)": "y"}
# px: the legend panel, floated over the view's bottom-left corner. Its height is fixed, to
# hold the tallest legend (the five FLD zones): a floating panel is placed by its height when
# placed, and a taller legend later would push it past the view's bottom edge
LEGEND_WIDTH, LEGEND_HEIGHT = 250, 232


class Viewer:
    def __init__(self, host: str, port: int, actions: Actions, colour_hz: float = 4.0):
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.actions = actions
        self.colour_period = 1.0 / colour_hz
        self.lock = threading.RLock()  # viser runs update callbacks in the assigning thread
        self.faces: np.ndarray | None = None
        self.surface = self.wire = None
        self.tools: dict[str, object] = {}  # tool name -> viser mesh handle
        self.tool_meshes: dict[str, tuple[np.ndarray, np.ndarray]] = {}  # name -> V, F (own frame)
        self.tool_poses: dict[str, tuple[np.ndarray, np.ndarray]] = {}  # name -> t, wxyz
        self.options = field_options(FIELDS)  # dropdown label -> field key
        self.palette = Palette()
        self.section = Section()
        self.last_colour = 0.0
        self.frame: dict | None = None  # the frame drawn (live, scrubbed, recorded, preview)
        self._code = threading.local()  # .on while this thread's GUI changes are the code's
        self.selected: str | None = None  # the run shown (the server's selection)
        self.active = False  # whether it is active (its own colour ranges still grow)
        self.parameters: dict[str, float] = {}  # its live parameters
        self.live_run: str | None = None  # the latest run, whose frames the bridge pushes
        self.live_faces: np.ndarray | None = None
        self.live_tools: list[dict] = []
        self.live_frame: dict | None = None  # the latest run's newest frame
        self.live_seen: dict[str, tuple[float, float]] = {}  # its fields' ranges so far
        # what is drawn: "live" (the latest run's frames), "replay" (a recording), "preview"
        # (a scene's rest state) or "none"
        self.mode = "none"
        self.replay: Replay | None = None  # a recorded run being shown
        self.previewed: str | None = None  # the scene previewed
        # the surface last sent: its field (None: recorded colours), RGB per vertex and faces
        self.painted: tuple[str | None, np.ndarray, np.ndarray] | None = None
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
        colour, view = self._colour_controls(), self._view_controls()
        field, legend = self._legend_panel()
        return Gui(status, field, legend, {}, time_slider, run, buttons, colour, view)

    def _legend_panel(self) -> tuple[viser.GuiDropdownHandle, viser.GuiHtmlHandle]:
        """The colour choice and the legend in a panel of their own, floated over the view's
        bottom-left corner: in view whatever the control panel shows or folds."""
        g = self.server.gui
        panel = g.add_panel()
        with panel.add_tab("Legend"):
            field = g.add_dropdown("Colour by", tuple(field_options(FIELDS)),
                                   initial_value=field_label(DEFAULT_FIELD))
            legend = g.add_html("")
        panel.float(x=12, y=-12, width=LEGEND_WIDTH, height=LEGEND_HEIGHT)
        field.on_update(self._by_user(self._field_chosen))
        return field, legend

    def _colour_controls(self) -> dict:
        g = self.server.gui
        with g.add_folder("Colour scale"):
            c = {"range": g.add_dropdown("Range", (RUN_RANGE, FIXED_RANGE),
                                         initial_value=RUN_RANGE,
                                         hint="the shown field's colour range: the run's own, "
                                              "or fixed (kept for every run: compare runs)"),
                 "min": g.add_number("Min", 0.0, disabled=True, hint="in the field's unit"),
                 "max": g.add_number("Max", 1.0, disabled=True, hint="in the field's unit"),
                 "marginal": g.add_number("Thinning marginal %",
                                          self.palette.thinning.bounds[1], step=0.5),
                 "failure": g.add_number("Thinning failure %",
                                         self.palette.thinning.bounds[2], step=0.5)}
        c["range"].on_update(self._by_user(self._range_chosen))
        for k in ("min", "max"):
            c[k].on_update(self._by_user(self._range_set))
        for k in ("marginal", "failure"):
            c[k].on_update(self._by_user(self._limits_set))
        return c

    def _view_controls(self) -> dict:
        g = self.server.gui
        with g.add_folder("View"):
            v = {"opacity": g.add_slider("Tool opacity", min=0.0, max=1.0, step=0.05,
                                         initial_value=TOOL_OPACITY, hint="0 hides the tools"),
                 "section": g.add_dropdown("Section", tuple(SECTIONS), initial_value=NO_SECTION,
                                           hint="cut the part and the tools by a plane"),
                 "at": g.add_slider("Section at (mm)", min=-1.0, max=1.0, step=0.1,
                                    initial_value=0.0, disabled=True)}
        v["opacity"].on_update(self._by_user(self._opacity_set))
        v["section"].on_update(self._by_user(self._section_set))
        v["at"].on_update(self._by_user(self._section_set))
        return v

    def add_parameters(self, parameters: dict[str, tuple[float, float]]) -> None:
        """One slider per live parameter, once the solver process has said which exist; each
        shows the selected run's value."""
        with self.lock, self.param_folder:
            active = not self.gui.buttons["Pause"].disabled
            for name, (lo, hi) in parameters.items():
                value = self.parameters.get(name, 1.0)  # no run shown: as written
                s = self.server.gui.add_slider(name, min=lo, max=hi, step=(hi - lo) / 1000,
                                               initial_value=min(max(value, lo), hi),
                                               disabled=not active)
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
            if run_id == self.selected and self.mode != "preview":
                self.gui.status.content = line
            if run_id == self.selected:
                was = self.active
                self._enable(active)
                if was and not active and self.mode == "live" and self.frame is not None:
                    self._send_surface(self.frame)  # the legend: the run's range, no more growing

    def new_run(self, run_id: str, faces: np.ndarray, tools: list[dict], line: str,
                parameters: dict[str, float]) -> None:
        """The latest run is built: its sheet's faces and its tools (meshes sent once), shown
        live when it is the selected run."""
        with self.lock:
            self.live_run = run_id
            self.live_faces = np.asarray(faces, np.uint32)
            self.live_tools = list(tools)
            self.live_frame = None
            self.live_seen = {}
            if run_id == self.selected:
                self._show_parameters(parameters)
                self._show_live(line)

    def show_preview(self, scene: str, faces: np.ndarray, tools: list[dict], frame: dict,
                     line: str) -> None:
        """A scene's rest state before any run: its blank (``frame``: the solver's frame of the
        built model at step 0) and its tools at their start positions."""
        with self.lock:
            self.mode, self.replay, self.previewed = "preview", None, scene
            self._set_scene(np.asarray(faces, np.uint32),
                            [(t["name"], t["vertices"], t["faces"]) for t in tools])
            self.palette.ranges.seen = {}
            self.palette.ranges.add(frame["fields"])
            with self._from_code():
                self.gui.time.value, self.gui.time.max = 0, 1
            self._draw(frame, colour=True)
            self.gui.status.content = line

    def preview_status(self, line: str) -> None:
        """Why a preview is not shown (yet): building, or its build failed."""
        with self.lock:
            self.gui.status.content = line

    def _clear(self, line: str) -> None:
        """Nothing drawn, the line shown (under lock)."""
        self.mode, self.replay, self.previewed, self.frame = "none", None, None, None
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
        self.tools, self.tool_meshes, self.tool_poses = {}, {}, {}
        opacity = float(self.gui.view["opacity"].value)
        for i, (name, V, F) in enumerate(tools):
            rgb, _ = tool_colour(i)
            V, F = np.asarray(V, np.float32), np.asarray(F, np.uint32)
            self.tool_meshes[name] = (V, F)
            self.tools[name] = self.server.scene.add_mesh_simple(
                f"/tools/{name}", V, F, color=rgb, opacity=opacity, side="double",
                cast_shadow=False, receive_shadow=False, visible=opacity > 0)

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
            self.palette.ranges.seen = {}
            for fields in rep.fields:  # a recorded run is over: its range is known at once
                self.palette.ranges.add(fields)
            with self._from_code():
                self.gui.time.max = max(1, rep.steps[-1])
                self.gui.time.value = rep.steps[-1]
            self._show_recorded(rep.steps[-1], f"{line}  \n{message}")
            self.mode = "replay"  # last: a reader outside the lock finds it all drawn

    def _show_live(self, line: str) -> None:
        """The latest run's sheet and tools, and its latest frame (under lock)."""
        self.mode, self.replay, self.previewed = "live", None, None
        self._set_scene(self.live_faces, [(t["name"], t["vertices"], t["faces"])
                                          for t in self.live_tools])
        self.palette.ranges.seen = self.live_seen
        self.frame = None
        with self._from_code():
            self.gui.time.value, self.gui.time.max = 0, 1
        if self.live_frame is not None:
            self.show(self.live_frame, line, final=True)
        else:
            self.gui.status.content = line

    def _show_recorded(self, step: int, message: str) -> None:
        """The recorded frame at ``step`` or the nearest before it (under lock)."""
        rep = self.replay
        i = max(int(np.searchsorted(rep.steps, step, side="right")) - 1, 0)
        with self.server.atomic():
            self._draw(rep.frame(i), colour=True)
            self.gui.status.content = f"{message}  \nshowing recorded step {rep.steps[i]}"

    def _set_fields(self, keys: Collection[str]) -> None:
        """Offer exactly the fields this frame carries; keep the choice when still offered."""
        options = field_options(keys)
        if not options or options == self.options:
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
            if self.mode != "live":
                return
        frame, message = self.actions.scrub(int(self.gui.time.value))
        if frame is None:
            self._status(message)
            live = self.live_frame
            if live is not None:
                self._set_time(live["step"])
            return
        self.show(frame, message, final=True, live=False)

    def _move_tools(self, frame: dict) -> None:
        rotations = frame.get("tool_rotations") or {}
        for name, pose in (frame.get("tools") or {}).items():
            h = self.tools.get(name)
            if h is None:
                continue
            t = np.asarray(pose, np.float64)
            q = np.asarray(rotations.get(name, (1.0, 0.0, 0.0, 0.0)), np.float64)
            h.position = t
            if name in rotations:
                h.wxyz = q
            self.tool_poses[name] = (t, q)
        if self.section.axis is not None:
            self._cut_tools()

    def show(self, frame: dict, status: str, final: bool = False, live: bool = True) -> None:
        """Push one frame: positions always, colours when due or final. A live frame also moves
        the time slider; a scrubbed one (``live=False``) leaves it where the user put it."""
        with self.lock:
            if live and frame.get("run") != self.live_run:
                return  # a frame of an earlier run, pushed late
            if live:
                self.live_frame = frame
            self.live_seen_add(frame)
            if self.faces is None or self.mode != "live":
                return  # another run is shown: the live run is kept, not drawn
            now = time.perf_counter()
            with self.server.atomic():
                if live:
                    self._set_time(frame["step"])
                due = final or self.surface is None or now - self.last_colour >= \
                    self.colour_period
                self._draw(frame, colour=due)
                if due:
                    self.last_colour = now
                self.gui.status.content = status

    def live_seen_add(self, frame: dict) -> None:
        """The latest run's colour ranges hold every frame of it shown or kept for showing."""
        if frame.get("run") == self.live_run:
            grow(self.live_seen, frame["fields"])

    def _draw(self, frame: dict, colour: bool) -> None:
        """Draw ``frame``: its fields offered, tools placed, wireframe moved, and the coloured
        surface when ``colour`` (under lock)."""
        self.frame = frame
        self._set_fields(frame["fields"])
        self._move_tools(frame)
        if self.wire is None:
            self.wire = self.server.scene.add_mesh_simple(
                "/sheet/wire", frame["positions"], self._kept(frame["positions"]),
                wireframe=True, color=(60, 60, 60), opacity=0.25)
            self._aim(frame["positions"])
        else:
            self.wire.vertices = frame["positions"]
        if colour or self.surface is None:
            self._send_surface(frame)

    # ---- colours ------------------------------------------------------------------------------
    def _key(self) -> str:
        """The field chosen in "Colour by" (under lock)."""
        return self.options.get(self.gui.field.value, DEFAULT_FIELD)

    def _field_chosen(self) -> None:
        with self.lock:
            self._show_range_controls()
            self._recolour()

    def _show_range_controls(self) -> None:
        """The Range controls show the chosen field's setting; a banded or categorical field
        has no range (under lock)."""
        c, key = self.gui.colour, self._key()
        scale = self.palette.scale(key)
        ranged = hasattr(scale, "lo")
        fixed = key in self.palette.ranges.fixed
        with self._from_code():
            c["range"].disabled = not ranged
            c["range"].value = FIXED_RANGE if fixed else RUN_RANGE
            for k in ("min", "max"):
                c[k].disabled = not (ranged and fixed)
            if ranged:
                c["min"].value, c["max"].value = float(scale.lo), float(scale.hi)

    def _range_chosen(self) -> None:
        """Fixed: the range shown now is kept (for every run, until changed); the run's own:
        the fixed one is dropped."""
        with self.lock:
            key = self._key()
            if self.gui.colour["range"].value == FIXED_RANGE:
                scale = self.palette.scale(key)
                self.palette.ranges.fix(key, scale.lo, scale.hi)
            else:
                self.palette.ranges.release(key)
            self._show_range_controls()
            self._recolour()

    def _range_set(self) -> None:
        with self.lock:
            c = self.gui.colour
            try:
                self.palette.ranges.fix(self._key(), float(c["min"].value), float(c["max"].value))
            except ValueError as exc:
                self.gui.status.content = str(exc)
                return
            self._recolour()

    def _limits_set(self) -> None:
        with self.lock:
            c = self.gui.colour
            try:
                self.palette.set_thinning(float(c["marginal"].value), float(c["failure"].value))
            except ValueError as exc:
                self.gui.status.content = str(exc)
                return
            self._recolour()

    def _recolour(self) -> None:
        """The frame drawn, coloured again (under lock)."""
        if self.frame is not None and self.faces is not None and self.mode != "none":
            self._send_surface(self.frame)

    def _send_surface(self, frame: dict) -> None:
        key = self._key()
        fields = frame["fields"]
        if fields and key not in fields:
            key = next(iter(fields))
        positions = frame["positions"]
        faces = self._kept(positions)
        if self.surface is not None:
            self.surface.remove()
            self.surface = None
        if fields:
            scale = self.palette.scale(key, growing=self.mode == "live" and self.active)
            rgb, legend = scale.colours(fields[key]), scale.legend()
        else:  # a recording made before it held the fields: its colours, as recorded
            rgb = frame["colours"]
            legend = ("<div class='q3t-legend'><b>Thickness</b>, colours as recorded (each "
                      "frame's min to max)</div>")
        self.painted = (key if fields else None, rgb, faces)
        if len(faces):
            mesh = trimesh.Trimesh(positions, faces, process=False,
                                   vertex_colors=np.c_[rgb, np.full(len(rgb), 255, np.uint8)])
            self.surface = self.server.scene.add_mesh_trimesh("/sheet/surface", mesh)
        if self.wire is not None and self.section.axis is not None:
            self.wire.faces = faces if len(faces) else self.faces[:1]
        if self.gui.legend.content != legend:
            self.gui.legend.content = legend

    # ---- tools and the section plane ----------------------------------------------------------
    def _opacity_set(self) -> None:
        with self.lock:
            alpha = float(self.gui.view["opacity"].value)
            for h in self.tools.values():
                h.opacity = alpha
            self._cut_tools()

    def _section_set(self) -> None:
        with self.lock:
            v = self.gui.view
            axis = SECTIONS.get(v["section"].value)
            self.section = Section(AXES[axis] if axis else None, float(v["at"].value) / 1e3)
            v["at"].disabled = axis is None
            if self.wire is not None and axis is None:
                self.wire.faces = self.faces
            self._cut_tools()
            self._recolour()

    def _kept(self, positions: np.ndarray) -> np.ndarray:
        return self.section.faces(positions, self.faces)

    def _cut_tools(self) -> None:
        """Each tool's triangles left by the section, at its current pose; a tool shows while
        its opacity is above 0 and some of it is left (under lock)."""
        alpha = float(self.gui.view["opacity"].value)
        for name, h in self.tools.items():
            V, F = self.tool_meshes[name]
            t, q = self.tool_poses.get(name, (np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0])))
            kept = self.section.tool_faces(V, F, t, q)
            if len(kept) and (len(kept) != len(h.faces) or not np.array_equal(kept, h.faces)):
                h.faces = kept
            h.visible = alpha > 0 and len(kept) > 0

    def _aim(self, positions: np.ndarray) -> None:
        lo, hi = positions.min(0), positions.max(0)
        centre, size = (lo + hi) / 2, float(np.linalg.norm(hi - lo)) or 1.0
        eye = centre + size * np.array([0.1, -0.9, 0.6])
        cam = self.server.initial_camera
        cam.look_at, cam.position, cam.up = tuple(centre), tuple(eye), (0.0, 0.0, 1.0)
        self._section_range(lo, hi)
        for client in self.server.get_clients().values():
            # a client camera's position setter drags look_at along with it: place the eye
            # first, then aim (the other order leaves the sheet out of view)
            try:
                client.camera.up_direction = (0.0, 0.0, 1.0)
                client.camera.position = tuple(eye)
                client.camera.look_at = tuple(centre)
            except AssertionError:
                pass  # its camera state has not arrived yet; initial_camera places it

    def _section_range(self, lo: np.ndarray, hi: np.ndarray) -> None:
        """The section slider spans the part (mm), across both axes it may cut."""
        a, b = 1e3 * float(min(lo[:2])), 1e3 * float(max(hi[:2]))
        at = self.gui.view["at"]
        with self._from_code():
            at.min, at.max = round(a, 1), round(b, 1)
            at.step = max(round((b - a) / 200, 2), 0.01)
            at.value = min(max(float(at.value), at.min), at.max)

    def stop(self) -> None:
        self.server.stop()

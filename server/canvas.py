"""What the viewer draws, and the controls of how: the sheet coloured by a field on its scale
(server.palette, server.colormap: a value keeps its colour in every frame, and across runs
with a fixed range), its wireframe, the tools (translucent, at the opacity the user sets), the
section plane that cuts both (server.section), and the legend.

Positions stream to the wireframe every push; the coloured surface is a glTF re-sent when the
viewer says so (``draw(frame, colour=True)``) and whenever the colours change. Each tool is one
single-colour mesh sent once per run; frames only move it (``.position``, ``.wxyz``). The
legend and the "Colour by" choice sit in a small panel of their own, floated over the
bottom-left corner of the view: the control panel (docked to the right by the viewer) never
hides it, folded or not. Every method is called under the viewer's lock (its controls take it
themselves).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Collection
from contextlib import AbstractContextManager

import numpy as np
import trimesh
import viser

from server.colormap import FAILURE_PCT, MARGINAL_PCT, MARGINAL_SHARE, TOOL_OPACITY, tool_colour
from server.palette import DEFAULT_FIELD, FIELDS, Palette, Scale, field_label, field_options
from server.section import AXES, Section

RUN_RANGE, FIXED_RANGE = "this run's", "fixed"
NO_SECTION = "off"
SECTIONS = {NO_SECTION: None, "x plane (keep x ≥ at)": "x", "y plane (keep y ≥ at)": "y"}


def _matte(tree: dict) -> None:
    # A primitive without a material gets three.js's glTF default, a fully metallic one: lit by
    # reflections alone, which the view has none of (no image-based light), it drew every
    # face not mirroring a light black (a drawn cup's whole wall). A matte, two-sided material
    # shows the colour map on both skins, shaded by the lights.
    tree["materials"] = [{"pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0],
                                                   "metallicFactor": 0.0,
                                                   "roughnessFactor": 0.8},
                          "doubleSided": True}]
    for mesh in tree.get("meshes", []):
        for primitive in mesh["primitives"]:
            primitive["material"] = 0


def surface_glb(positions: np.ndarray, faces: np.ndarray, rgb: np.ndarray) -> bytes:
    """The sheet's surface as a GLB: vertex colours ``rgb (n, 3) uint8``, smooth normals, a
    matte two-sided material."""
    mesh = trimesh.Trimesh(positions, faces, process=False,
                           vertex_colors=np.c_[rgb, np.full(len(rgb), 255, np.uint8)])
    return trimesh.exchange.gltf.export_glb(trimesh.Scene(mesh), include_normals=True,
                                            tree_postprocessor=_matte)


def typing_step(lo: float, hi: float) -> tuple[float, int]:
    """The step and decimals of a colour range's Min and Max boxes for a range lo..hi: a
    thousandth of its span's decade, so its ends show and can be typed to three digits of the
    span (viser rounds what a box shows and takes to its step: thickness around 1 mm with a
    step of 1 read "1 / 1" and took 0.85 as 85)."""
    span = hi - lo
    if not (np.isfinite(span) and span > 0):
        span = max(abs(lo), abs(hi), 1.0) if np.isfinite(lo) and np.isfinite(hi) else 1.0
    # at most 12 decimals: a range fixed narrower than that is typed no finer
    decimals = min(12, max(0, 3 - int(np.floor(np.log10(span)))))
    return 10.0 ** -decimals, decimals


class Canvas:
    def __init__(self, client: viser.ClientHandle, initial_camera: object,
                 lock: threading.RLock,
                 status: Callable[[str], None],
                 by_user: Callable[[Callable[[], object]], Callable[[object], None]],
                 from_code: Callable[[], AbstractContextManager],
                 growing: Callable[[], bool]):
        """``client``: the browser drawn for (its own GUI, scene and camera);
        ``initial_camera``: the viser server's, where a browser's camera starts. ``status``
        shows a line (a refused setting says why); ``by_user(action)`` makes a
        control's callback that acts on a user's change only, and changes made inside
        ``from_code()`` are the code's (server.viewer.Viewer); ``growing()``: whether the run
        drawn still runs (its own colour ranges grow). Adds the "Colour scale" and
        "View" folders to the control panel, and the legend panel."""
        self.client, self.initial_camera, self.lock = client, initial_camera, lock
        self.status, self.by_user, self.from_code = status, by_user, from_code
        self.faces: np.ndarray | None = None
        self.surface = self.wire = None
        self.tools: dict[str, viser.MeshHandle] = {}  # tool name -> mesh handle
        self.tool_meshes: dict[str, tuple[np.ndarray, np.ndarray]] = {}  # V, F in its frame
        self.tool_poses: dict[str, tuple[np.ndarray, np.ndarray]] = {}  # translation, wxyz
        self.options = field_options(FIELDS)  # dropdown label -> field key
        self.palette = Palette()
        self.section = Section()
        self.growing = growing
        self.frame: dict | None = None  # the frame drawn
        # the surface last sent: its field (None: recorded colours), RGB per vertex and faces
        self.painted: tuple[str | None, np.ndarray, np.ndarray] | None = None
        self.scale: Scale | None = None  # its colour scale (None: recorded colours)
        self.limits_by_user = False  # the thinning limits set in this browser
        self.colour, self.view = self._colour_controls(), self._view_controls()
        self.field, self.legend = self._legend_panel()

    def clear(self) -> None:
        """Nothing drawn."""
        self.set_scene(None, [])
        self.frame = None
        self.legend.content = ""

    def _legend_panel(self) -> tuple[viser.GuiDropdownHandle, viser.GuiHtmlHandle]:
        """The colour choice and the legend in a panel of their own, docked below the control
        panel: beside the part, never over it. Floated over the view's corner it covered two
        thirds of a 360 px tall view (the page at 1280 x 720); the price is that folding the
        control panel folds the legend with it."""
        g = self.client.gui
        panel = g.add_panel()
        with panel.add_tab("Legend"):
            field = g.add_dropdown("Colour by", tuple(field_options(FIELDS)),
                                   initial_value=field_label(DEFAULT_FIELD))
            legend = g.add_html("")
        panel.dock_below(g.main_panel)  # the main panel is docked first (ClientView)
        field.on_update(self.by_user(self._field_chosen))
        return field, legend

    def _colour_controls(self) -> dict:
        g = self.client.gui
        step, _ = typing_step(0.0, 1.0)  # the run's range sets its own (_show_range_controls)
        with g.add_folder("Colour scale"):
            c = {"range": g.add_dropdown("Range", (RUN_RANGE, FIXED_RANGE),
                                         initial_value=RUN_RANGE,
                                         hint="the shown field's colour range: the run's own, "
                                              "or fixed (kept for every run: compare runs)"),
                 "min": g.add_number("Min", 0.0, disabled=True, hint="in the field's unit",
                                     step=step),
                 "max": g.add_number("Max", 1.0, disabled=True, hint="in the field's unit",
                                     step=step),
                 "marginal": g.add_number("Thinning marginal %",
                                          self.palette.thinning.bounds[1], step=0.5),
                 "failure": g.add_number("Thinning failure %",
                                         self.palette.thinning.bounds[2], step=0.5)}
        c["range"].on_update(self.by_user(self._range_chosen))
        for k in ("min", "max"):
            c[k].on_update(self.by_user(self._range_set))
        for k in ("marginal", "failure"):
            c[k].on_update(self.by_user(self._limits_set))
        return c

    def _view_controls(self) -> dict:
        g = self.client.gui
        with g.add_folder("View"):
            v = {"opacity": g.add_slider("Tool opacity", min=0.0, max=1.0, step=0.05,
                                         initial_value=TOOL_OPACITY, hint="0 hides the tools"),
                 "section": g.add_dropdown("Section", tuple(SECTIONS), initial_value=NO_SECTION,
                                           hint="cut the part and the tools by a plane"),
                 "at": g.add_slider("Section at (mm)", min=-1.0, max=1.0, step=0.1,
                                    initial_value=0.0, disabled=True)}
        v["opacity"].on_update(self.by_user(self._opacity_set))
        v["section"].on_update(self.by_user(self._section_set))
        v["at"].on_update(self.by_user(self._section_set))
        return v

    def set_scene(self, faces: np.ndarray | None, tools: list[tuple]) -> None:
        """Replace the sheet's faces (None: no sheet) and the tool meshes ``[(name, V, F)]``
        (under lock)."""
        for h in (self.surface, self.wire, *self.tools.values()):
            if h is not None:
                h.remove()
        self.surface = self.wire = None
        self.faces = faces
        self.tools, self.tool_meshes, self.tool_poses = {}, {}, {}
        opacity = float(self.view["opacity"].value)
        for i, (name, V, F) in enumerate(tools):
            rgb, _ = tool_colour(i)
            V, F = np.asarray(V, np.float32), np.asarray(F, np.uint32)
            self.tool_meshes[name] = (V, F)
            self.tools[name] = self.client.scene.add_mesh_simple(
                f"/tools/{name}", V, F, color=rgb, opacity=opacity, side="double",
                cast_shadow=False, receive_shadow=False, visible=opacity > 0)

    def _set_fields(self, keys: Collection[str]) -> None:
        """Offer exactly the fields this frame carries; keep the choice when still offered."""
        options = field_options(keys)
        if not options or options == self.options:
            return
        current = self.options.get(self.field.value, DEFAULT_FIELD)
        self.options = options
        keep = next((lab for lab, k in options.items() if k == current),
                    next((lab for lab, k in options.items() if k == DEFAULT_FIELD),
                         next(iter(options))))
        with self.from_code():
            self.field.options = tuple(options)
            self.field.value = keep

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

    def draw(self, frame: dict, colour: bool) -> None:
        """Draw ``frame``: its fields offered, tools placed, wireframe moved, and the coloured
        surface when ``colour`` (under lock)."""
        self.frame = frame
        self._set_fields(frame["fields"])
        self._move_tools(frame)
        if self.wire is None:
            self.wire = self.client.scene.add_mesh_simple(
                "/sheet/wire", frame["positions"], self.faces, wireframe=True,
                color=(60, 60, 60), opacity=0.25)
            self.aim(frame["positions"])
        else:
            self.wire.vertices = frame["positions"]
        if colour or self.surface is None:
            self._send_surface(frame)

    def _key(self) -> str:
        """The field chosen in "Colour by" (under lock)."""
        return self.options.get(self.field.value, DEFAULT_FIELD)

    def _field_chosen(self) -> None:
        with self.lock:
            self._show_range_controls()
            self.recolour()

    def _show_range_controls(self) -> None:
        """The Range controls show the chosen field's setting; a banded or categorical field
        has no range (under lock)."""
        c, key = self.colour, self._key()
        scale = self.palette.scale(key)
        ranged = hasattr(scale, "lo")
        fixed = key in self.palette.ranges.fixed
        shown = [(c["range"], "disabled", not ranged),
                 (c["range"], "value", FIXED_RANGE if fixed else RUN_RANGE),
                 (c["min"], "disabled", not (ranged and fixed)),
                 (c["max"], "disabled", not (ranged and fixed))]
        if ranged:
            step, decimals = typing_step(float(scale.lo), float(scale.hi))
            for end, value in (("min", scale.lo), ("max", scale.hi)):
                # to the digits shown, and + 0.0: round-off below zero read "-0.00"
                shown += [(c[end], "step", step), (c[end], "precision", decimals),
                          (c[end], "value", round(float(value), decimals) + 0.0)]
        with self.from_code():
            for handle, prop, value in shown:
                if getattr(handle, prop) != value:  # each change is a message to every client
                    setattr(handle, prop, value)

    def _range_chosen(self) -> None:
        """Fixed: the range shown now is kept (for every run, until changed); the run's own:
        the fixed one is dropped."""
        with self.lock:
            key = self._key()
            if self.colour["range"].value == FIXED_RANGE:
                scale = self.palette.scale(key)
                self.palette.ranges.fix(key, scale.lo, scale.hi)
            else:
                self.palette.ranges.release(key)
            self._show_range_controls()
            self.recolour()

    def _range_set(self) -> None:
        with self.lock:
            c = self.colour
            try:
                self.palette.ranges.fix(self._key(), float(c["min"].value), float(c["max"].value))
            except ValueError as exc:  # both values are read: the other one may follow
                self.status(f"{exc}; the colours keep the last valid ones")
                return
            self.recolour()

    def card_thinning(self, limit: float | None) -> None:
        """The thinning bands of a run whose material card has a thinning limit (%): failure
        from it, marginal from MARGINAL_SHARE of it; without one the rule of thumb.
        Limits the user set in this browser stay: theirs to compare runs by."""
        if self.limits_by_user:
            return
        marginal, failure = ((MARGINAL_SHARE * limit, limit) if limit is not None
                             else (MARGINAL_PCT, FAILURE_PCT))
        self.palette.set_thinning(marginal, failure)
        with self.from_code():
            self.colour["marginal"].value, self.colour["failure"].value = marginal, failure

    def _limits_set(self) -> None:
        with self.lock:
            self.limits_by_user = True
            c = self.colour
            try:
                self.palette.set_thinning(float(c["marginal"].value), float(c["failure"].value))
            except ValueError as exc:  # both values are read: the other one may follow
                self.status(f"{exc}; the colours keep the last valid ones")
                return
            self.recolour()

    def recolour(self) -> None:
        """The frame drawn, coloured again (under lock)."""
        if self.frame is not None and self.faces is not None:
            self._send_surface(self.frame)

    def _send_surface(self, frame: dict) -> None:
        key = self._key()
        fields = frame["fields"]
        if fields and key not in fields:
            key = next(iter(fields))
        positions = frame["positions"]
        faces = self._kept(positions)
        if fields:
            scale = self.palette.scale(key, growing=self.growing())
            rgb, legend = scale.colours(fields[key]), scale.legend()
        else:  # a recording made before it held the fields: its colours, as recorded
            rgb = frame["colours"]
            legend = ("<div class='q3t-legend'><b>Thickness</b>, colours as recorded (each "
                      "frame's min to max)</div>")
        self.painted = (key if fields else None, rgb, faces)
        self.scale = scale if fields else None  # the legend's, for a PNG of the view
        if len(faces):  # the same name: the new surface replaces the old
            self.surface = self.client.scene.add_glb("/sheet/surface",
                                                     surface_glb(positions, faces, rgb))
        elif self.surface is not None:  # the section left nothing of the sheet
            self.surface.remove()
            self.surface = None
        self._cut_wire(faces)
        if self.legend.content != legend:
            self.legend.content = legend
        if fields:
            self._show_range_controls()  # a run's own range grows with it

    def _cut_wire(self, faces: np.ndarray) -> None:
        """The wireframe over the triangles the section left (hidden when none are)."""
        if self.wire is None:
            return
        if len(faces) and (len(faces) != len(self.wire.faces)
                           or not np.array_equal(faces, self.wire.faces)):
            self.wire.faces = faces
        self.wire.visible = len(faces) > 0

    def _opacity_set(self) -> None:
        with self.lock:
            alpha = float(self.view["opacity"].value)
            for h in self.tools.values():
                h.opacity = alpha
            self._cut_tools()

    def _section_set(self) -> None:
        with self.lock:
            v = self.view
            axis = SECTIONS.get(v["section"].value)
            self.section = Section(AXES[axis] if axis else None, float(v["at"].value) / 1e3)
            v["at"].disabled = axis is None
            self._cut_tools()
            self.recolour()

    def _kept(self, positions: np.ndarray) -> np.ndarray:
        return self.section.faces(positions, self.faces)

    def _cut_tools(self) -> None:
        """Each tool's triangles left by the section, at its current pose; a tool shows while
        its opacity is above 0 and some of it is left (under lock)."""
        alpha = float(self.view["opacity"].value)
        for name, h in self.tools.items():
            V, F = self.tool_meshes[name]
            t, q = self.tool_poses.get(name, (np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0])))
            kept = self.section.tool_faces(V, F, t, q)
            if len(kept) and (len(kept) != len(h.faces) or not np.array_equal(kept, h.faces)):
                h.faces = kept
            h.visible = alpha > 0 and len(kept) > 0

    def aim(self, positions: np.ndarray) -> None:
        lo, hi = positions.min(0), positions.max(0)
        centre, size = (lo + hi) / 2, float(np.linalg.norm(hi - lo)) or 1.0
        eye = centre + size * np.array([0.1, -0.9, 0.6])
        cam = self.initial_camera
        cam.look_at, cam.position, cam.up = tuple(centre), tuple(eye), (0.0, 0.0, 1.0)
        self._section_range(lo, hi)
        # a client camera's position setter drags look_at along with it: place the eye
        # first, then aim (the other order leaves the sheet out of view)
        try:
            self.client.camera.up_direction = (0.0, 0.0, 1.0)
            self.client.camera.position = tuple(eye)
            self.client.camera.look_at = tuple(centre)
        except AssertionError:
            pass  # its camera state has not arrived yet; initial_camera places it

    def _section_range(self, lo: np.ndarray, hi: np.ndarray) -> None:
        """The section slider spans the part (mm), across both axes it may cut."""
        a, b = 1e3 * float(min(lo[:2])), 1e3 * float(max(hi[:2]))
        at = self.view["at"]
        with self.from_code():
            at.min, at.max = round(a, 1), round(b, 1)
            at.step = max(round((b - a) / 200, 2), 0.01)
            at.value = min(max(float(at.value), at.min), at.max)
        self.section = Section(self.section.axis, float(at.value) / 1e3)

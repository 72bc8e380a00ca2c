"""``q3t play RUN --viser``: a recorded run (``run.rrd``) in a viser viewer with a time slider.

The recording is read back with ``rerun.chunk.RrdReader``: the sheet (``/sheet``: its triangles
static, then per keyframe its positions, the values of its fields and the thickness colours they
were recorded with),
the tool meshes (``/tools/<name>``, static) and their poses (``Transform3D`` per step: the
translation, and the rotation of a tool whose keyframes turn it).
The same loader feeds the service's viewer when it replays an older run, and colours the fields
on its scales; a recording made before the fields were recorded has its colours only.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from server.colormap import tool_colour

if TYPE_CHECKING:  # rerun's arrow tables: imported when a recording is read
    import pyarrow as pa
    import viser
    from pyarrow import RecordBatch


FIELD_PREFIX = "field:"  # the sheet's per-vertex field columns (server.recording writes them)


@dataclass
class Replay:
    steps: list[int] = field(default_factory=list)
    positions: list[np.ndarray] = field(default_factory=list)  # per step (n, 3) float32
    colors: list[np.ndarray] = field(default_factory=list)  # per step (n, 3) uint8
    fields: list[dict[str, np.ndarray]] = field(default_factory=list)  # per step name -> (n,)
    faces: np.ndarray | None = None
    tools: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)  # V, F
    poses: dict[str, dict[int, np.ndarray]] = field(default_factory=dict)  # tool -> step -> t
    # tool -> step -> unit quaternion (w, x, y, z), for tools the recording turns
    rotations: dict[str, dict[int, np.ndarray]] = field(default_factory=dict)
    # %, the run's material card's thinning limit: its record's (server.records.Run), not the
    # recording's, set by whoever replays it from the run
    thinning_limit: float | None = None
    # each field's (lo, hi) over every step of the run, which the recording keeps only some of:
    # its record's (server.records.Run.field_ranges), set by whoever replays it from the run
    ranges: dict[str, tuple[float, float]] = field(default_factory=dict)

    def frame(self, i: int) -> dict:
        """The ``i``-th recorded frame as the viewer draws it (a live frame's keys); a
        recording without field values brings its ``colours``."""
        k = self.steps[i]
        return {"step": k, "positions": self.positions[i], "fields": self.fields[i],
                "colours": self.colors[i],
                "tools": {name: self.pose(name, k) for name in self.tools},
                "tool_rotations": {name: self.rotation(name, k) for name in self.tools}}

    def pose(self, tool: str, step: int) -> np.ndarray:
        """The tool's translation at ``step``: the latest recorded at or before it."""
        return _latest(self.poses.get(tool), step, np.zeros(3))

    def rotation(self, tool: str, step: int) -> np.ndarray:
        """The tool's rotation (w, x, y, z) at ``step``: the latest recorded, else none."""
        return _latest(self.rotations.get(tool), step, np.array([1.0, 0.0, 0.0, 0.0]))


def _latest(known: dict | None, step: int, default: np.ndarray) -> np.ndarray:
    """The value recorded at the latest step at or before ``step`` (the first one before the
    first record)."""
    if not known:
        return default
    before = [s for s in known if s <= step]
    return known[max(before)] if before else known[min(known)]


def _vec3(cell: pa.Scalar) -> np.ndarray:
    """One row of a list<fixed_size_list<float, 3>> column -> (n, 3)."""
    return np.asarray(cell.values.flatten().to_numpy(zero_copy_only=False)).reshape(-1, 3)


def _rgb(cell: pa.Scalar) -> np.ndarray:
    """One row of packed RGBA uint32 colours (0xRRGGBBAA) -> (n, 3) uint8."""
    c = np.asarray(cell.values.to_numpy(zero_copy_only=False), np.uint32)
    return np.stack([(c >> 24) & 255, (c >> 16) & 255, (c >> 8) & 255], axis=1).astype(np.uint8)


def load(path: Path) -> Replay:
    """The sheet's keyframes, the tools' meshes and poses of the recording at ``path``."""
    from rerun.chunk import RrdReader

    rep, sheet = Replay(), {}
    for chunk in RrdReader(str(path)).stream():
        entity = str(chunk.entity_path)
        rb = chunk.to_record_batch()
        cols = set(rb.schema.names)
        steps = rb.column("step").to_pylist() if "step" in cols else [None] * rb.num_rows
        if entity == "/sheet":
            _read_sheet(rep, sheet, rb, cols, steps)
        elif entity.startswith("/tools/"):
            _read_tool(rep, entity.removeprefix("/tools/"), rb, cols, steps)
    for step in sorted(sheet):
        rep.steps.append(step)
        rep.positions.append(sheet[step][0])
        rep.colors.append(sheet[step][1])
        rep.fields.append(sheet[step][2])
    return rep


def _read_sheet(rep: Replay, sheet: dict, rb: RecordBatch, cols: set, steps: list) -> None:
    """The triangles are static (logged once) and go to ``rep``; positions, colours and field
    values come per keyframe and go to ``sheet`` (step -> (positions, colours, fields))."""
    if "Mesh3D:triangle_indices" in cols and rep.faces is None:
        tri = rb.column("Mesh3D:triangle_indices")
        rep.faces = next((_vec3(tri[i]).astype(np.uint32) for i in range(rb.num_rows)
                          if tri[i].is_valid), None)
    if "Mesh3D:vertex_positions" not in cols:
        return
    pos = rb.column("Mesh3D:vertex_positions")
    col = rb.column("Mesh3D:vertex_colors") if "Mesh3D:vertex_colors" in cols else None
    named = {c.removeprefix(FIELD_PREFIX): rb.column(c) for c in cols
             if c.startswith(FIELD_PREFIX)}
    for i, step in enumerate(steps):
        if step is None or not pos[i].is_valid:
            continue
        p = _vec3(pos[i]).astype(np.float32)
        c = _rgb(col[i]) if col is not None and col[i].is_valid \
            else np.full((len(p), 3), 180, np.uint8)
        values = {k: np.asarray(v[i].values.to_numpy(zero_copy_only=False), np.float32)
                  for k, v in named.items() if v[i].is_valid}
        sheet[int(step)] = (p, c, values)


def _read_tool(rep: Replay, name: str, rb: RecordBatch, cols: set, steps: list) -> None:
    """A tool's mesh (static) and its translations and rotations per step."""
    if "Mesh3D:vertex_positions" in cols:
        rep.tools[name] = (_vec3(rb.column("Mesh3D:vertex_positions")[0]),
                           _vec3(rb.column("Mesh3D:triangle_indices")[0]).astype(np.uint32))
    if "Transform3D:translation" in cols:
        tr = rb.column("Transform3D:translation")
        for i, step in enumerate(steps):
            if step is not None:
                rep.poses.setdefault(name, {})[int(step)] = _vec3(tr[i])[0]
    if "Transform3D:quaternion" in cols:
        q = rb.column("Transform3D:quaternion")
        for i, step in enumerate(steps):
            if step is not None and q[i].is_valid:  # rerun stores (x, y, z, w)
                xyzw = np.asarray(q[i].values.flatten().to_numpy(zero_copy_only=False),
                                  np.float64).reshape(-1, 4)[0]
                rep.rotations.setdefault(name, {})[int(step)] = np.roll(xyzw, 1)


def serve(rep: Replay, host: str = "127.0.0.1", port: int = 9090, title: str = "",
          block: bool = True) -> viser.ViserServer | None:
    """A viser viewer of ``rep``: sheet, tools, a step slider and Play/Pause. Returns the
    server when ``block`` is false (tests); otherwise runs until Ctrl-C."""
    import trimesh
    import viser

    from server import viserloop

    if not rep.steps or rep.faces is None:
        raise ValueError("the recording holds no sheet mesh")
    viserloop.install()
    server = viser.ViserServer(host=host, port=port, verbose=False)
    lock = threading.Lock()
    handles = _add_tools(server, rep)
    g = server.gui
    status = g.add_markdown(f"Recording `{title}`: {len(rep.steps)} frames, steps "
                            f"{rep.steps[0]}-{rep.steps[-1]} (sheet coloured by thickness)")
    colours = _thickness_colours(rep)
    slider = g.add_slider("Step", min=0, max=max(1, len(rep.steps) - 1), step=1,
                          initial_value=0, hint="index into the recorded frames")
    playing = g.add_checkbox("Play", initial_value=False)
    fps = g.add_slider("Frames/s", min=1, max=30, step=1, initial_value=8)

    def show(i: int) -> None:
        i = int(min(max(i, 0), len(rep.steps) - 1))
        step = rep.steps[i]
        rgba = np.c_[colours(i), np.full(len(rep.colors[i]), 255, np.uint8)]
        mesh = trimesh.Trimesh(rep.positions[i], rep.faces, vertex_colors=rgba, process=False)
        with lock, server.atomic():
            server.scene.add_mesh_trimesh("/sheet", mesh)
            for name, h in handles.items():
                h.position = np.asarray(rep.pose(name, step), np.float64)
                h.wxyz = rep.rotation(name, step)
            status.content = f"Recording `{title}`: step {step} ({i + 1}/{len(rep.steps)})"

    slider.on_update(lambda _e: show(slider.value))
    _aim(server, rep.positions[0])
    show(0)
    if not block:
        return server
    _play(server, slider, playing, fps, len(rep.steps))
    return None


def _thickness_colours(rep: Replay) -> Callable[[int], np.ndarray]:
    """The RGB of the ``i``-th frame's thickness on one scale for the whole recording, its
    range over every frame (server.palette), so a thickness looks the same at every step; a
    recording without field values gives the colours it was recorded with."""
    from server.palette import Palette

    palette = Palette()
    for fields in rep.fields:
        palette.ranges.add(fields)
    return lambda i: (palette.colours("thickness_mm", rep.fields[i]["thickness_mm"])
                      if "thickness_mm" in rep.fields[i] else rep.colors[i])


def _add_tools(server: viser.ViserServer, rep: Replay) -> dict:
    """One mesh per tool, in its own colour: tool name -> viser handle."""
    handles = {}
    for i, (name, (V, F)) in enumerate(rep.tools.items()):
        rgb, alpha = tool_colour(i)
        handles[name] = server.scene.add_mesh_simple(
            f"/tools/{name}", V.astype(np.float32), F, color=rgb, opacity=alpha, side="double",
            cast_shadow=False, receive_shadow=False)
    return handles


def _aim(server: viser.ViserServer, positions: np.ndarray) -> None:
    """Look at the sheet from the front, a little above it."""
    lo, hi = positions.min(0), positions.max(0)
    centre, size = (lo + hi) / 2, float(np.linalg.norm(hi - lo)) or 1.0
    cam = server.initial_camera
    cam.look_at, cam.up = tuple(centre), (0.0, 0.0, 1.0)
    cam.position = tuple(centre + size * np.array([0.1, -0.9, 0.6]))


def _play(server: viser.ViserServer, slider: viser.GuiSliderHandle,
          playing: viser.GuiCheckboxHandle, fps: viser.GuiSliderHandle, n: int) -> None:
    """Advance ``slider`` through the ``n`` frames at ``fps`` while ``playing`` is ticked,
    until Ctrl-C."""
    try:
        while True:
            time.sleep(1.0 / fps.value)
            if playing.value:
                slider.value = (slider.value + 1) % n
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()

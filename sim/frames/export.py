"""A run's results in the files other tools read, from its folder (result.json, final.npz, the
frames it saved, run.json): the probes as CSV, the final state and the saved frames as VTU with a
``.pvd`` time series (ParaView), the formed part as STL or PLY, the summary as JSON.

Exports are for engineers: lengths in mm, forces in kN, stresses in MPa, thinning in %,
strains as ratios (true strain), each labelled (CSV headers, VTU array names such as
``thickness_mm``); result.json and final.npz stay SI. Pure conversions: nothing here knows the
solver or the server."""

from __future__ import annotations

import csv
import io
import json
from dataclasses import dataclass
from pathlib import Path
from xml.etree import ElementTree

import numpy as np

from sim.frames import results, series
from sim.frames.display import DisplayMesh
from sim.frames.punch import punch_history
from sim.frames.units import DISPLAY

FORMATS = {"csv": "the probes per step (mm, kN: units in the header)",
           "vtu": "final state and frames, VTU + PVD (ParaView; units in the field names)",
           "stl": "the formed part (closed surface, mm)", "ply": "the formed part (closed "
           "surface, mm)", "json": "the run summary: each entry's value in SI units and its "
           "display value in the page's (mm, kN, MPa, %); field ranges in SI; FLD zone counts"}
STATE_FORMATS = ("vtu", "stl", "ply")  # need the final state (final.npz)
MM = 1e3
# final.npz's fields (sim.frames.fields.output_fields, SI) -> the exported name and its factor;
# ``*_elem`` (per element) likewise, as cell data
FIELDS = {"thickness": ("thickness_mm", MM), "thinning_pct": ("thinning_pct", 1.0),
          "von_mises": ("von_mises_MPa", 1e-6), "eq_plastic_strain": ("eq_plastic_strain", 1.0),
          "net_plastic_strain": ("net_plastic_strain", 1.0),
          "major_strain": ("major_strain", 1.0), "minor_strain": ("minor_strain", 1.0),
          "fld_zone": ("fld_zone", 1.0)}
ZONE = "fld_zone"  # a zone code (sim.frames.forming_limits.ZONES): an integer


class ExportError(ValueError):
    """Bad input: no run there, a format unknown, or a run without what the format needs."""


@dataclass
class State:
    """A state of the run in exported units: the skins' corner positions ``(2 n_v, 3)`` (mm, top
    skin first, as DisplayMesh), the mesh's at rest, and the fields per mid-surface vertex
    ``(n_v,)`` and per element ``(n_f,)``."""

    step: int
    time: float
    positions: np.ndarray
    rest: np.ndarray
    point: dict[str, np.ndarray]
    cell: dict[str, np.ndarray]


@dataclass
class RunFolder:
    path: Path
    result: dict
    status: dict  # run.json of a server run, {} otherwise

    @property
    def name(self) -> str:
        return self.path.name

    @property
    def final(self) -> Path:
        return self.path / "final.npz"


def open_run(path: Path) -> RunFolder:
    """The run in folder ``path``; ExportError naming what is missing."""
    if not path.is_dir():
        raise ExportError(f"{path}: no such run folder")
    try:
        result = json.loads((path / "result.json").read_text())
    except FileNotFoundError:
        raise ExportError(f"{path}: no result.json (not a run folder, or a run that has not "
                          "ended)") from None
    except (OSError, ValueError) as exc:
        raise ExportError(f"{path}/result.json: unreadable: {exc}") from None
    try:
        status = json.loads((path / "run.json").read_text())
    except (OSError, ValueError):
        status = {}
    return RunFolder(path, result, status)


def check_format(fmt: str) -> str:
    if fmt not in FORMATS:
        raise ExportError(f"format {fmt!r}: unknown; known: {', '.join(FORMATS)}")
    return fmt


def missing(run: RunFolder, fmt: str) -> str | None:
    """Why ``run`` cannot be exported as ``fmt``, or None when it can."""
    reason = (run.result.get("failure") or {}).get("reason")
    because = f" ({reason})" if reason else ""
    if fmt in STATE_FORMATS and not run.final.is_file():
        return (f"run {run.name!r} has no final state (final.npz): it ended before it had one"
                + because)
    if fmt == "csv" and not run.result.get("steps"):  # a header and no row is no table
        return f"run {run.name!r} has no steps: it ended before its first" + because
    return None


# ---- the probes: CSV ------------------------------------------------------------------------
def unit_of(unit: str | None) -> tuple[str, float]:
    """The shown unit and factor of an SI unit ("-" a count; "SI" when it is not known)."""
    if unit is None:
        return "SI", 1.0
    shown, factor = DISPLAY[unit]
    return shown or "-", factor


def probe_units(run: RunFolder) -> dict[str, str | None]:
    from sim.frames.probes import PROBES

    kinds = run.result.get("probe_kinds") or run.status.get("probe_kinds") or {}
    steps = run.result.get("steps") or []
    names = list(kinds) or (list(steps[-1]["probes"]) if steps else [])
    return {n: PROBES[kinds[n]].unit if kinds.get(n) in PROBES else None for n in names}


def columns(run: RunFolder) -> list[tuple[str, list]]:
    """The CSV's columns: ``(header with unit, value per step)``. A probe that says what a
    punch's column already says, under its name (the scenes' ``punch_force``, the punch's z
    force, beside "punch force", the force resisting its stroke: the same numbers when it
    moves along z), is left out: one quantity, one column."""
    steps = run.result.get("steps") or []
    # a static run's time is the pseudo-time that moves its tools and loads, 0 to 1 over the
    # run, not seconds (a run written before result.json said which kind says seconds)
    time = "pseudo-time [-]" if time_name(run) == "pseudo_time" else "time [s]"
    cols = [("step", [r["step"] for r in steps]), (time, [r["time"] for r in steps])]
    punches = run.result.get("punches") or run.status.get("punches") or {}
    for tool, start in punches.items():
        # a released punch reports nothing in the release stage: empty cells there
        rows = [(r["step"], r["tools"][tool]) for r in steps if tool in (r.get("tools") or {})]
        if not rows:
            continue
        h = punch_history(rows, np.asarray(start, float))
        at = {int(k): i for i, k in enumerate(h["steps"])}
        if h["stroke"] is not None:
            cols.append((f"{tool} stroke [mm]", _at_steps(steps, at, h["stroke"] * MM)))
        cols.append((f"{tool} force [kN]", _at_steps(steps, at, h["force"] * DISPLAY["N"][1])))
        if h["lateral"] is not None:  # side thrust: an axisymmetric draw's should be nil
            cols.append((f"{tool} lateral force [kN]", _at_steps(
                steps, at, np.linalg.norm(h["lateral"], axis=1) * DISPLAY["N"][1])))
    for name, unit in probe_units(run).items():
        shown, factor = unit_of(unit)
        values = [(r.get("probes") or {}).get(name) for r in steps]
        col = (f"{name} [{shown}]", [None if v is None else v * factor for v in values])
        if not any(_same(col, c) for c in cols):
            cols.append(col)
    return cols


def _same(a: tuple[str, list], b: tuple[str, list]) -> bool:
    """Whether two columns have one name (an underscore read as a space) and the same cells."""
    def cells(c: tuple[str, list]) -> list:
        return ["" if v is None else f"{v:.{DIGITS}g}" for v in c[1]]
    return a[0].replace("_", " ") == b[0].replace("_", " ") and cells(a) == cells(b)


def _at_steps(steps: list[dict], at: dict[int, int], values: np.ndarray) -> list:
    """``values`` (one per step in ``at``: step -> index) for each step, None where absent."""
    return [float(values[at[r["step"]]]) if r["step"] in at else None for r in steps]


# significant digits of a CSV value, a spreadsheet's: a holder's 5 kN read 5.00000000858 at
# twelve, the solver's residual in its last digits; six keep a micrometre in a metre and a
# newton in a meganewton. Every bit stays in result.json (and the JSON export)
DIGITS = 6


def probes_csv(run: RunFolder) -> str:
    """A row per step: step, time, each punch's stroke, force and lateral force (the size of
    its part perpendicular to the stroke), every probe; units in the header; ``DIGITS``
    significant digits. A value the run could not compute (not finite) is an
    empty cell."""
    cols = columns(run)
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow([h for h, _ in cols])
    for row in zip(*(v for _, v in cols), strict=True):
        w.writerow(["" if v is None else f"{v:.{DIGITS}g}" if isinstance(v, float) else v
                    for v in row])
    return out.getvalue()


# ---- the summary: JSON -----------------------------------------------------------------------
def summary_json(run: RunFolder) -> str:
    """What the run is and what it gave: scene, element, its end (converged, failure, stopped),
    its last step, counts, the summary entries (SI value and display value, as result.json), the
    min/mean/max of its result fields (SI) and its FLD zone counts."""
    r = run.result
    steps = r.get("steps") or []
    fl = r.get("forming_limits") or {}
    out = {"run": run.name, "scene": r.get("scene"), "element": r.get("element"),
           "converged": r.get("converged"), "failure": r.get("failure"),
           "stopped": r.get("stopped"), "step": steps[-1]["step"] if steps else 0,
           "counts": r.get("counts"), "summary": r.get("summary") or [],
           "fields": r.get("fields") or {},
           "forming_limits": {k: fl[k] for k in ("strain", "step", "zones", "zone_counts")
                              if k in fl} or None}
    return results.dumps(out, indent=1) + "\n"


# ---- states: final.npz and the saved frames ----------------------------------------------------
def _fields(data: dict) -> tuple[dict, dict]:
    """Per vertex and per element fields of ``data`` in exported names and units."""
    point, cell = {}, {}
    for key, v in data.items():
        base = key.removesuffix("_elem")
        if base not in FIELDS:
            continue
        name, factor = FIELDS[base]
        value = np.asarray(v).astype(np.int32) if base == ZONE else np.asarray(v, float) * factor
        (cell if key.endswith("_elem") else point)[name] = value
    return point, cell


def final_state(run: RunFolder) -> tuple[State, np.ndarray]:
    """The run's last state (final.npz) and the mid-surface faces ``(n_f, 3)``."""
    if why := missing(run, "vtu"):
        raise ExportError(why)
    with np.load(run.final) as z:
        data = dict(z)
    if "skins" not in data:
        raise ExportError(f"{run.final}: no skin nodes (written before exports existed): run "
                          "the scene again")
    steps = run.result.get("steps") or []
    skins = data["skins"].reshape(-1)
    point, cell = _fields(data)
    return State(steps[-1]["step"] if steps else 0, steps[-1]["time"] if steps else 0.0,
                 data["deformed"][skins] * MM, data["rest"][skins] * MM, point, cell), \
        data["faces"]


def frame_states(run: RunFolder) -> list[State]:
    """The frames the run saved (sim.frames.series), by step; [] when it saved none."""
    folder = run.path / series.FOLDER
    found = series.steps(folder)
    if not found:
        return []
    with np.load(folder / series.MESH) as z:
        rest = z["rest"].reshape(-1, 3).astype(float) * MM
    out = []
    for _, path in found:
        with np.load(path) as z:
            data = dict(z)
        point, cell = _fields(data)
        out.append(State(int(data["step"]), float(data["time"]),
                         data["positions"].reshape(-1, 3).astype(float) * MM, rest, point,
                         cell))
    return out


# ---- VTU + PVD ---------------------------------------------------------------------------------
def wedges(faces: np.ndarray, n_v: int) -> np.ndarray:
    """VTK wedges ``(n_f, 6)`` over the skin points (top ``v``, bottom ``n_v + v``), one per
    element: VTK's base triangle (0, 1, 2) has its right-hand normal pointing away from the
    other (3, 4, 5); a mid-surface face's normal points to the top skin, so the base is the
    top skin's triangle as the face has it, over the bottom's."""
    return np.concatenate([faces, faces + n_v], axis=1)


def vtu(state: State, faces: np.ndarray, path: Path, time: str = "time_s") -> None:
    """One state as an unstructured grid of wedges (the shell's volume): points in mm, the
    fields on both skins' points and per cell, displacement from the rest state (mm); step
    and time as field data, the time named ``time`` (:func:`time_name`)."""
    import meshio

    n_v = len(state.positions) // 2
    point = {k: np.concatenate([v, v]) for k, v in state.point.items()}
    point["displacement_mm"] = state.positions - state.rest
    mesh = meshio.Mesh(state.positions, [("wedge", wedges(faces, n_v))], point_data=point,
                       cell_data={k: [v] for k, v in state.cell.items()})
    tmp = path.with_name(f".{path.name}.meshio.tmp")
    try:
        meshio.write(tmp, mesh, file_format="vtu")
        text = tmp.read_bytes()
    finally:
        tmp.unlink(missing_ok=True)
    # meshio writes no field data to VTU: the step and time go in by hand (VTK's FieldData)
    grid = b"<UnstructuredGrid>"
    if grid not in text:
        raise RuntimeError("meshio's VTU has no <UnstructuredGrid>: its format changed")
    _bytes(path, text.replace(grid, grid + _field_data(step=state.step, **{time: state.time}), 1))


def _field_data(**values: float) -> bytes:
    arrays = "".join(
        f'<DataArray type="{"Int64" if isinstance(v, int) else "Float64"}" Name="{k}" '
        f'NumberOfTuples="1" format="ascii">{v!r}</DataArray>' for k, v in values.items())
    return f"<FieldData>{arrays}</FieldData>".encode()


def pvd(entries: list[tuple[int, str]]) -> str:
    """A ParaView collection of ``(step, file)``: its time is the step (a release stage's
    step has the same scene time as the last of the stroke; each file has its time:
    :func:`time_name`)."""
    root = ElementTree.Element("VTKFile", type="Collection", version="0.1")
    coll = ElementTree.SubElement(root, "Collection")
    for step, file in entries:
        ElementTree.SubElement(coll, "DataSet", timestep=str(step), part="0", file=file)
    ElementTree.indent(root)
    return '<?xml version="1.0"?>\n' + ElementTree.tostring(root, encoding="unicode") + "\n"


def time_name(run: RunFolder) -> str:
    """The VTU field data's name of a state's time: a static run's is the pseudo-time that
    moves its tools and loads, 0 to 1 (as the CSV's header says), a dynamic run's seconds."""
    return "pseudo_time" if run.result.get("stepping") == "static" else "time_s"


def write_vtu(run: RunFolder, out: Path) -> list[Path]:
    """``<run>_final.vtu``, the saved frames ``<run>_frames/step-NNNNNN.vtu`` and
    ``<run>.pvd`` (the frames in step order; the final state alone when none were saved)."""
    final, faces = final_state(run)
    stem, time = run.name, time_name(run)
    written = [out / f"{stem}_final.vtu"]
    vtu(final, faces, written[0], time)
    entries = []
    frames = frame_states(run)
    if frames:
        (out / f"{stem}_frames").mkdir(exist_ok=True)
    for s in frames:
        rel = f"{stem}_frames/step-{s.step:06d}.vtu"
        vtu(s, faces, out / rel, time)
        written.append(out / rel)
        entries.append((s.step, rel))
    written.append(out / f"{stem}.pvd")
    _text(written[-1], pvd(entries or [(final.step, written[0].name)]))
    return written


# ---- the formed part: STL / PLY --------------------------------------------------------------
def part(run: RunFolder) -> object:
    """The formed part: the closed surface of the deformed shell (top skin, bottom skin and
    rim, sim.frames.display), in mm, as a trimesh.Trimesh with outward normals."""
    import trimesh

    state, faces = final_state(run)
    n_v = len(state.positions) // 2
    d = DisplayMesh.from_skins(faces, np.arange(n_v), np.arange(n_v, 2 * n_v))
    return trimesh.Trimesh(state.positions, d.faces, process=False)


def write_part(run: RunFolder, fmt: str, out: Path) -> list[Path]:
    path = out / f"{run.name}.{fmt}"
    data = part(run).export(file_type=fmt)
    _bytes(path, data if isinstance(data, bytes) else data.encode())
    return [path]


# ---- one entry ---------------------------------------------------------------------------------
def export(path: Path, fmt: str, out: Path) -> list[Path]:
    """The run in folder ``path`` as ``fmt`` (FORMATS) into folder ``out``; the files written.
    ExportError (bad input) names the problem."""
    check_format(fmt)
    run = open_run(path)
    if why := missing(run, fmt):
        raise ExportError(why)
    if out.exists() and not out.is_dir():
        raise ExportError(f"{out}: not a folder to write into")
    out.mkdir(parents=True, exist_ok=True)
    if fmt == "vtu":
        return write_vtu(run, out)
    if fmt in ("stl", "ply"):
        return write_part(run, fmt, out)
    text = probes_csv(run) if fmt == "csv" else summary_json(run)
    target = out / f"{run.name}{'' if fmt == 'csv' else '_summary'}.{fmt}"
    _text(target, text)
    return [target]


def _bytes(path: Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_bytes(data)
    tmp.replace(path)


def _text(path: Path, text: str) -> None:
    _bytes(path, text.encode())

"""A run's split rings (sim.stepping.split_ring) on disk and in a forming engineer's units.

Each ring's summary (SI) is an entry of the run's result.json (``split_ring``: one per heights
and cut angle, sorted), its states are ``<ring>.npz`` beside it and, for ParaView,
``<ring>/ring_<state>.vtu`` (``<ring>``: :func:`name_of`). ``q3t splitring`` and the service
both write and read them here; the service hands them out (DOWNLOADS). Light on purpose, as
sim.frames.results: the server reads the rings without importing the solver.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np

from sim.frames import results
from sim.stepping.wall import WALL

KEY = "split_ring"  # result.json's list of rings
STATES = ("formed", "released", "split")  # a ring's states, in the order the test goes
# a ring's downloads, its files as saved (server.routers.split_ring): what each holds
DOWNLOADS = {"vtu": "the ring formed, released and split as VTU (mm; displacement from rest, "
                    "the formed equivalent plastic strain per element) with a PVD series for "
                    "ParaView, zipped",
             "npz": "the ring as saved (numpy, SI): its mesh (rest, conn, faces, skins), the "
                    "run's element of each of its elements, the vertices duplicated along the "
                    "cut (twins), its positions formed, released and split"}


# section points through the thickness a ring's opening needs at the least: the residual
# bending stress that opens it is an elastic-plastic profile, which three points (the
# elements' own rule) integrate too coarsely; on the split-ring cup (docs/split-ring.md) seven
# moved the openings by millimetres from three and were converged on the coarse blank, while
# a fine wall mesh, whose profile is sharper, needed eleven
SPRINGBACK_POINTS = 7
FINE_WALL_POINTS = 11


def caution(points: int | None) -> str | None:
    """What a forming engineer should know of a ring's opening integrated on ``points``
    section points (None: a ring saved before they were recorded), or None."""
    if points is None or points >= SPRINGBACK_POINTS:
        return None
    return (f"{points} section points through the thickness are too few for springback: the "
            "opening moves when more are taken; form the cup with shell.thickness_points = "
            f"{SPRINGBACK_POINTS} or more ({FINE_WALL_POINTS} on a fine mesh of the wall; "
            "docs/split-ring.md)")


def angle(deg: float) -> float:
    """A cut angle (deg) in [0, 360): the same meridian, the same ring (its name and its
    entry)."""
    a = deg % 360.0
    return 0.0 if a == 360.0 else a  # a tiny negative angle rounds up to 360


def name_of(s: dict) -> str:
    """A ring's name from its heights and, when not 0, its cut's angle: ``split_ring-8-13mm``,
    ``split_ring-8-13mm-45deg``."""
    cut = f"-{s['cut_angle']:g}deg" if s["cut_angle"] else ""
    return f"split_ring-{1e3 * s['heights'][0]:g}-{1e3 * s['heights'][1]:g}mm{cut}"


def of_run(folder: Path) -> list[dict]:
    """The rings cut from the run in ``folder`` (SI, as result.json holds them); none when it
    has no result."""
    path = folder / "result.json"
    return json.loads(path.read_text()).get(KEY, []) if path.is_file() else []


def npz_file(folder: Path, name: str) -> Path:
    """Where the ring ``name`` of the run in ``folder`` keeps its states."""
    return folder / f"{name}.npz"


def vtu_series(folder: Path, name: str, stem: str) -> dict[str, Path | str]:
    """The ring ``name``'s VTU files in the run folder ``folder`` and a PVD that steps
    through them formed, released, split (the step each holds), by their names in a download:
    ``<stem>/ring_<state>.vtu`` and ``<stem>.pvd``, as a run's VTU export names its own."""
    from sim.frames import export

    vtus = {f"{stem}/ring_{s}.vtu": folder / name / f"ring_{s}.vtu" for s in STATES}
    return {**vtus, f"{stem}.pvd": export.pvd(list(enumerate(vtus)))}


def wall(folder: Path) -> tuple[float, float] | None:
    """How far the steep wall of the part in ``folder``'s final.npz reaches: the lowest and
    highest centroid (m above the part's lowest point) of the elements steeper than WALL, or
    None without any. About: the mid-surface is taken halfway between the skins here (the
    ring itself is cut by the element's own mid-surface, sim.stepping.split_ring), enough to
    say where heights may go. The final state's positions, skins and faces are read, nothing
    is built."""
    with np.load(folder / "final.npz") as z:
        x, skins, faces = z["deformed"], z["skins"], z["faces"]
    mid = 0.5 * (x[skins[0]] + x[skins[1]])
    n = np.cross(mid[faces[:, 1]] - mid[faces[:, 0]], mid[faces[:, 2]] - mid[faces[:, 0]])
    steep = np.abs(n[:, 2]) < np.cos(np.radians(WALL)) * np.linalg.norm(n, axis=1)
    if not steep.any():
        return None
    h = mid[faces[steep]].mean(1)[:, 2] - mid[:, 2].min()
    return float(h.min()), float(h.max())


def save(folder: Path, res: object, ep: np.ndarray) -> None:
    """A ring (a sim.stepping.split_ring.Result) into the run in ``folder``: its states into
    ``<ring>.npz`` and, each as ``<ring>/ring_<state>.vtu`` (mm, the formed equivalent plastic
    strain ``ep`` per ring element), then its summary into result.json (the same heights and
    cut replaced). The summary is checked first (a number not finite: ValueError naming it),
    every file is written into a hidden staging folder, then each is moved into place by a
    rename and result.json is written last: a ring that cannot be saved leaves the run as it
    was (its staging folder removed), and a ring listed in result.json has its files (those of
    a ring cut again are replaced one by one, never missing)."""
    path = folder / "result.json"
    data = json.loads(path.read_text()) if path.is_file() else {}
    key = (res.summary["heights"], res.summary["cut_angle"])
    rings = [r for r in data.get(KEY, []) if (r["heights"], r["cut_angle"]) != key]
    data[KEY] = sorted([*rings, res.summary], key=lambda r: (r["heights"], r["cut_angle"]))
    results.dumps(data)  # a number not finite raises here, before anything is written
    name = name_of(res.summary)
    stage = folder / f".{name}.tmp"
    shutil.rmtree(stage, ignore_errors=True)  # left by a save that was killed
    try:
        stage.mkdir()
        _stage(stage, res, ep)
        (folder / name).mkdir(exist_ok=True)
        for f in sorted(stage.glob("*.vtu")):
            os.replace(f, folder / name / f.name)
        os.replace(stage / "ring.npz", npz_file(folder, name))
        results.write(path, data)
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def _stage(stage: Path, res: object, ep: np.ndarray) -> None:
    """A ring's files into the folder ``stage``: ring.npz and ring_<state>.vtu (as save)."""
    from sim.frames import export, series

    sh = res.ring.shell
    skins = series.skins(res.ring)
    series.save_npz(stage / "ring.npz", rest=sh.rest, conn=sh.conn, faces=sh.mesh.faces,
                    skins=skins, elements=res.ring.elements, twins=res.ring.twins, **res.states)
    rest = sh.rest[skins.ravel()] * export.MM
    for i, (state, x) in enumerate(res.states.items()):
        shown = export.State(i, 0.0, x[skins.ravel()] * export.MM, rest, {},
                             {"eq_plastic_strain": ep})
        export.vtu(shown, sh.mesh.faces, stage / f"ring_{state}.vtu")


def shown(s: dict) -> dict:
    """A ring's summary ``s`` (SI) in a forming engineer's units, each unit in its field's
    name: heights and lengths in mm, the cut in degrees, re-yield as a % of the ring's
    quadrature points (its largest growth a plastic strain, dimensionless)."""
    mm = lambda v: 1e3 * v  # noqa: E731
    o, d = s["opening"], s["diameters"]
    return {
        "name": name_of(s),
        # 4.5 mm, not the 4.500000000000001 of its round trip through m
        "heights_mm": [float(f"{mm(z):.12g}") for z in s["heights"]],
        "cut_angle_deg": s["cut_angle"],
        "section_points": s.get("section_points"),
        "caution": caution(s.get("section_points")),
        "elements": s["elements"], "duplicated_nodes": s["duplicated_nodes"],
        "opening_mm": {"at_mid_height": mm(o["at_mid_height"]), "min": mm(o["min"]),
                       "max": mm(o["max"]),
                       "distance_at_mid_height": mm(o["distance_at_mid_height"])},
        "diameters_mm": {state: {k: mm(d[state][k]) for k in ("mean", "d0", "d90")}
                         for state in STATES},
        "reyield_pct": {k: 100 * v["fraction"] for k, v in s["reyield"].items()},
        "reyield_max_plastic_strain": {k: v["max"] for k, v in s["reyield"].items()},
        "solver": {k: {"iterations": v["iterations"], "released_force_N": v["released_force"],
                       "support_reaction_N": v["support_reaction"]}
                   for k, v in s["solver"].items()},
    }

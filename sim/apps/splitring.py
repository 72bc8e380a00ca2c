"""``q3t splitring``: the split-ring (Demeri) springback test on formed cups
(sim.stepping.split_ring): a ring cut from each run's wall between two heights, released,
split along a meridian and released again; its opening and diameters.

Each ring's result goes into its run's result.json (``split_ring``, a list, SI) and its states
into ``split_ring-<z1>-<z2>mm.npz`` beside it (the ring's rest, formed, released and split
positions, its elements and the skins of its mid-surface vertices) and as VTU in the folder of
that name; the table of all runs and rings to stdout and, with ``--results``, to a stamped
file.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from sim.apps.common import BAD_INPUT, FAILED, OK
from sim.apps.study_report import markdown_table
from sim.frames import rings
from sim.stamp import Stamp, add_results_option, write_results

if TYPE_CHECKING:
    from sim.stepping.split_ring import Formed, Progress, Report

# a ring 5 mm high (Xia, Miller and Ren's rings, J. Manuf. Sci. Eng. 129 (2007) 352) from the
# middle of the 1 mm cup's straight wall: its punch radius ends 5.5 mm above the bottom, the
# die's shoulder begins 5 mm below the 30 mm stroke's rim (docs/split-ring.md)
HEIGHTS = "8,13"

COLS = [("run", "run", ""), ("element", "element", ""),
        ("section", "section points", "d"), ("material", "material", ""),
        ("edge", "edge [mm]", ""),
        ("band", "ring [mm above the bottom]", ""), ("cut", "cut [deg]", "g"),
        ("elements", "elements", "d"),
        ("opening", "opening [mm]", ".3f"), ("d_formed", "D formed [mm]", ".3f"),
        ("d_released", "D released [mm]", ".3f"), ("d_split", "D split [mm]", ".3f"),
        ("d0", "D split 0 deg [mm]", ".3f"), ("d90", "D split 90 deg [mm]", ".3f"),
        ("reyield", "re-yield: points, largest growth of the plastic strain", "")]


def parse_heights(text: str) -> tuple[float, float]:
    """``"z1,z2"`` in mm -> (z1, z2) in m; ValueError naming ``--heights``."""
    try:
        z1, z2 = (float(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"--heights: {text!r} is not two comma-separated heights in mm "
                         "(e.g. 8,13)") from None
    if not (math.isfinite(z1) and math.isfinite(z2)):
        raise ValueError(f"--heights: {text!r}: heights must be finite")
    return 1e-3 * z1, 1e-3 * z2


def row(folder: Path, formed: Formed, s: dict) -> dict:
    """One line of the table (mm) from a run's split-ring summary ``s`` (SI): ``formed`` its
    run's final state (sim.stepping.split_ring.open_formed)."""
    r = rings.shown(s)
    d = r["diameters_mm"]
    scene = formed.scene
    return {"run": folder.name, "element": scene.shell.element, "section": r["section_points"],
            "material": "Hill48" if scene.material.hill48 is not None else "von Mises",
            "edge": edges(scene.mesh),
            "band": "-".join(f"{z:g}" for z in r["heights_mm"]), "cut": r["cut_angle_deg"],
            "elements": r["elements"], "opening": r["opening_mm"]["at_mid_height"],
            "d_formed": d["formed"]["mean"], "d_released": d["released"]["mean"],
            "d_split": d["split"]["mean"], "d0": d["split"]["d0"], "d90": d["split"]["d90"],
            "reyield": ", ".join(f"{k} {v:.1f} % (+{r['reyield_max_plastic_strain'][k]:.1e})"
                                 for k, v in r["reyield_pct"].items())}


def edges(mesh: object) -> str:
    """The blank's edge length in mm, and those of its refined rings (``mesh.refine``), which
    decide a ring's opening where they hold the wall."""
    if not hasattr(mesh, "edge_length"):
        return "-"  # a mesh file's
    bands = [f"{1e3 * r.edge_length:g} in r {1e3 * r.ring.r_min:g}-{1e3 * r.ring.r_max:g}"
             for r in getattr(mesh, "refine", ())]
    return ", ".join([f"{1e3 * mesh.edge_length:g}", *bands])


def text(s: dict) -> str:
    """A run's split ring in words, mm."""
    o, d = s["opening"], s["diameters"]
    lines = [f"ring {1e3 * s['heights'][0]:g}-{1e3 * s['heights'][1]:g} mm above the bottom: "
             f"{s['elements']} elements, {s['duplicated_nodes']} nodes duplicated on the cut",
             f"opening at mid-height {1e3 * o['at_mid_height']:.3f} mm (along the cut "
             f"{1e3 * o['min']:.3f} to {1e3 * o['max']:.3f} mm)"]
    for name in ("formed", "released", "split"):
        lines.append(f"diameter {name}: mean {1e3 * d[name]['mean']:.3f} mm, 0 deg "
                     f"{1e3 * d[name]['d0']:.3f} mm, 90 deg {1e3 * d[name]['d90']:.3f} mm")
    caution = rings.caution(s.get("section_points"))
    return "\n".join([*lines, *([f"caution: {caution}"] if caution else [])])


def _told(folder: Path) -> Progress:
    """The test's progress on stderr, a line as each stage starts: a fine cup's ring takes
    minutes, most of them in its two releases."""
    from sim.stepping.split_ring import STAGES

    def tell(report: Report) -> None:
        if report.iteration is None:  # a stage starts (Newton's iterates are not printed)
            print(f"q3t splitring: {folder}: {STAGES[report.stage]}", file=sys.stderr,
                  flush=True)

    return tell


def run(args: argparse.Namespace) -> int:
    """Exit 0 when every ring was released, 2 on bad input (before any solve), 1 when a
    release failed."""
    from sim.stepping.split_ring import SplitRingError, open_formed, split_ring

    stamp = Stamp.begin(args.command)
    try:
        bands = [parse_heights(h) for h in args.heights or [HEIGHTS]]
        if not math.isfinite(args.cut_angle):
            raise ValueError("--cut-angle: must be a finite angle in degrees")
        args.cut_angle = rings.angle(args.cut_angle)  # 360 is 0: the same ring
        formed = [(Path(f), open_formed(Path(f))) for f in args.runs]
    except (SplitRingError, ValueError) as exc:
        print(f"q3t splitring: {exc}", file=sys.stderr)
        return BAD_INPUT
    rows = []
    for folder, fm in formed:
        for z1, z2 in bands:
            try:
                res = split_ring(fm, z1, z2, math.radians(args.cut_angle), _told(folder))
            except SplitRingError as exc:
                print(f"q3t splitring: {folder}: {exc}", file=sys.stderr)
                return BAD_INPUT
            except RuntimeError as exc:
                print(f"q3t splitring: {folder}: FAILED: {exc}", file=sys.stderr)
                return FAILED
            try:
                rings.save(folder, res, fm.ep[res.ring.elements].mean(1))
            except ValueError as exc:  # a number not finite: nothing written
                print(f"q3t splitring: {folder}: FAILED: {exc}", file=sys.stderr)
                return FAILED
            print(f"{folder}:\n{text(res.summary)}")
            rows.append(row(folder, fm, res.summary))
    body = (f"The split-ring test (sim.stepping.split_ring) on each run's final state: rings "
            "cut between the heights given (mm above the cup's bottom), split along the "
            f"meridian at {args.cut_angle:g} degrees from the rolling direction (x); the "
            "opening is the gap between the cut's faces along the circumference at the ring's "
            "mid-height; D the mean diameter (a least-squares circle through the mid-surface) "
            "formed (in the tools), released (the closed ring cut out) and split, and the "
            "split ring's diameters at 0 and 90 degrees to the cut.\n\n"
            + markdown_table(rows, COLS))
    print(body)
    if args.results:
        write_results(args.results, "The split-ring test", body, stamp)
        print(f"wrote {args.results}", file=sys.stderr)
    return OK


def add_parser(sub: argparse._SubParsersAction) -> None:
    s = sub.add_parser("splitring", help="the split-ring springback test on formed cups: a "
                                         "ring cut from the wall, split and released")
    s.add_argument("runs", nargs="+", metavar="RUN",
                   help="run folders (q3t run --out) of plastic cups")
    s.add_argument("--heights", action="append", metavar="Z1,Z2",
                   help="a ring's lower and upper edge, mm above the cup's bottom; repeat for "
                        f"more rings (default {HEIGHTS})")
    s.add_argument("--cut-angle", type=float, default=0.0, metavar="DEG",
                   help="the split's meridian, degrees about z from x (the rolling direction; "
                        "taken modulo 360; default %(default)g)")
    add_results_option(s, "split-ring.md")
    s.set_defaults(func=run)

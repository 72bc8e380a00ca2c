"""``q3t springback``: a strip bent by a pure end moment and released, against the classical
formula K = R / R_after = 4 X^3 - 3 X + 1, X = sigma_y R / (E t), in plane strain
(E / (1 - nu^2), 2 sigma_y / sqrt(3)), R the measured loaded radius.

The strip is the scene's (``plastic_bending``: an elastic-perfectly-plastic strip in plane
strain whose end section turns as on an arc; ``sim.analytic.springback`` checks the scene meets
the formula's assumptions) cut to one cell across and ``--length`` long, its end turned to the
radius of each X. Each X and element runs three cases, as Dask tasks
(``sim.apps.tasks.run_tasks``, ``run_case``): at the element's edge (``--spacing`` times its
in-plane degree, from the registry) with ``--points`` section points, at half that edge, and
with twice the points, so that the table says both the error against the formula and how far
the result is from converged in the mesh and in the thickness rule
(``tests/verification/test_plasticity.py::test_springback_matches_the_classical_formula``).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from sim.apps.cases import run_case
from sim.apps.common import BAD_INPUT, FAILED, OK, load, resolve_scene
from sim.apps.study_report import markdown_table
from sim.apps.tasks import cluster_text, run_tasks
from sim.frames import results
from sim.refinement import element_overrides
from sim.stamp import Stamp, add_results_option, write_results

if TYPE_CHECKING:
    from sim.scene.load import Scene

VARIANTS = ("base", "half edge", "double points")


def formula(X: float) -> float:
    """K = R / R_after of an elastic-perfectly-plastic section bent to X and released."""
    return 4 * X**3 - 3 * X + 1


def plane_strain(scene: Scene) -> tuple[float, float, float]:
    """(E / (1 - nu^2), 2 sigma_y / sqrt(3), t) of the scene: X = Yp R / (Ep t)."""
    m = scene.material
    return m.E / (1 - m.nu**2), 2 * m.yield_stress / math.sqrt(3), scene.shell.thickness


def strip(scene_path: str, X: float, element: str, edge: float, length: float,
          points: int) -> dict:
    """The overrides cutting the scene to a strip one cell (``edge``) across and ``length``
    long, its bent end turned to the radius of ``X``, with ``element``'s in-plane rule and
    ``points`` section points. ValueError naming the field when the scene cannot be cut so or
    does not meet the formula's assumptions."""
    from sim.analytic import springback
    from sim.elements import ELEMENTS

    sc = load(scene_path)
    bend = [i for i, bc in enumerate(sc.bcs) if bc.bend is not None]
    if len(bend) != 1:
        raise ValueError(f"{sc.name}: bcs: springback needs one bent end, found {len(bend)}")
    regions = [r.name for r in sc.regions]
    end = regions.index(sc.bcs[bend[0]].region)
    if sc.regions[end].plane is None:
        raise ValueError(f"{sc.name}: regions.{end}: the bent end must be a plane region")
    Ep, Yp, t = plane_strain(sc)
    R = X * Ep * t / Yp
    rule = f"{element}:{ELEMENTS[element].default_quadrature[0]}x{points}"
    o = {**element_overrides(rule), "mesh.size": [length, edge], "mesh.edge_length": edge,
         f"bcs.{bend[0]}.bend.length": length, f"bcs.{bend[0]}.bend.angle": length / R,
         f"regions.{end}.plane.point": [length, 0.0, 0.0]}
    cut = load(scene_path, o)
    probe = next((p.name for p in cut.probes if p.kind == "curvature"), None)
    if probe is None:
        raise ValueError(f"{sc.name}: probes: springback needs a curvature probe")
    springback(cut, probe)  # ValueError: not plastic, not plane strain, X outside (0, 1), ...
    return o


def plan(args: argparse.Namespace) -> tuple[str, list[dict]]:
    """The scene and its cases, each ``{"X", "element", "edge", "variant", "overrides"}``;
    ValueError on bad input."""
    from sim.elements import ELEMENTS

    scene = str(resolve_scene(args.scene))
    for name in ("spacing", "length"):
        if not getattr(args, name) > 0:
            raise ValueError(f"--{name} must be positive (m)")
    if args.points < 1:
        raise ValueError("--points must be at least 1")
    try:
        xs = [float(v) for v in args.X.split(",")]
    except ValueError:
        raise ValueError(f"--X: {args.X!r} is not a comma-separated list of numbers") from None
    if not all(0 < X < 1 for X in xs):
        raise ValueError(f"--X: each X must lie in (0, 1), where the strip yields and is not "
                         f"a hinge (got {args.X})")
    cases = []
    for X in xs:
        for el in args.elements.split(","):
            if el not in ELEMENTS:
                raise ValueError(f"--elements: unknown {el!r}; known: {sorted(ELEMENTS)}")
            edge = ELEMENTS[el].edge_for_spacing(args.spacing)
            for variant, (h, n) in zip(VARIANTS, ((edge, args.points), (edge / 2, args.points),
                                                  (edge, 2 * args.points)), strict=True):
                cases.append({"X": X, "element": el, "edge": edge, "variant": variant,
                              "overrides": strip(scene, X, el, h, args.length, n)})
    return scene, cases


def measured(r: dict, Ep: float, Yp: float, t: float) -> dict:
    """K = k_load / k_after of a case and the formula at the X of its loaded curvature (the
    last loading step's; the release is not in the history)."""
    if r.get("status") != "converged":
        return {}
    k_load, k_after = r["history"]["curvature"][-1], r["probes"]["curvature"]
    Xm = Yp / (Ep * t * k_load)
    return {"K": k_after / k_load, "X_measured": Xm, "formula": formula(Xm)}


def table(cases: list[dict], rows: list[dict], constants: tuple[float, float, float]) -> list[dict]:
    """One line per X and element: its base case against the formula, and the change of K
    when the edge is halved and when the section points are doubled."""
    got = [{**c, **measured(r, *constants), "status": r.get("status"),
            "reason": r.get("reason")} for c, r in zip(cases, rows, strict=True)]
    out = []
    for i in range(0, len(got), len(VARIANTS)):
        base, half, double = got[i:i + len(VARIANTS)]
        bad = [f"{g['variant']}: {g['status']} ({g['reason']})" for g in (base, half, double)
               if g["status"] != "converged"]
        line = {"X": base["X"], "element": base["element"], "edge": 1e3 * base["edge"],
                "status": "; ".join(bad) or "converged"}
        if not bad:
            line.update(X_measured=base["X_measured"], formula=base["formula"], K=base["K"],
                        error=100 * (base["K"] / base["formula"] - 1),
                        half=100 * (half["K"] / base["K"] - 1),
                        double=100 * (double["K"] / base["K"] - 1))
        out.append(line)
    return out


def report(args: argparse.Namespace, lines: list[dict], where: str) -> str:
    cols = [("X", "X", "g"), ("element", "element", ""), ("edge", "edge [mm]", "g"),
            ("X_measured", "X at the loaded R", ".4f"), ("formula", "formula K", ".4f"),
            ("K", "K = R / R_after", ".4f"), ("error", "against the formula [%]", "+.2f"),
            ("half", "halving the edge [%]", "+.3f"),
            ("double", f"{args.points} -> {2 * args.points} points [%]", "+.3f"),
            ("status", "status", "")]
    return (f"K = R / R_after = 4X^3 - 3X + 1, X = sigma_y R / (E t) in plane strain (E / (1 - "
            "nu^2), 2 sigma_y / sqrt(3)), R the loaded radius measured at the end of loading "
            "(the curvature of a circle fitted to the mid-surface), against K of the same "
            f"strip after release. The strip: `{Path(args.scene).stem}` cut to one cell across "
            f"and {1e3 * args.length:g} mm long, bent by turning its end section (a pure end "
            f"moment), {args.points} section points, the element's edge {1e3 * args.spacing:g} "
            "mm times its in-plane degree; the last two columns are the change of K when the "
            "edge is halved and when the section points are doubled. Ran on "
            f"{where}.\n\n" + markdown_table(lines, cols))


def run(args: argparse.Namespace) -> int:
    """Exit 0 when every case converged, 1 when one failed (the table says which), 2 on bad
    input."""
    from sim.scene.load import SceneError

    stamp = Stamp.begin(args.command)
    try:
        if args.workers < 1:
            raise ValueError("--workers must be at least 1")
        if args.timeout is not None and not args.timeout > 0:
            raise ValueError("--timeout must be positive (seconds)")
        scene, cases = plan(args)
    except (SceneError, ValueError) as exc:
        print(f"q3t springback: {exc}", file=sys.stderr)
        return BAD_INPUT
    calls = [(run_case, scene, c["overrides"], True) for c in cases]

    def progress(i: int, r: dict) -> None:
        c = cases[i]
        print(f"X={c['X']:g} {c['element']:9s} {c['variant']:13s} {r['status']}",
              file=sys.stderr, flush=True)

    rows, _ = run_tasks(calls, [{} for _ in calls], args.workers, 1, args.scheduler,
                        args.timeout, progress)
    lines = table(cases, rows, plane_strain(load(scene)))
    body = report(args, lines, cluster_text(args.workers, 1, args.scheduler))
    print(body)
    title = "Springback against the classical formula"
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "report.md").write_text(f"# {title}\n\n{body}")
        results.write(out / "report.json", {"cases": [{**c, **r} for c, r in
                                                      zip(cases, rows, strict=True)],
                                            "table": lines})
    if args.results:
        write_results(args.results, title, body, stamp)
        print(f"wrote {args.results}")
    failed = [ln for ln in lines if ln["status"] != "converged"]
    if failed:
        print(f"q3t springback: {len(failed)} line(s) did not converge", file=sys.stderr)
    return FAILED if failed else OK


def add_parser(sub: argparse._SubParsersAction) -> None:
    s = sub.add_parser("springback", help="springback of a bent strip against the classical "
                                          "formula, converged in mesh and section points")
    s.add_argument("--scene", default="plastic_bending",
                   help="the strip's scene (default plastic_bending)")
    s.add_argument("--X", default="0.1,0.2",
                   help="comma-separated X = sigma_y R / (E t), each in (0, 1) (default "
                        "%(default)s)")
    s.add_argument("--elements", default="q3t,quadratic",
                   help="comma-separated (default %(default)s)")
    s.add_argument("--spacing", type=float, default=0.0025,
                   help="in-plane node spacing in m: the edge is this times the element's "
                        "degree (default %(default)g)")
    s.add_argument("--length", type=float, default=0.04,
                   help="the strip's length in m (default %(default)g)")
    s.add_argument("--points", type=int, default=20,
                   help="section points through the thickness (default %(default)d)")
    s.add_argument("--workers", type=int, default=1, help="local Dask workers (default 1)")
    s.add_argument("--scheduler", help="address of an existing Dask scheduler")
    s.add_argument("--timeout", type=float, default=None,
                   help="seconds for all cases; unfinished ones are marked timeout")
    s.add_argument("--out", help="also write report.md and report.json there")
    add_results_option(s, "springback-formula.md")
    s.set_defaults(func=run)

"""``q3t bifurcation``: follow the stiffness's lowest eigenvalues along a scene's static load
path (sim.apps.stability), per element: where the lowest one crosses zero (the path
bifurcates: a stretched sheet wrinkles), how far the sheet then leaves its plane, and whether
it comes back (wrinkles that vanish again at larger strain).

The load path is the scene's pulled end: its first BC with a displacement, else its first
traction load. The nominal strain is that end's mean displacement along the pull over the
sheet's length along it. Runs one element after the other in this process (one heavy process
at a time on a shared machine)."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from sim.apps.common import BAD_INPUT, FAILED, OK, load, parse_sets
from sim.stamp import Stamp, add_results_option, write_results

if TYPE_CHECKING:
    from sim.apps.stability import PathPoint
    from sim.scene.load import Scene


def markdown_table(rows: list[dict]) -> str:
    """Rows of already formatted cells under the first row's keys."""
    from sim.apps.study_report import markdown_table as columns

    if not rows:
        return "(no step converged)\n"
    return columns(rows, [(k, k, "") for k in rows[0]])


def pulled_end(scene: Scene) -> tuple[str, np.ndarray]:
    """The region that pulls the sheet and the direction of the pull: the first BC with a
    nonzero displacement, else the first traction load; SceneError naming the fields when the
    scene has neither."""
    from sim.scene.load import SceneError

    for bc in scene.bcs:
        d = np.asarray(bc.displacement, float)
        if np.any(d != 0):
            return bc.region, d / np.linalg.norm(d)
    for ld in scene.loads:
        if ld.kind == "traction" and np.any(np.asarray(ld.vector) != 0):
            v = np.asarray(ld.vector, float)
            return ld.region, v / np.linalg.norm(v)
    raise SceneError(f"{scene.name}: bcs, loads: bifurcation follows a pulled end, a BC with a "
                     "displacement or a traction load; the scene has neither")


def follow_scene(scene: Scene, modes: int, kick: float,
                 progress: Callable[[PathPoint], None] | None = None) -> dict:
    """One element's path: ``{"element", "dofs", "edge", "points", "failure", "wall"}``, each
    point a sim.apps.stability.PathPoint; ``kick`` in thicknesses."""
    from sim.apps.stability import follow, history
    from sim.scene.load import SceneError
    from sim.stepping.simulation import Simulation

    if scene.stepping.kind != "static":
        raise SceneError(f"{scene.name}: stepping.kind: bifurcation follows a static load path, "
                         f"not {scene.stepping.kind!r}")
    region, direction = pulled_end(scene)
    sim = Simulation.from_scene(scene)
    if kick and (why := history(sim)):
        raise SceneError(f"--kick: {kick:g} thicknesses retakes steps from a saved state, "
                         f"which {scene.name}'s {why} makes path-dependent (--kick 0 follows "
                         "it without)")
    m = sim.model
    nodes = m.column_nodes(m.regions[region])
    c = sim.result()["counts"]
    if modes >= c["free_dofs"]:
        raise SceneError(f"--modes: {modes} eigenvalues of a stiffness with {c['free_dofs']} "
                         "free DoFs (at most one fewer)")
    t0 = time.perf_counter()
    points, failure = [], None
    thickness = float(np.mean(m.shell.thickness))
    try:
        for p in follow(sim, nodes, direction, modes, kick * thickness):
            points.append(p)
            if progress:
                progress(p)
    except RuntimeError as exc:  # the eigensolver's (SuperLU, ARPACK): the path so far stays
        failure = {"step": points[-1].step + 1 if points else 0,
                   "reason": f"eigenvalues: {exc}"}
    return {"element": scene.shell.element, "dofs": c["free_dofs"], "edge":
            scene.mesh.edge_length, "points": points, "failure": failure or sim.failure,
            "thickness": thickness, "wall": time.perf_counter() - t0}


def summary_row(run: dict) -> dict:
    """The path in a few numbers: where the lowest eigenvalue crosses zero (interpolated), the
    largest out-of-plane amplitude and its strain (none under 1 % of the thickness: "flat"),
    and the last step's."""
    from sim.apps.stability import bracket, crossing

    pts = run["points"]
    cross, ab = crossing(pts), bracket(pts)
    peak = max(pts, key=lambda p: p.amplitude) if pts else None
    # a sheet that never left its plane has round-off heights, no peak to come back from
    if peak and peak.amplitude < 0.01 * run["thickness"]:
        peak = None
    # flat again: the first step after the peak whose amplitude is under 1 % of it (a
    # wrinkled state comes back to the plane where its branch rejoins the flat one)
    flat = next((p for p in pts if peak and p.step > peak.step
                 and p.amplitude < 0.01 * peak.amplitude), None)
    last = pts[-1] if pts else None
    fail = run["failure"]
    return {
        "element": run["element"], "mesh edge [mm]": 1e3 * run["edge"], "free DoFs": run["dofs"],
        "lowest eigenvalue crosses zero at strain [%]": "never" if cross is None
        else f"{100 * cross:.3g}",
        "between steps at [%]": "" if ab is None
        else f"{100 * ab[0].strain:.3g} - {100 * ab[1].strain:.3g}",
        "most negative eigenvalues at once": max((p.negative for p in pts), default=0),
        "largest amplitude [mm]": f"{1e3 * peak.amplitude:.4g}" if peak else "flat",
        "at strain [%]": f"{100 * peak.strain:.3g}" if peak else "",
        "flat again at strain [%]": f"{100 * flat.strain:.3g}" if flat else "",
        "last strain [%]": f"{100 * last.strain:.3g}" if last else "",
        "amplitude there [mm]": f"{1e3 * last.amplitude:.4g}" if last else "",
        "lowest eigenvalue there [N/m]": f"{last.eigenvalues[0]:.4g}" if last else "",
        "status": "converged" if fail is None else f"failed at step {fail['step']}: "
                                                   f"{fail['reason']}",
        "wall [s]": f"{run['wall']:.0f}",
    }


def _modes(p: PathPoint) -> str:
    return "the lowest mode" if p.modes == 1 else f"the {p.modes} unstable modes"


def path_rows(run: dict) -> list[dict]:
    rows = []
    for p in run["points"]:
        rows.append({
            "step": p.step, "nominal strain [%]": f"{100 * p.strain:.4g}",
            **{f"eigenvalue {i + 1} [N/m]": f"{v:.5g}" for i, v in enumerate(p.eigenvalues)},
            "negative": p.negative, "unstable direction's z share": f"{p.out_of_plane:.2f}",
            "amplitude [mm]": f"{1e3 * p.amplitude:.4g}", "RMS height [mm]": f"{1e3 * p.rms:.4g}",
            "Newton iterations": p.iterations,
            "kicked": f"along {_modes(p)}" if p.kicked else ""})
    return rows


def run(args: argparse.Namespace) -> int:
    from sim.scene.load import SceneError

    started = Stamp.begin(args.command)
    overrides = parse_sets(args.set)
    if args.modes < 1:
        raise SceneError(f"--modes: {args.modes} is not a number of eigenvalues >= 1")
    if not args.kick >= 0:
        raise SceneError(f"--kick: {args.kick:g} thicknesses is not >= 0")
    if args.spacing is not None and not args.spacing > 0:
        raise SceneError(f"--spacing: {args.spacing:g} m is not a positive node spacing")
    elements = args.elements.split(",") if args.elements else [None]
    runs = []
    for el in elements:
        o = dict(overrides)
        if el:
            o["shell.element"] = el
        if args.spacing:
            from sim.elements import ELEMENTS

            name = el or load(args.scene, o).shell.element
            if name not in ELEMENTS:
                raise SceneError(f"--elements: unknown {name!r}; known: {sorted(ELEMENTS)}")
            o["mesh.edge_length"] = ELEMENTS[name].edge_for_spacing(args.spacing)
        scene = load(args.scene, o)  # SceneError: exit 2
        print(f"{scene.name}: {scene.shell.element}", file=sys.stderr, flush=True)

        def show(p: PathPoint) -> None:
            if not args.quiet:
                print(f"  step {p.step}: strain {100 * p.strain:.2f} %, lowest eigenvalues "
                      f"{np.array2string(np.asarray(p.eigenvalues), precision=4)} N/m, "
                      f"{p.negative} negative, amplitude {1e3 * p.amplitude:.4g} mm, RMS "
                      f"{1e3 * p.rms:.4g} mm"
                      + (f" (kicked along {_modes(p)})" if p.kicked else ""),
                      file=sys.stderr, flush=True)

        try:
            runs.append(follow_scene(scene, args.modes, args.kick, show))
        except SceneError as exc:
            print(f"q3t: {exc}", file=sys.stderr)
            return BAD_INPUT
    summary = [summary_row(r) for r in runs]
    text = markdown_table(summary)
    print(text)
    if args.results:
        body = ["## Per element", "", text, "",
                "Eigenvalues of the stiffness (exact Hessian of the total energy, held DoFs "
                "removed), the lowest first; `negative`: how many are below s0, a hair below "
                "zero (the inertia; what counts as unstable); the unstable direction's z share: "
                "the part of its squared norm out of plane; amplitude: the mid-surface's height "
                "range; RMS height: the root mean square of its height over its area (the same "
                "where nearly equal wrinkle patterns mix, which moves the range: "
                "sim.apps.stability.rms_height). "
                f"Kick: {args.kick:g} thickness along the unstable direction (a sheet "
                "lifted at one corner through the negative part of the stiffness, each unstable "
                "mode weighted by how far below s0 it lies) each time a state is unstable "
                "(sim.apps.stability.follow); until the first, "
                "a step that ends unstable or off the plane is retaken in "
                "halves, down to 1/8 of a step (strains between the planned ones), so the "
                "crossing is found on flat converged states and the kick, not round-off, "
                "picks the branch.", ""]
        for r in runs:
            body += [f"## {r['element']}, edge {1e3 * r['edge']:g} mm, {r['dofs']} free DoFs",
                     "", markdown_table(path_rows(r)), ""]
        write_results(args.results, f"`{load(args.scene, overrides).name}`: the lowest "
                      "eigenvalues of the stiffness along the load path", "\n".join(body),
                      started)
        print(f"wrote {args.results}", file=sys.stderr)
    return OK if all(r["failure"] is None for r in runs) else FAILED


def add_parser(sub: argparse._SubParsersAction) -> None:
    b = sub.add_parser("bifurcation", help="follow the stiffness's lowest eigenvalues along a "
                                           "static load path: where it buckles or wrinkles")
    b.add_argument("scene", help="scene name in scenes/ or a TOML path")
    b.add_argument("--elements", help="comma-separated elements to run one after the other "
                                      "(default: the scene's)")
    b.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scene value, e.g. mesh.edge_length=0.005 (repeatable)")
    b.add_argument("--spacing", type=float, metavar="M",
                   help="in-plane node spacing (m): each element's mesh edge is this times its "
                        "in-plane degree, so all compare on the same nodes (default: the "
                        "scene's edge_length for all)")
    b.add_argument("--modes", type=int, default=3, help="eigenvalues per step (default 3)")
    b.add_argument("--kick", type=float, default=0.1, metavar="THICKNESSES",
                   help="push the state this far (mid-surface z, in thicknesses) along its "
                        "unstable direction each time it is unstable, so the run leaves the "
                        "flat path, and an unstable wrinkled one (default %(default)g; 0: "
                        "never)")
    b.add_argument("--quiet", action="store_true")
    add_results_option(b, "fig4-wrinkling.md")
    b.set_defaults(func=run)

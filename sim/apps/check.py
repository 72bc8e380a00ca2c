"""``q3t check``: a stability suite of hard cases, each with every element type.

Each (case, element) runs in a child process with a wall-clock budget and is killed when over it.
Every case states the outcome it must end in, per element where they differ: ``converged`` (and
then physically right: the supports carry what is applied, see ``sim.apps.cases.force_balance``),
``rejected`` (input that is wrong, with an error naming the field or the element), or a failure
class (:data:`FAILURES`: what the solver's diagnostic names as the cause). Anything else - another
outcome, an unclassified failure, a crash, a non-finite probe, a timeout - is a problem.

The base is the cantilever plate (paper Fig. 5) at a coarse size with the same in-plane node
spacing for every element (the paper's same-nodes comparison, edge lengths from the element
registry: ``Prism.edge_for_spacing``): 320 triangles for linear and Q3T,
80 for quadratic, 20 for quartic, about 1,200-3,000 DoFs each. The tool cases use the beam
forming scene (paper Fig. 1) at the same node spacing, 2.5 mm: 160 triangles for linear and
Q3T, 10 for quartic.
"""

from __future__ import annotations

import argparse
import signal
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from sim.apps.cases import isolated_context, run_isolated
from sim.apps.common import FAILED, OK, load, resolve_scene
from sim.elements import ELEMENTS, get_element
from sim.frames import results
from sim.stamp import Stamp, add_results_option, write_results

if TYPE_CHECKING:
    from sim.scene.load import Scene

BASE = "cantilever"
TOOLS = "beam_forming"
SPACING = 0.0175  # in-plane node spacing of every element on the base scene (m)
TOOL_EDGE = 0.0025 / SPACING  # the tool scene's spacing, relative

# Failure classes, each with the words of the solver's diagnostic that name it, in the order
# they are looked for (a round-off floor message wraps the way the iteration ended).
FAILURES = {
    "load below round-off floor": "load below force round-off floor",
    "penetration beyond bound": "penetration beyond bound",
    "inverted element": "inverted element",
    "singular factorisation": "singular factorisation",
    "line search stalled": "line search stalled",
    "iteration budget": "no convergence in",
}
# what a converged run's supports may miss of what is applied, relative: the residual left at
# its round-off floor sums to 1e-15..1.3e-6 of it over the free DoFs (measured, every case)
BALANCE = 1e-4


@dataclass(frozen=True)
class Case:
    name: str
    what: str  # why the case is hard
    overrides: dict = field(default_factory=dict)
    # the outcome it must end in: "converged", "rejected" or a failure class; per element
    expect: str | dict = "converged"
    reject: str = ""  # words the rejection must contain
    scene: str = BASE
    mesh: str = ""  # a file mesh written at run time: "sliver", "inverted" or "flat"
    skip: dict = field(default_factory=dict)  # element -> why the case does not run with it

    def expected(self, element: str) -> str:
        return self.expect if isinstance(self.expect, str) else self.expect[element]


def load_overrides(scene: Scene, factor: float) -> dict:
    """Every load of ``scene`` times ``factor``, as overrides."""
    out = {}
    for i, ld in enumerate(scene.loads):
        if ld.kind == "pressure":  # a magnitude; the other kinds carry a vector
            out[f"loads.{i}.value"] = ld.value * factor
        else:
            out[f"loads.{i}.vector"] = [v * factor for v in ld.vector]
    return out


def make_cases(scene: Scene) -> list[Case]:
    """The suite on ``scene`` (the cantilever)."""
    h0, L = scene.shell.thickness, scene.mesh.size[0]
    cs = [Case(f"nu={nu}", "Poisson locking, near-incompressible", {"material.nu": nu})
          for nu in (0.49, 0.499, 0.4999)]
    cs += [Case(f"E={E:.0e}", "load fixed: 1 MPa hangs the plate down (large rotation), 200 GPa "
                "tests the residual floor", {"material.E": E}) for E in (1e6, 1e8, 2e11)]
    for r in (1e-1, 1e-2, 1e-3, 1e-4):
        h = r * L
        # self-weight deflection goes as g / h^2: scaling g by (h/h0)^2 keeps it at ~10 % of L,
        # so the case tests thin-shell conditioning ((L/h)^2), not large rotation (E=1e+06 does)
        expect: str | dict = "converged"
        if r == 1e-4:
            # the load (2.6e-8 N) sits 200x below what rounding the positions does to the
            # residual (4.9e-6 N for Q3T): the prisms' through-thickness stiffness against
            # their bending stiffness, (L/h)^2 (edge/h)^2 ~ 1e13, is beyond double precision.
            # Shear-locked linear prisms bend 60x less, which keeps them within it; the
            # assumed-strain Q3T does not lock, and is beyond it too.
            expect = {"linear": "converged", "q3t": "load below round-off floor",
                      "q3t_ans": "load below round-off floor",
                      "quadratic": "load below round-off floor",
                      "quartic": "load below round-off floor"}
        cs.append(Case(f"h/L={r:.0e}", "thin-shell conditioning, load x (h/h0)^2",
                       {"shell.thickness": h, **load_overrides(scene, (h / h0) ** 2)}, expect))
    cs.append(Case("1 step, 100x load", "one huge increment: cut-backs must rescue it",
                   {"stepping.steps": 1, **load_overrides(scene, 100.0)}))
    # implicit Euler from rest under gravity; 2 ms is 1/200 of the first bending period
    # (0.43 s), x100 steps over two periods at once
    dyn = {"stepping.kind": "dynamic", "stepping.steps": 10}
    cs.append(Case("dynamic, dt 2 ms", "implicit Euler, the plate starts to fall",
                   {**dyn, "stepping.dt": 2e-3}))
    cs.append(Case("dynamic, dt x100", "time steps 100x the default: 0.2 s, past two periods",
                   {**dyn, "stepping.dt": 0.2}))
    # thickness falling linearly from h0 at the clamp to h0 / 4 at the tip
    cs.append(Case("varying thickness", "tapered plate: h0 at the clamp, h0/4 at the tip",
                   {"shell.thickness_gradient": [-0.75 * h0 / L, 0.0, 0.0]}))
    cs.append(Case("sliver triangles", "file mesh: 4 vertices at 1e-3 of an opposite edge, 6 "
                   "triangles of aspect ratio 1e3-2e3", mesh="sliver"))
    cs.append(Case("zero thickness", "must be rejected with an error naming the field",
                   {"shell.thickness": 0.0}, "rejected", reject="shell.thickness"))
    cs.append(Case("inverted element", "file mesh with one triangle wound the other way",
                   expect="rejected", reject="1 element(s) inverted or flat", mesh="inverted"))
    cs.append(Case("zero-area element", "file mesh with one vertex on its opposite edge",
                   expect="rejected", reject="1 element(s) inverted or flat", mesh="flat"))
    # the punch's 13.2 mm stroke in 100 steps, then in one: sub-steps must keep the punch from
    # jumping through the 2 mm beam
    tool = {"stepping.release": False}
    cs.append(Case("punch, 100 steps", "beam pressed into a mold, plastic, 0.13 mm per step",
                   {**tool, "stepping.steps": 100}, scene=TOOLS))
    cs.append(Case("punch 100x faster", "the whole 13.2 mm stroke in one step",
                   {**tool, "stepping.steps": 1}, scene=TOOLS))
    return cs


def base_edge(element: str) -> float:
    """The base scene's mesh edge length for ``element``: its nodes ``SPACING`` apart."""
    return get_element(element).edge_for_spacing(SPACING)


def write_sliver_obj(path: Path, size: tuple[float, float] = (0.7, 0.07), edge: float = SPACING,
                     eps: float = 1e-3, kind: str = "sliver") -> int:
    """The rectangle mesh with 4 interior vertices moved to ``eps`` of the way from the midpoint
    of an opposite edge (of one of their triangles): slivers of aspect ratio ~1/eps. The midpoint
    is inside the vertex's convex star, so no triangle inverts. ``kind`` "flat": one vertex moved
    onto the midpoint (a zero-area triangle); "inverted": one triangle wound the other way.
    Returns the number of triangles."""
    from sim.geometry.trimesh import boundary_edges, rectangle

    m = rectangle(size, edge)
    V, F = m.vertices.copy(), m.faces.copy()
    inner = np.setdiff1d(np.arange(len(V)), boundary_edges(F))
    moved = inner[np.linspace(0, len(inner) - 1, 6).astype(int)[1:-1]]
    if kind == "inverted":  # at vertices of 3+ triangles: every vertex normal stays defined
        f = np.nonzero((np.bincount(F.ravel())[F] >= 3).all(1))[0][0]
        F[f] = F[f, ::-1]
    else:
        for v in moved[:1] if kind == "flat" else moved:
            a, b = [u for u in F[np.nonzero((F == v).any(1))[0][0]] if u != v]
            mid = (V[a] + V[b]) / 2
            V[v] = mid + (0.0 if kind == "flat" else eps) * (V[v] - mid)
        e1, e2 = V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]
        area = 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
        small = np.sort(np.abs(area))[:2] / np.median(area)
        # a moved vertex's triangle: 1e-3 of the others (sliver), or zero to round-off (flat)
        assert area.min() > 0 if kind == "sliver" else small[0] < 1e-12 < small[1], kind
    lines = [f"v {x:.17g} {y:.17g} {z:.17g}" for x, y, z in V]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in F]
    path.write_text("\n".join(lines) + "\n")
    return len(F)


def outcome(out: dict) -> str:
    """The run's outcome: converged, rejected, a failure class from its diagnostic, or what
    went wrong (timeout, crashed, nan, unclassified failure)."""
    status = out["status"]
    if status == "invalid":
        return "rejected"
    if status != "failed":
        return status
    reason = out.get("reason") or ""
    return next((c for c, words in FAILURES.items() if words in reason),
                "unclassified failure")


def verdict(case: Case, element: str, out: dict) -> str:
    """"ok", or "PROBLEM: " and what is wrong."""
    got, want = outcome(out), case.expected(element)
    if got != want:
        return f"PROBLEM: expected {want}"
    if got == "rejected" and case.reject not in (out.get("reason") or ""):
        return f"PROBLEM: rejection does not name {case.reject!r}"
    bal = out.get("measured", {}).get("balance")
    if got == "converged" and not (bal is not None and bal <= BALANCE):
        return f"PROBLEM: supports miss {bal:.1e} of the applied force"
    return "ok"


def run_check(cases: list[Case], elements: list[str], budget: float,
              progress: Callable[[dict], None] | None = None,
              edges: dict | None = None) -> list[dict]:
    """Every case with every element; ``edges`` overrides the mesh edge length per element
    (default: ``base_edge``, the same node spacing for all; a name the registry does not know runs
    at ``SPACING``, for its scene to reject)."""
    edges = {**{el: base_edge(el) for el in elements if el in ELEMENTS}, **(edges or {})}
    with tempfile.TemporaryDirectory() as tmp:
        return _run_all(cases, elements, budget, Path(tmp), progress, edges)


def _run_all(cases: list[Case], elements: list[str], budget: float, tmp: Path,
             progress: Callable[[dict], None] | None, edges: dict[str, float]) -> list[dict]:
    rows = []
    ctx = isolated_context()
    for c in cases:
        for el in elements:
            row = {"case": c.name, "what": c.what, "element": el, "expect": c.expected(el)}
            if el in c.skip:
                rows.append({**row, "status": "skipped", "outcome": "skipped",
                             "reason": c.skip[el], "verdict": "skipped"})
                continue
            # the same node spacing for every element, on the tool scene too (2.5 mm)
            h = edges.get(el, SPACING) * (1.0 if c.scene == BASE else TOOL_EDGE)
            o = {"shell.element": el, "mesh.edge_length": h, **c.overrides}
            if c.mesh:
                h = min(o["mesh.edge_length"], 0.035)  # two rows of cells at least
                obj = tmp / f"{c.mesh}-{h}.obj"
                if not obj.exists():
                    write_sliver_obj(obj, edge=h, kind=c.mesh)
                o.update({"mesh.kind": "file", "mesh.path": str(obj)})
            out = run_isolated(str(resolve_scene(c.scene)), o, budget, ctx)
            rows.append({**row, **out, "overrides": o, "outcome": outcome(out),
                         "verdict": verdict(c, el, out)})
            if progress:
                progress(rows[-1])
    return rows


def table(rows: list[dict]) -> str:
    head = ["case", "element", "DoFs", "outcome", "Newton it.", "cut-backs", "final residual [N]",
            "floor [N]", "support z [N]", "balance", "probe", "time [s]", "verdict",
            "diagnostic"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        res, ms = r.get("residual"), r.get("measured") or {}
        pr = r.get("probes", {})
        key = next((k for k in ("tip_deflection", "curvature") if k in pr), None)
        done = r.get("outcome") == "converged" and "support_z" in ms
        cells = [r["case"], r["element"], str(r.get("dofs") or ""),
                 r.get("outcome", r["status"]), str(r.get("iterations", "")),
                 str(r.get("cutbacks", "")), f"{res:.2e}" if res is not None else "",
                 f"{ms['floor']:.1e}" if ms.get("floor") is not None else "",
                 f"{ms['support_z']:.6g}" if done else "",
                 f"{ms['balance']:.0e}" if done else "",
                 f"{key} {pr[key]:.4g}" if key else "",
                 f"{r['elapsed']:.1f}" if "elapsed" in r else "", r["verdict"],
                 (r.get("reason") or "").replace("|", "/")[:110]]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def summary(rows: list[dict]) -> str:
    """Markdown, one line per case and a column per element: the outcome with Newton
    iterations, cut-backs and the final residual, or the rejection / failure class."""
    elements = list(dict.fromkeys(r["element"] for r in rows))
    by = {(r["case"], r["element"]): r for r in rows}
    lines = ["| case | " + " | ".join(elements) + " |", "|---|" + "---|" * len(elements)]
    for case in dict.fromkeys(r["case"] for r in rows):
        cells = []
        for el in elements:
            r = by.get((case, el))
            if r is None:
                cells.append("")
                continue
            c = r.get("outcome", r["status"])
            if c == "converged":
                c = (f"{r['iterations']} it, {r['cutbacks']} cb, {r['residual']:.0e} N, "
                     f"{r['elapsed']:.1f} s")
            if r["verdict"] != "ok" and r["verdict"] != "skipped":
                c += f" **{r['verdict']}**"
            cells.append(c)
        lines.append(f"| {case} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def select(cases: list[Case], names: str | None) -> list[Case]:
    if not names:
        return cases
    want = [n.strip() for n in names.split(",")]
    return [c for c in cases if any(w in c.name for w in want)]


def report(cases: list[Case], rows: list[dict], budget: float, wall: float) -> str:
    """The check's markdown below its title: the set-up, the cases, the summary and every run."""
    bad = [r for r in rows if r["verdict"].startswith("PROBLEM")]
    wider = {el: base_edge(el) for el in ELEMENTS if base_edge(el) != SPACING}
    return (f"Base: `{BASE}` scene, edge {SPACING} m "
            f"({', '.join(f'{k} {v} m' for k, v in wider.items())}); tool cases: `{TOOLS}`; "
            f"budget {budget:g} s per run; {len(rows)} runs in {wall:.0f} s; {len(bad)} "
            f"problem(s).\n\n"
            + "\n".join(f"- **{c.name}**: {c.what}" for c in cases) + "\n\n" + summary(rows)
            + "\n" + table(rows))


TITLE = "The stability check (`q3t check`)"


def run(args: argparse.Namespace) -> int:
    # a terminated check exits through Python, which stops its running child and server
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    stamp = Stamp.begin(args.command)
    elements = args.elements.split(",")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    cases = select(make_cases(load(BASE)), args.cases)
    rows = run_check(cases, elements, args.budget, progress=lambda r: print(
        f"{r['case']:20s} {r['element']:9s} {r['outcome']:26s} {r['elapsed']:6.1f} s "
        f"{r['verdict']}", file=sys.stderr, flush=True))
    wall = time.perf_counter() - t0
    md = report(cases, rows, args.budget, wall)
    for path in (out / "check.md", args.results):
        if path:
            write_results(path, TITLE, md, stamp)
    (out / "check.json").write_text(results.dumps({"wall": wall, "budget": args.budget,
                                                   "rows": rows}, nulls=True, indent=1))
    print(md)
    return FAILED if any(r["verdict"].startswith("PROBLEM") for r in rows) else OK


def add_parser(sub: argparse._SubParsersAction) -> None:
    c = sub.add_parser("check", help="stability suite of hard cases (child process each)")
    c.add_argument("--elements", default=",".join(ELEMENTS))
    c.add_argument("--budget", type=float, default=60.0, help="wall-clock seconds per run")
    c.add_argument("--cases", help="comma-separated substrings of case names (default: all)")
    c.add_argument("--out", default="runs/check")
    add_results_option(c, "check.md")
    c.set_defaults(func=run)

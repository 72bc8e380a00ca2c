"""``q3t check``: a stability suite of hard cases, each with every element type.

Each (case, element) runs in a child process with a wall-clock budget and is killed when over it.
A case passes when it ends in one of the expected ways: converged, or failed with the solver's
diagnostic (a reason string), or - for input that is wrong - rejected with an error naming the
field. A crash (any other exception, a signal), a non-finite probe or a timeout is a problem.

The base is the cantilever plate (paper Fig. 5) at a coarse size with the same in-plane node
spacing for every element (the paper's same-nodes comparison): 320 triangles for linear and Q3T,
80 for quadratic, 20 for quartic, about 1,200-3,000 DoFs each.
"""

from __future__ import annotations

import math
import multiprocessing as mp
import signal
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

BASE = "cantilever"
EDGE = {"quadratic": 0.035, "quartic": 0.07}  # p nodes per edge: p times the edge length
DEFAULT_EDGE = 0.0175
ELEMENTS = ["linear", "q3t", "quadratic", "quartic"]


@dataclass(frozen=True)
class Case:
    name: str
    what: str  # why the case is hard
    overrides: dict = field(default_factory=dict)
    expect: str = "solve"  # "solve": converged or a diagnosed failure; "reject": a scene error
    skip: str = ""  # why the case cannot run yet
    sliver: bool = False  # on a file mesh with sliver triangles at the element's edge length


def load_overrides(scene, factor: float) -> dict:
    """Every load of ``scene`` times ``factor``, as overrides."""
    out = {}
    for i, ld in enumerate(scene.loads):
        if ld.value is not None:
            out[f"loads.{i}.value"] = ld.value * factor
        else:
            out[f"loads.{i}.vector"] = [v * factor for v in ld.vector]
    return out


def make_cases(scene) -> list[Case]:
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
        cs.append(Case(f"h/L={r:.0e}", "thin-shell conditioning, load x (h/h0)^2",
                       {"shell.thickness": h, **load_overrides(scene, (h / h0) ** 2)}))
    cs.append(Case("1 step, 100x load", "one huge increment: cut-backs must rescue it",
                   {"stepping.steps": 1, **load_overrides(scene, 100.0)}))
    # thickness falling linearly from h0 at the clamp to h0 / 4 at the tip
    cs.append(Case("varying thickness", "tapered plate: h0 at the clamp, h0/4 at the tip",
                   {"shell.thickness_gradient": [-0.75 * h0 / L, 0.0, 0.0]}))
    cs.append(Case("sliver triangles", "file mesh: 4 vertices at 1e-3 of an opposite edge, 6 "
                   "triangles of aspect ratio 1e3-2e3",
                   sliver=True))
    cs.append(Case("zero thickness", "must be rejected with an error naming the field",
                   {"shell.thickness": 0.0}, expect="reject"))
    return cs


def write_sliver_obj(path: Path, size=(0.7, 0.07), edge=DEFAULT_EDGE, eps=1e-3) -> int:
    """The rectangle mesh with 4 interior vertices moved to ``eps`` of the way from the midpoint
    of an opposite edge (of one of their triangles): slivers of aspect ratio ~1/eps. The midpoint
    is inside the vertex's convex star, so no triangle inverts. Returns the number of triangles."""
    from sim.mesh import boundary_edges, rectangle

    m = rectangle(size, edge)
    V, F = m.vertices.copy(), m.faces
    inner = np.setdiff1d(np.arange(len(V)), boundary_edges(F))
    for v in inner[np.linspace(0, len(inner) - 1, 6).astype(int)[1:-1]]:
        a, b = [u for u in F[np.nonzero((F == v).any(1))[0][0]] if u != v]
        mid = (V[a] + V[b]) / 2
        V[v] = mid + eps * (V[v] - mid)
    e1, e2 = V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]
    area = 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    assert area.min() > 0, "a sliver inverted a triangle"
    lines = [f"v {x:.17g} {y:.17g} {z:.17g}" for x, y, z in V]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in F]
    path.write_text("\n".join(lines) + "\n")
    return len(F)


def _child(conn, scene_path: str, overrides: dict) -> None:
    from sim.sweep import run_case

    # on SIGTERM exit through Python, so numba's process lock is released and not reported as a
    # leaked semaphore; a child stuck in a kernel gets SIGKILL after a grace period
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    try:
        conn.send(run_case(scene_path, overrides))
    except Exception as exc:  # noqa: BLE001 - anything but a diagnosed failure is a crash
        conn.send({"status": "crashed", "reason": f"{type(exc).__name__}: {exc}", "probes": {}})


def run_isolated(scene_path: str, overrides: dict, budget: float, ctx=None) -> dict:
    """``run_case`` in a child process; killed after ``budget`` seconds (status ``timeout``)."""
    ctx = ctx or _context()
    parent, child = ctx.Pipe(duplex=False)
    p = ctx.Process(target=_child, args=(child, scene_path, overrides), daemon=True)
    t0 = time.perf_counter()
    p.start()
    child.close()
    try:
        if parent.poll(budget):
            out = parent.recv()
        else:
            p.terminate()
            p.join(2)
            if p.is_alive():
                p.kill()
            out = {"status": "timeout", "reason": f"killed after the {budget:g} s budget",
                   "probes": {}}
    except EOFError:  # the child died without a word: a signal or a hard exit
        p.join(5)
        out = {"status": "crashed", "reason": f"child exited with code {p.exitcode}",
               "probes": {}}
    p.join(5)
    parent.close()
    out["elapsed"] = time.perf_counter() - t0
    if any(not math.isfinite(v) for v in out.get("probes", {}).values()):
        out.update(status="nan", reason=f"non-finite probe ({out.get('reason')})")
    return out


def _context():
    """Children forked from a clean server that has the solver imported (saves ~1 s a case);
    never forked from this process, whose numba/MKL threads may hold locks."""
    ctx = mp.get_context("forkserver")
    ctx.set_forkserver_preload(["sim.sweep", "sim.simulation", "sim.scene"])
    return ctx


def verdict(case: Case, out: dict) -> str:
    if case.expect == "reject":
        ok = out["status"] == "invalid" and "shell.thickness" in (out.get("reason") or "")
    else:
        ok = out["status"] == "converged" or (out["status"] == "failed" and out.get("reason"))
    return "ok" if ok else "PROBLEM"


def run_check(cases: list[Case], elements: list[str], budget: float, scene_path: str,
              progress=None, edges: dict | None = None) -> list[dict]:
    """Every case with every element; ``edges`` overrides the mesh edge length per element."""
    edges = {**EDGE, **(edges or {})}
    with tempfile.TemporaryDirectory() as tmp:
        return _run_all(cases, elements, budget, scene_path, Path(tmp), progress, edges)


def _run_all(cases, elements, budget, scene_path, tmp: Path, progress, edges) -> list[dict]:
    rows = []
    ctx = _context()
    for c in cases:
        for el in elements:
            row = {"case": c.name, "what": c.what, "element": el, "expect": c.expect}
            if c.skip:
                rows.append({**row, "status": "skipped", "reason": c.skip, "verdict": "skipped"})
                continue
            edge = edges.get(el, DEFAULT_EDGE)
            o = {"shell.element": el, "mesh.edge_length": edge, **c.overrides}
            if c.sliver:
                edge = min(edge, 0.035)  # two rows of cells at least: interior vertices to move
                obj = tmp / f"sliver-{edge}.obj"
                if not obj.exists():
                    write_sliver_obj(obj, edge=edge)
                o.update({"mesh.kind": "file", "mesh.path": str(obj)})
            out = run_isolated(scene_path, o, budget, ctx)
            rows.append({**row, **out, "overrides": o, "verdict": verdict(c, out)})
            if progress:
                progress(rows[-1])
    return rows


def table(rows: list[dict]) -> str:
    head = ["case", "element", "triangles", "DoFs", "status", "Newton it.", "cut-backs",
            "final residual", "tip deflection [m]", "time [s]", "verdict", "diagnostic"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        res, tip = r.get("residual"), r.get("probes", {}).get("tip_deflection")
        cells = [r["case"], r["element"], str(r.get("elements") or ""), str(r.get("dofs") or ""),
                 r["status"], str(r.get("iterations", "")), str(r.get("cutbacks", "")),
                 f"{res:.2e}" if res is not None else "", f"{tip:.4g}" if tip is not None else "",
                 f"{r['elapsed']:.1f}" if "elapsed" in r else "", r["verdict"],
                 (r.get("reason") or "").replace("|", "/")[:110]]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def select(cases: list[Case], names: str | None) -> list[Case]:
    if not names:
        return cases
    want = [n.strip() for n in names.split(",")]
    return [c for c in cases if any(w in c.name for w in want)]


def run(args) -> int:
    from sim.cli import resolve_scene
    from sim.scene import load_scene

    scene_path = str(resolve_scene(BASE))
    elements = args.elements.split(",")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    cases = select(make_cases(load_scene(scene_path)), args.cases)
    rows = run_check(cases, elements, args.budget, scene_path, progress=lambda r: print(
        f"{r['case']:20s} {r['element']:9s} {r['status']:9s} {r['elapsed']:6.1f} s "
        f"{r['verdict']}", file=sys.stderr, flush=True))
    wall = time.perf_counter() - t0
    bad = [r for r in rows if r["verdict"] == "PROBLEM"]
    md = (f"# q3t check\n\nBase: `{BASE}` scene, edge {DEFAULT_EDGE} m "
          f"({', '.join(f'{k} {v} m' for k, v in EDGE.items())}); budget {args.budget:g} s per "
          f"run; {len(rows)} runs in {wall:.0f} s; {len(bad)} problem(s).\n\n"
          + "\n".join(f"- **{c.name}**: {c.what}" for c in cases) + "\n\n" + table(rows))
    (out / "check.md").write_text(md)
    print(md)
    return 1 if bad else 0


def add_parser(sub) -> None:
    c = sub.add_parser("check", help="stability suite of hard cases (child process each)")
    c.add_argument("--elements", default=",".join(ELEMENTS))
    c.add_argument("--budget", type=float, default=60.0, help="wall-clock seconds per run")
    c.add_argument("--cases", help="comma-separated substrings of case names (default: all)")
    c.add_argument("--out", default="runs/check")
    c.set_defaults(func=run)

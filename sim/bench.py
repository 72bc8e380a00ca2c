"""``q3t bench``: per-Newton-iteration cost (assembly, factorisation, solve) at the paper's
Table 1 sizes, and the factorisation comparison of its Fig. 7 on the cantilever (same elements /
same nodes; ``sim.study.factorisation_report``, also ``q3t study --factorisation``).

Medians of ``--repeat`` runs; the machines are noisy, so compare ratios more than seconds.
"""

from __future__ import annotations

import json
import platform
import time
from pathlib import Path

import numpy as np

# (case, element, edge length): the beam is the paper's 70 x 7 cm plate (4,504 triangles), the
# cup a 60 mm disk (about 26,700 triangles); quadratic at half the edge count has the same nodes.
CASES = {
    "beam": {"scene": "cantilever", "edge": {"linear": 0.0046667, "q3t": 0.0046667,
                                              "quadratic": 0.0093333}},
    "cup": {"scene": "cup_blank", "edge": {"linear": 0.00046, "q3t": 0.00046,
                                            "quadratic": 0.00092}},
}
# Fig. 7 levels: the cantilever at 80 to 4,500 triangles; equal edge lengths give equal
# elements, and Q3T at one level has the nodes of quadratic at the next coarser (about 2x edge)
FIG7_LEVELS = [0.035, 0.0175, 0.00875, 0.0046667]
PAPER = {("beam", "linear"): 0.184, ("beam", "q3t"): 0.298, ("beam", "quadratic"): 0.372,
         ("cup", "linear"): 0.812, ("cup", "q3t"): 1.887, ("cup", "quadratic"): 2.525}


def _scene(case: str, element: str, edge: float, extra: dict | None = None):
    from sim.cli import resolve_scene
    from sim.scene import load_scene

    overrides = {"shell.element": element, "mesh.edge_length": edge, **(extra or {})}
    return load_scene(resolve_scene(CASES[case]["scene"]), overrides)


# the beam as an elastoplastic sheet: the same Hencky energy plus the return mapping, at a
# yield stress low enough that the perturbed state yields (plasticity's cost per iteration)
PLASTIC = {"material.model": "plastic", "material.yield_stress": 1e3}
HENCKY = {"material.model": "hencky"}


def measure(case: str, element: str, edge: float, repeat: int, extra=None) -> dict:
    from sim.linsolve import SingularMatrix
    from sim.newton import _solve
    from sim.simulation import Simulation

    t0 = time.perf_counter()
    sim = Simulation.from_scene(_scene(case, element, edge, extra))
    build = time.perf_counter() - t0
    m, P = sim.model, sim.model.problem
    h = float(np.mean(m.shell.thickness))
    # a smooth deflection of a tenth of the thickness: a state Newton meets (random noise
    # compresses fibres locally and makes the exact Hessian indefinite, which no run does)
    X = m.x0
    lo, hi = X.min(0), X.max(0)
    s_ = np.sin(np.pi * (X[:, 0] - lo[0]) / (hi[0] - lo[0]))
    s_ *= np.sin(np.pi * (X[:, 1] - lo[1]) / (hi[1] - lo[1]))
    x = X.copy()
    x[:, 2] += 0.1 * h * s_
    x[m.fixed] = X[m.fixed]
    P.evaluate(x, exact=m.settings.try_exact)  # compile / warm up
    out = {"assembly": [], "factorisation": [], "solve": [], "energy": []}
    for _ in range(repeat):
        t = time.perf_counter()
        # as Newton does: the exact Hessian first (the projected one only when it is indefinite)
        _, _, g, data = P.evaluate(x, exact=m.settings.try_exact)
        t1 = time.perf_counter()
        try:
            P.solver.factor(data)
        except SingularMatrix:  # as Newton: the projected Hessian when the exact one is not PD
            _, _, g, data = P.evaluate(x)
            P.solver.factor(data)
        t2 = time.perf_counter()
        _solve(P, data, g.ravel())
        t3 = time.perf_counter()
        P.energy(x)
        t4 = time.perf_counter()
        out["assembly"].append(t1 - t)
        out["factorisation"].append(t2 - t1)
        out["solve"].append(t3 - t2)
        out["energy"].append(t4 - t3)
    med = {k: float(np.median(v)) for k, v in out.items()}
    # one Newton iteration = energy+gradient+Hessian in one pass (the line search's full step,
    # reused by the next iteration), factorisation, solve; an energy-only evaluation is paid
    # only when the full step is rejected
    med["iteration"] = med["assembly"] + med["factorisation"] + med["solve"]
    c = sim.result()["counts"]
    return {"case": case, "element": element, "vertices": c["vertices"],
            "elements": c["elements"], "nodes": c["nodes"], "dofs": c["dofs"],
            "nnz_upper": int(m.pattern.nnz), "solver": m.built["linear_solver"],
            "build_s": build, **med, "paper_s": PAPER.get((case, element))}


def _print(r: dict) -> None:
    print(f"{r['case']:12s} {r['element']:9s} {r['elements']:6d} el {r['dofs']:7d} dof  iter "
          f"{r['iteration']:.3f} s (assembly {r['assembly']:.3f}, factor "
          f"{r['factorisation']:.3f}, solve {r['solve']:.3f}, energy "
          f"{r['energy']:.3f})  paper {r['paper_s']}", flush=True)


def forming(edge: float, steps: int, element: str = "q3t") -> dict:
    """The first ``steps`` steps of cup_drawing (contact, friction, plasticity) at a given edge:
    seconds per Newton iteration and iterations per step."""
    from sim.cli import resolve_scene
    from sim.scene import load_scene
    from sim.simulation import Simulation

    base = load_scene(resolve_scene("cup_drawing"))
    frac = steps / base.stepping.steps
    sim = Simulation.from_scene(load_scene(resolve_scene("cup_drawing"), {
        "shell.element": element, "mesh.edge_length": edge, "stepping.steps": steps,
        "tools.0.velocity": [v * frac for v in base.tools[0].velocity]}))
    sim.run()
    res = sim.result()
    t = res["timing"]
    return {"case": "cup_forming", "element": element, **res["counts"],
            "converged": res["converged"], "steps": len(res["steps"]),
            "newton_per_step": t["newton_iterations"] / max(1, len(res["steps"])),
            "per_iteration": t["per_iteration"], "assembly": t["assembly"],
            "factorisation": t["factorisation"], "solve": t["solve"],
            "line_search": t["line_search"], "total": t["total"], "paper_s": 1.887}


def run(args) -> int:
    rows = []
    cases = args.cases.split(",")
    elements = args.elements.split(",")
    for case in cases:
        if case == "plastic":
            for label, extra in (("beam_hencky", HENCKY), ("beam_plastic", PLASTIC)):
                r = measure("beam", "q3t", CASES["beam"]["edge"]["q3t"], args.repeat, extra)
                r["case"] = label
                rows.append(r)
                _print(r)
            continue
        if case == "factorisation":
            from sim.cli import resolve_scene
            from sim.study import factorisation_report

            fig7 = factorisation_report(str(resolve_scene("cantilever")), elements, FIG7_LEVELS,
                                        Path(args.out) / "factorisation", args.repeat)
            rows += [{"case": "fig7", **r} for r in fig7]
            continue
        if case == "forming":
            r = forming(CASES["cup"]["edge"]["q3t"], args.forming_steps)
            rows.append(r)
            print(f"cup_forming q3t {r['elements']} el {r['dofs']} dof: "
                  f"{r['per_iteration']:.3f} s per Newton iteration, "
                  f"{r['newton_per_step']:.1f} iterations per step "
                  f"({r['steps']} steps, converged {r['converged']})", flush=True)
            continue
        for el in elements:
            r = measure(case, el, CASES[case]["edge"][el], args.repeat)
            rows.append(r)
            _print(r)
    meta = {"date": time.strftime("%Y-%m-%d"), "machine": platform.processor() or
            platform.machine(), "cpus": __import__("os").cpu_count(), "repeat": args.repeat}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    print(f"wrote {out / 'bench.json'}")
    return 0


def add_parser(sub) -> None:
    b = sub.add_parser("bench", help="per-iteration cost at the paper's Table 1 sizes")
    b.add_argument("--cases", default="beam,cup,factorisation,plastic,forming",
                   help="beam, cup (Table 1 sizes), factorisation (Fig. 7: the cantilever "
                        "at 80-4,500 elements), plastic (elastic vs plastic beam), forming "
                        "(cup_drawing steps at the paper's cup size)")
    b.add_argument("--forming-steps", type=int, default=3)
    b.add_argument("--elements", default="linear,q3t,quadratic")
    b.add_argument("--repeat", type=int, default=5)
    b.add_argument("--out", default="runs/bench")
    b.set_defaults(func=run)

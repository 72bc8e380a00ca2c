"""``q3t bench``: per-Newton-iteration cost (assembly, factorisation, solve) at the paper's
Table 1 sizes, and the factorisation comparison of its Fig. 7 (same elements / same nodes).

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
PAPER = {("beam", "linear"): 0.184, ("beam", "q3t"): 0.298, ("beam", "quadratic"): 0.372,
         ("cup", "linear"): 0.812, ("cup", "q3t"): 1.887, ("cup", "quadratic"): 2.525}


def _scene(case: str, element: str, edge: float):
    from sim.cli import resolve_scene
    from sim.scene import load_scene

    overrides = {"shell.element": element, "mesh.edge_length": edge}
    return load_scene(resolve_scene(CASES[case]["scene"]), overrides)


def measure(case: str, element: str, edge: float, repeat: int) -> dict:
    from sim.newton import _solve
    from sim.simulation import Simulation

    t0 = time.perf_counter()
    sim = Simulation.from_scene(_scene(case, element, edge))
    build = time.perf_counter() - t0
    m, P = sim.model, sim.model.problem
    rng = np.random.default_rng(0)
    h = float(np.mean(m.shell.thickness))
    x = m.shell.rest + 1e-3 * h * rng.standard_normal(m.shell.rest.shape)
    x[m.fixed] = m.shell.rest[m.fixed]
    P.gradient_hessian(x)  # compile / warm up
    out = {"assembly": [], "factorisation": [], "solve": [], "energy": []}
    for _ in range(repeat):
        t = time.perf_counter()
        g, data = P.gradient_hessian(x)
        t1 = time.perf_counter()
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
    # one Newton iteration = gradient+Hessian, factorisation, solve, and typically one energy
    # evaluation in the line search
    med["iteration"] = sum(med.values())
    c = sim.result()["counts"]
    return {"case": case, "element": element, "vertices": c["vertices"],
            "elements": c["elements"], "nodes": c["nodes"], "dofs": c["dofs"],
            "nnz_upper": int(m.pattern.nnz), "solver": m.built["linear_solver"],
            "build_s": build, **med, "paper_s": PAPER.get((case, element))}


def run(args) -> int:
    rows = []
    cases = args.cases.split(",")
    elements = args.elements.split(",")
    for case in cases:
        for el in elements:
            r = measure(case, el, CASES[case]["edge"][el], args.repeat)
            rows.append(r)
            print(f"{case:5s} {el:9s} {r['elements']:6d} el {r['dofs']:7d} dof  iter "
                  f"{r['iteration']:.3f} s (assembly {r['assembly']:.3f}, factor "
                  f"{r['factorisation']:.3f}, solve {r['solve']:.3f}, energy "
                  f"{r['energy']:.3f})  paper {r['paper_s']}", flush=True)
    meta = {"date": time.strftime("%Y-%m-%d"), "machine": platform.processor() or
            platform.machine(), "cpus": __import__("os").cpu_count(), "repeat": args.repeat}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    print(f"wrote {out / 'bench.json'}")
    return 0


def add_parser(sub) -> None:
    b = sub.add_parser("bench", help="per-iteration cost at the paper's Table 1 sizes")
    b.add_argument("--cases", default="beam,cup")
    b.add_argument("--elements", default="linear,q3t,quadratic")
    b.add_argument("--repeat", type=int, default=5)
    b.add_argument("--out", default="runs/bench")
    b.set_defaults(func=run)

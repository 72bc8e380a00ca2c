"""``q3t bench``: per-Newton-iteration cost (assembly, factorisation, solve) at the paper's
Table 1 sizes, and the factorisation comparison of its Fig. 7 on the cantilever (same elements /
same nodes; ``sim.apps.factorisation``, also ``q3t study --factorisation``).

Medians of ``--repeat`` runs; the machines are noisy, so compare ratios more than seconds.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from sim.apps import bench_calculix, calculix
from sim.apps.bench_report import bench_md
from sim.apps.common import BAD_INPUT, OK, load, resolve_scene
from sim.apps.factorisation import factorisation_report
from sim.elements import get_element
from sim.frames import results
from sim.stamp import Stamp, add_results_option, write_results

if TYPE_CHECKING:
    from sim.scene.load import Scene
    from sim.stepping.simulation import Simulation

# Each case: a scene and the in-plane node spacing of every element (the edge lengths follow
# from the registry, ``case_edge``), at the paper's Table 1 sizes. The beam is its 70 x 7 cm plate:
# 150 x 15 cells of linear and Q3T (4,500 triangles), a hair under 0.7 m / 150 so that the
# quadratic's 7.5 cells across round up, to 75 x 8. The cup is a 60 mm disk (about 26,700
# triangles of linear and Q3T).
CASES = {
    "beam": {"scene": "cantilever", "spacing": 0.00466665},
    "cup": {"scene": "cup_blank", "spacing": 0.00046},
}
# Fig. 7 levels: the cantilever at 80 to 4,500 triangles; equal edge lengths give equal
# elements, and Q3T at one level has the nodes of quadratic at the next coarser (about 2x edge)
FIG7_LEVELS = [0.035, 0.0175, 0.00875, 0.0046667]
PAPER = {("beam", "linear"): 0.184, ("beam", "q3t"): 0.298, ("beam", "quadratic"): 0.372,
         ("cup", "linear"): 0.812, ("cup", "q3t"): 1.887, ("cup", "quadratic"): 2.525}


def case_edge(case: str, element: str) -> float:
    """The mesh edge length of ``element`` in ``case``: its nodes at the case's spacing."""
    return get_element(element).edge_for_spacing(CASES[case]["spacing"])


def _scene(case: str, element: str, edge: float, extra: dict | None = None) -> Scene:
    overrides = {"shell.element": element, "mesh.edge_length": edge, **(extra or {})}
    return load(CASES[case]["scene"], overrides)


HENCKY = {"material.model": "hencky"}


def _prepare(case: str, element: str, edge: float,
             extra: dict | None = None) -> tuple[Simulation, np.ndarray, float]:
    """(sim, state, build seconds): the scene at a smooth deflection of a tenth of the
    thickness, a state Newton meets (random noise compresses fibres locally and makes the exact
    Hessian indefinite, which no run does), compiled and warmed up."""
    from sim.stepping.simulation import Simulation

    t0 = time.perf_counter()
    sim = Simulation.from_scene(_scene(case, element, edge, extra))
    build = time.perf_counter() - t0
    m = sim.model
    h = float(np.mean(m.shell.thickness))
    X = m.x0
    lo, hi = X.min(0), X.max(0)
    s_ = np.sin(np.pi * (X[:, 0] - lo[0]) / (hi[0] - lo[0]))
    s_ *= np.sin(np.pi * (X[:, 1] - lo[1]) / (hi[1] - lo[1]))
    x = X.copy()
    x[:, 2] += 0.1 * h * s_
    x[m.fixed] = X[m.fixed]
    _iteration(sim, x)  # compile / warm up
    return sim, x, build


def _iteration(sim: Simulation, x: np.ndarray) -> dict:
    """One Newton iteration as Newton does it, timed: energy + gradient + exact Hessian in one
    pass (the line search's full step, reused by the next iteration), factorisation (with the
    projected Hessian evaluated again if the exact one is not positive definite), one solve;
    plus an energy-only evaluation (paid only when a full step is rejected)."""
    from sim.solve.linsolve import SingularMatrix
    from sim.solve.problem import solve_refined

    m, P = sim.model, sim.model.problem
    t = time.perf_counter()
    _, _, g, data, _ = P.evaluate(x, exact=m.settings.try_exact)
    t1 = time.perf_counter()
    projected = False
    try:
        P.solver.factor(data)
    except SingularMatrix:
        _, _, g, data, _ = P.evaluate(x)
        P.solver.factor(data)
        projected = True
    t2 = time.perf_counter()
    solve_refined(P, data, g.ravel())
    t3 = time.perf_counter()
    P.energy(x)
    t4 = time.perf_counter()
    return {"assembly": t1 - t, "factorisation": t2 - t1, "solve": t3 - t2, "energy": t4 - t3,
            "projected": projected}


def _row(case: str, element: str, sim: Simulation, build: float, times: list[dict]) -> dict:
    m = sim.model
    med = {k: float(np.median([t[k] for t in times]))
           for k in ("assembly", "factorisation", "solve", "energy")}
    med["iteration"] = med["assembly"] + med["factorisation"] + med["solve"]
    c = sim.result()["counts"]
    return {"case": case, "element": element, "vertices": c["vertices"],
            "elements": c["elements"], "nodes": c["nodes"], "dofs": c["dofs"],
            "nnz_upper": int(m.pattern.nnz), "solver": m.built["linear_solver"],
            "build_s": build, **med, "projected_hessian": any(t["projected"] for t in times),
            "paper_s": PAPER.get((case, element))}


def measure(case: str, element: str, edge: float, repeat: int, extra: dict | None = None) -> dict:
    sim, x, build = _prepare(case, element, edge, extra)
    return _row(case, element, sim, build, [_iteration(sim, x) for _ in range(repeat)])


def plastic(repeat: int, element: str = "q3t") -> list[dict]:
    """Plasticity's cost per iteration on the beam at the elastic case's size: a Swift-hardening
    sheet whose yield stress is the median von Mises stress of the deflected state, so about half
    of the quadrature points return to the yield surface and half stay elastic, against the same
    sheet elastic with the plastic model's own energy (Hencky: the 1.5x bound's baseline) and
    with the default Neo-Hookean (closed-form, SVD-free). Runs are interleaved, one iteration of
    each per round, so drifts of a shared machine hit all three alike; ratios are medians of the
    per-round ratios."""
    h = case_edge("beam", element)
    hencky = _prepare("beam", element, h, HENCKY)
    y0 = float(np.median(hencky[0].model.elasticity.von_mises(hencky[1])))
    swift = {"material.model": "plastic", "material.yield_stress": y0,
             "material.hardening": {"law": "swift", "K": 3 * y0, "n": 0.2}}
    cases = {"beam_neo_hookean": _prepare("beam", element, h),
             "beam_hencky": hencky, "beam_plastic": _prepare("beam", element, h, swift)}
    el = cases["beam_plastic"][0].model.elasticity
    fp, ep = el.fp_inv.copy(), el.ep.copy()
    el.commit(cases["beam_plastic"][1])  # which points would flow at this state
    yielding = float(np.mean(el.ep > 0))
    el.fp_inv[:], el.ep[:] = fp, ep
    times = {k: [] for k in cases}
    for _ in range(repeat):
        for k, (sim, x, _) in cases.items():
            times[k].append(_iteration(sim, x))
    rows = [_row(k, element, sim, build, times[k]) for k, (sim, _, build) in cases.items()]
    plastic_row = rows[-1]
    plastic_row["yield_stress"], plastic_row["yielding_fraction"] = y0, yielding
    for k in ("beam_hencky", "beam_neo_hookean"):
        for part, keys in (("iteration", ("assembly", "factorisation", "solve")),
                           ("assembly", ("assembly",))):
            per_round = [sum(tp[p] for p in keys) / sum(tb[p] for p in keys)
                         for tp, tb in zip(times["beam_plastic"], times[k], strict=True)]
            plastic_row[f"{part}_ratio_vs_{k[5:]}"] = float(np.median(per_round))
    return rows


def _print(r: dict) -> None:
    print(f"{r['case']:12s} {r['element']:9s} {r['elements']:6d} el {r['dofs']:7d} dof  iter "
          f"{r['iteration']:.3f} s (assembly {r['assembly']:.3f}, factor "
          f"{r['factorisation']:.3f}, solve {r['solve']:.3f}, energy "
          f"{r['energy']:.3f})  paper {r['paper_s']}", flush=True)


def forming(edge: float, steps: int, until: int, element: str = "q3t") -> dict:
    """cup_drawing as shipped (50 steps over the 25 mm stroke) at a given edge, run to step
    ``until``; the last ``steps`` of them are timed: seconds per Newton iteration and
    iterations per step while the punch nose, the die shoulder and the holder are in contact,
    with friction (its fixed point included) and plastic flow (mid-stroke by default)."""
    from sim.stepping.simulation import Simulation

    sim = Simulation.from_scene(load("cup_drawing", {"shell.element": element,
                                                     "mesh.edge_length": edge}))
    until = min(until, sim.n_steps)
    first = max(0, until - steps)
    while sim.step_index < first:
        sim.step()
    before = dict(vars(sim.timing))
    wall = sim.wall
    while sim.step_index < until:
        sim.step()
    t = {k: v - before[k] for k, v in vars(sim.timing).items()}
    n_it = max(1, t["iterations"])
    rec = sim.records[-1]
    res = sim.result()
    return {"case": "cup_forming", "element": element, **res["counts"],
            "converged": sim.failure is None, "steps": f"{first + 1}-{until}",
            "stroke_mm": -1e3 * rec.probes.get("centre_dz", float("nan")),
            "punch_force_kN": 1e-3 * rec.probes.get("punch_force", float("nan")),
            "newton_per_step": t["iterations"] / max(1, until - first),
            "per_iteration": (t["assembly"] + t["factorisation"] + t["solve"]
                              + t["line_search"]) / n_it,
            "assembly": t["assembly"] / n_it, "factorisation": t["factorisation"] / n_it,
            "solve": t["solve"] / n_it, "line_search": t["line_search"] / n_it,
            "total": sim.wall - wall, "paper_s": 1.887}


FORMING_TIMES = ("per_iteration", "assembly", "factorisation", "solve", "line_search", "total")


def forming_rounds(elements: list[str], edge: float, steps: int, until: int,
                   rounds: int) -> list[dict]:
    """:func:`forming` for each element, ``rounds`` times over, the elements interleaved in
    each round, so that a drift of a shared machine's speed hits them alike: each element's
    times the medians of its runs, and each element's ratios to Q3T's (``*_vs_q3t``) the
    medians of the rounds' ratios."""
    runs = {el: [] for el in elements}
    for _ in range(max(1, rounds)):
        for el in elements:
            runs[el].append(forming(edge, steps, until, el))
    rows = []
    for el, rs in runs.items():
        row = {**rs[0], **{k: float(np.median([r[k] for r in rs])) for k in FORMING_TIMES},
               "runs": len(rs)}
        if el != "q3t" and "q3t" in runs:
            pairs = list(zip(rs, runs["q3t"], strict=True))
            for k in ("per_iteration", "assembly", "line_search"):
                row[f"{k}_vs_q3t"] = float(np.median(
                    [r[k] / q[k] if q[k] else np.nan for r, q in pairs]))
        rows.append(row)
    return rows


KINDS = ("beam", "cup", "factorisation", "plastic", "forming", "calculix")  # --cases names


def _check_input(cases: list[str], elements: list[str], forming_edge: float | None,
                 forming_elements: list[str] = ("q3t",)) -> None:
    """ValueError naming the option, before anything is timed."""
    if forming_edge is not None and not forming_edge > 0:
        raise ValueError(f"--forming-edge must be a positive length (m), got {forming_edge:g}")
    unknown = [c for c in cases if c not in KINDS]
    if unknown:
        raise ValueError(f"--cases: unknown {', '.join(unknown)}; known: {', '.join(KINDS)}")
    for option, names in (("--elements", elements), ("--forming-elements", forming_elements)):
        for el in names:
            try:
                get_element(el)
            except ValueError as exc:
                raise ValueError(f"{option}: {exc}") from None
    if "calculix" in cases:
        alone = [el for el in elements if el not in bench_calculix.COUNTERPART]
        if alone:
            raise ValueError(f"--elements: {', '.join(alone)} has no CalculiX counterpart "
                             f"(--cases calculix takes {', '.join(bench_calculix.COUNTERPART)})")
        if calculix.program() is None:
            raise ValueError(f"--cases calculix: CalculiX's program `{calculix.PROGRAM}` is not "
                             "on PATH (Debian: apt-get install calculix-ccx)")


def _title(cases: list[str]) -> str:
    if cases == ["calculix"]:
        return "The cantilever beside CalculiX (`q3t bench --cases calculix`)"
    return "Cost per Newton iteration (`q3t bench`)"


def run(args: argparse.Namespace) -> int:
    stamp = Stamp.begin(args.command)
    rows = []
    cases = args.cases.split(",")
    elements = args.elements.split(",")
    try:
        _check_input(cases, elements, args.forming_edge, args.forming_elements.split(","))
    except ValueError as exc:
        print(f"q3t bench: {exc}", file=sys.stderr)
        return BAD_INPUT
    for case in cases:
        if case == "plastic":
            for r in plastic(args.repeat):
                rows.append(r)
                _print(r)
            r = rows[-1]
            print(f"plastic: {100 * r['yielding_fraction']:.0f} % of points yielding (Swift, "
                  f"yield {r['yield_stress']:.3g} Pa); per iteration "
                  f"{r['iteration_ratio_vs_hencky']:.2f}x Hencky, "
                  f"{r['iteration_ratio_vs_neo_hookean']:.2f}x Neo-Hookean; evaluation "
                  f"{r['assembly_ratio_vs_hencky']:.2f}x / "
                  f"{r['assembly_ratio_vs_neo_hookean']:.2f}x (bound: 1.5x the elastic "
                  "iteration, Hencky)", flush=True)
            continue
        if case == "factorisation":
            fig7 = factorisation_report(str(resolve_scene("cantilever")), elements, FIG7_LEVELS,
                                        Path(args.out) / "factorisation", args.repeat)
            rows += [{"case": "fig7", **r} for r in fig7]
            continue
        if case == "calculix":
            ccx_rows, material = bench_calculix.measure(
                elements, lambda el: case_edge("beam", el), args.repeat,
                Path(args.out) / "calculix", calculix.program())
            rows += ccx_rows + [{"case": "calculix_material", **r} for r in material]
            for r in ccx_rows:
                print(f"calculix {r['element']:9s} vs {r['ccx_element']:5s} {r['setting']:8s} "
                      f"iterations {r['ours_iterations']} vs {r.get('ccx_iterations')}, wall "
                      f"{r['ours_wall']:.2f} s vs {r.get('ccx_wall', float('nan')):.2f} s, tip "
                      f"{r['ours_tip_mm']:.4f} vs {r.get('ccx_tip_mm', float('nan')):.4f} mm "
                      f"({r['ccx_status']})", flush=True)
            continue
        if case == "forming":
            for r in forming_rounds(args.forming_elements.split(","),
                                    args.forming_edge or case_edge("cup", "q3t"),
                                    args.forming_steps, args.forming_to, args.repeat):
                rows.append(r)
                print(f"cup_forming {r['element']} {r['elements']} el {r['dofs']} dof: "
                      f"{r['per_iteration']:.3f} s per Newton iteration, "
                      f"{r['newton_per_step']:.1f} iterations per step (steps {r['steps']}, "
                      f"{r['stroke_mm']:.1f} mm stroke, punch force {r['punch_force_kN']:.1f} "
                      f"kN, converged {r['converged']})  paper {r['paper_s']}", flush=True)
            continue
        for el in elements:
            r = measure(case, el, case_edge(case, el), args.repeat)
            rows.append(r)
            _print(r)
    meta = {**asdict(stamp), "repeat": args.repeat}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench.json").write_text(results.dumps({"meta": meta, "rows": rows}, nulls=True,
                                                  indent=1))
    print(f"wrote {out / 'bench.json'}")
    if args.results:
        write_results(args.results, _title(cases), bench_md(rows), stamp)
        print(f"wrote {args.results}")
    return OK


def add_parser(sub: argparse._SubParsersAction) -> None:
    b = sub.add_parser("bench", help="per-iteration cost at the paper's Table 1 sizes")
    b.add_argument("--cases", default="beam,cup,factorisation,plastic,forming",
                   help="beam, cup (Table 1 sizes), factorisation (Fig. 7: the cantilever "
                        "at 80-4,500 elements), plastic (elastic vs plastic beam), forming "
                        "(cup_drawing steps at the paper's cup size), calculix (the cantilever "
                        "beside CalculiX's ccx on the same mesh; needs Debian's calculix-ccx)")
    b.add_argument("--forming-steps", type=int, default=3,
                   help="forming: how many steps are timed (the last ones before --forming-to)")
    b.add_argument("--forming-to", type=int, default=25,
                   help="forming: the step (of 50) the cup is run to; 25 = 12.5 mm, mid-stroke")
    b.add_argument("--forming-edge", type=float, default=None,
                   help="forming: the mesh edge length in m (default: the paper's cup size)")
    b.add_argument("--forming-elements", default="q3t",
                   help="forming: the elements timed, comma-separated (each against Q3T's "
                        "iteration when q3t is among them); each run --repeat times, "
                        "interleaved")
    b.add_argument("--elements", default="linear,q3t,quadratic")
    b.add_argument("--repeat", type=int, default=5)
    b.add_argument("--out", default="runs/bench")
    add_results_option(b, "bench.md")
    b.set_defaults(func=run)

"""``q3t bench --cases calculix``: the shipped cantilever (4 load steps, about 10 % tip
deflection) beside CalculiX on the same mesh (sim.apps.calculix): Newton iterations, whole-run
wall time and the tip deflection of both codes, at three pairs of tolerances, medians of the
repeats.

The tolerances (``TOLERANCES``): each code's defaults; then ours at ``MATCHED_RTOL`` against
CalculiX at the same number with its residual in the max-norm (ours implies it) and divided by
sqrt(free DoFs) (it implies ours). Not at our default 1e-8: neither code reaches it here. Ours
ends its steps at its measured round-off floor (about 1.6e-7 N in the 2-norm against a target of
1.3e-10 N at the first step), ccx's largest residual stalls at about 1e-8 of the force level and
it stops ("solution seems to diverge"). 1e-4 is the smallest power of ten above both floors.

Q3T has no CalculiX element: its rows put it beside C3D15 at the same node spacing (the
quadratic rows' run, each element at the bench's beam size, sim.apps.bench.case_edge).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from sim.apps import calculix as cx
from sim.apps.common import load
from sim.apps.study_report import markdown_table

if TYPE_CHECKING:
    from collections.abc import Callable

    from sim.scene.load import Scene

SCENE = "cantilever"
MATCHED_RTOL = 1e-4
# setting -> (ours' solver.rtol, None = the scene's; CalculiX's controls; what the table says)
TOLERANCES = {
    "default": (None, "default", "defaults: ours rtol 1e-8 (ends at its round-off floor), "
                                 "CalculiX R_n 0.005, C_n 0.01"),
    "matched": (MATCHED_RTOL, "matched", f"{MATCHED_RTOL:g}: CalculiX max-norm (ours implies it)"),
    "strict": (MATCHED_RTOL, "strict", f"{MATCHED_RTOL:g}: CalculiX max-norm / sqrt(n) (implies "
                                       "ours)"),
}
# our element -> the element whose mesh CalculiX runs (its counterpart there)
COUNTERPART = {"linear": "linear", "quadratic": "quadratic", "q3t": "quadratic"}
WARM_EDGE = 0.035  # a coarse run of each element before timing: numba's kernels load


def _overrides(element: str, edge: float, rtol: float | None) -> dict:
    return {"shell.element": element, "mesh.edge_length": edge,
            **({"solver.rtol": rtol} if rtol is not None else {})}


def _tip_probe(scene: Scene) -> str:
    return next(p.name for p in scene.probes if p.kind == "displacement")


def ours(element: str, edge: float, rtol: float | None) -> dict:
    """One run of the scene as ``q3t run`` does it, timed from the scene to the last step
    (mesh, model and every step; not Python's start-up)."""
    from sim.stepping.simulation import Simulation

    scene = load(SCENE, _overrides(element, edge, rtol))
    t, cpu = time.perf_counter(), time.process_time()
    sim = Simulation.from_scene(scene)
    sim.run()
    wall, cpu = time.perf_counter() - t, time.process_time() - cpu
    if sim.failure is not None:
        raise RuntimeError(f"q3t run {SCENE} ({element}) failed: {sim.failure.get('reason')}")
    probe = _tip_probe(scene)
    return {"wall": wall, "cpu": cpu, "iterations": sim.timing.iterations,
            "per_step": [r.iterations for r in sim.records],
            "tip": [r.probes[probe] for r in sim.records], "dofs": sim.result()["counts"]["dofs"]}


def deck(element: str, edge: float, setting: str, material: str = "neo_hooke") -> cx.Deck:
    from sim.model.build import build_model

    rtol, controls, _ = TOLERANCES[setting]
    return cx.write_deck(build_model(load(SCENE, _overrides(element, edge, rtol))), controls,
                         material)


def _median(runs: list[dict], key: str) -> float:
    return float(np.median([r[key] for r in runs]))


def _ccx(d: cx.Deck, folder: Path, ccx: str) -> dict:
    try:
        r = cx.run_deck(d, folder, ccx)
    except cx.CalculixError as exc:
        return {"failed": str(exc)}
    return {"wall": r.wall, "cpu": r.cpu, "iterations": r.iterations, "per_step": r.per_step,
            "tip": r.tip, "attempts": r.attempts, "threads": r.threads}


def measure(elements: list[str], edge: Callable[[str], float], repeat: int, out: Path,
            ccx: str) -> tuple[list[dict], list[dict]]:
    """(side-by-side rows, material rows), each element at ``edge(element)``. Runs interleaved
    round by round, ours and ccx's, so a shared machine's drift hits both alike."""
    ours_cfg = {("ours", el, s): (el, edge(el), TOLERANCES[s][0]) for el in elements
                for s in ("default", "matched")}
    decks = {("ccx", cel, s): deck(cel, edge(cel), s)
             for cel in sorted({COUNTERPART[el] for el in elements}) for s in TOLERANCES}
    for el in elements:
        ours(el, WARM_EDGE, None)
    runs: dict[tuple, list[dict]] = {k: [] for k in [*ours_cfg, *decks]}
    for _ in range(repeat):
        for k, (el, h, rtol) in ours_cfg.items():
            runs[k].append(ours(el, h, rtol))
        for k, d in decks.items():
            runs[k].append(_ccx(d, out / f"{k[1]}-{k[2]}", ccx))
    rows = [_row(el, s, runs[("ours", el, "default" if s == "default" else "matched")],
                 decks[("ccx", COUNTERPART[el], s)], runs[("ccx", COUNTERPART[el], s)])
            for el in elements for s in TOLERANCES]
    material = []
    if "linear" in elements:  # once: the tips do not vary between repeats
        elastic = _ccx(deck("linear", edge("linear"), "matched", "elastic"),
                       out / "linear-matched-elastic", ccx)
        neo = runs[("ccx", "linear", "matched")][0]
        material = _material_rows(runs[("ours", "linear", "matched")][0]["tip"][-1],
                                  {"`*HYPERELASTIC, NEO HOOKE`": neo,
                                   "`*ELASTIC` (St. Venant-Kirchhoff)": elastic})
    return rows, material


def _material_rows(ours_tip: float, ccx_runs: dict[str, dict]) -> list[dict]:
    rows = []
    for name, r in ccx_runs.items():
        tip = r["tip"][-1] if "tip" in r else None
        rows.append({"material": name, "ours_tip_mm": 1e3 * ours_tip,
                     "ccx_tip_mm": None if tip is None else 1e3 * tip,
                     "tip_diff": None if tip is None else tip / ours_tip - 1,
                     "ccx_status": r.get("failed", "converged")})
    return rows


def _per_step(runs: list[dict]) -> str:
    return " + ".join(str(n) for n in runs[0]["per_step"])


def _row(element: str, setting: str, mine: list[dict], d: cx.Deck, theirs: list[dict]) -> dict:
    row = {"case": "calculix", "element": element, "ccx_element": d.element,
           "tolerance": TOLERANCES[setting][2], "setting": setting, "dofs": mine[0]["dofs"],
           "ccx_dofs": d.dofs, "ours_iterations": mine[0]["iterations"],
           "ours_per_step": _per_step(mine), "ours_wall": _median(mine, "wall"),
           "ours_cpu": _median(mine, "cpu"),
           "ours_tip_mm": 1e3 * mine[0]["tip"][-1], "repeat": len(mine)}
    failed = [r["failed"] for r in theirs if "failed" in r]
    if failed:
        return {**row, "ccx_status": f"failed: {failed[0]}"}
    tip = theirs[0]["tip"][-1]
    return {**row, "ccx_status": "converged", "ccx_iterations": theirs[0]["iterations"],
            "ccx_per_step": _per_step(theirs), "ccx_wall": _median(theirs, "wall"),
            "ccx_cpu": _median(theirs, "cpu"),
            "ccx_threads": theirs[0]["threads"],
            "ccx_cutbacks": theirs[0]["attempts"] - d.steps,
            "wall_ratio": _median(theirs, "wall") / _median(mine, "wall"),
            "ccx_tip_mm": 1e3 * tip, "tip_diff": mine[0]["tip"][-1] / tip - 1}


COLS = [("element", "ours", ""), ("ccx_element", "CalculiX", ""), ("tolerance", "tolerance", ""),
        ("dofs", "DoFs ours", ",d"), ("ccx_dofs", "DoFs ccx", ",d"),
        ("ours_per_step", "Newton it. ours (per step)", ""), ("ours_iterations", "total", "d"),
        ("ccx_per_step", "iterations ccx (per step)", ""), ("ccx_iterations", "total ", "d"),
        ("ours_wall", "wall ours [s]", ".2f"), ("ccx_wall", "wall ccx [s]", ".2f"),
        ("wall_ratio", "ccx / ours", ".2f"), ("ours_cpu", "CPU ours [s]", ".2f"),
        ("ccx_cpu", "CPU ccx [s]", ".2f"), ("ours_tip_mm", "tip ours [mm]", ".4f"),
        ("ccx_tip_mm", "tip ccx [mm]", ".4f"), ("tip_diff", "ours / ccx - 1", ".2e"),
        ("ccx_status", "ccx", "")]
MATERIAL_COLS = [("material", "CalculiX material (C3D6, tolerance matched)", ""),
                 ("ours_tip_mm", "tip ours, linear [mm]", ".5f"),
                 ("ccx_tip_mm", "tip ccx [mm]", ".5f"), ("tip_diff", "ccx / ours - 1", ".2e"),
                 ("ccx_status", "ccx", "")]


def calculix_md(rows: list[dict], material: list[dict]) -> str:
    threads = {r.get("ccx_threads") for r in rows} - {None}
    text = (
        f"The shipped `{SCENE}` scene (4 load steps to about 10 % tip deflection, large rotation, "
        "strain about 1e-3) on the same mesh in both codes: our linear prism as C3D6, our "
        "quadratic prism as C3D15 (its three face-centre nodes dropped), Q3T beside the same "
        "C3D15 run (no CalculiX counterpart; the same in-plane node spacing), each element at "
        "`q3t bench`'s beam size. CalculiX: Debian's `calculix-ccx` (SPOOLES), NLGEOM, one "
        "`*STEP` of one fixed increment (`*STATIC, DIRECT`) per load step, the load as `*DLOAD, "
        "GRAV`, `*HYPERELASTIC, NEO HOOKE` with C10 = mu/2, D1 = 2/K (the same mu and K as our "
        "compressible Neo-Hookean; the two laws differ at second order in the strain, see the "
        "material table). Lengths in 0.1 mm and stresses in Pa in the deck: ccx zeroes a "
        "residual force below 1e-6 force units, and in newtons that floor would decide its "
        "convergence.\n\n"
        "Tolerances: ours converges when the residual's 2-norm is below rtol times the applied "
        "forces' 2-norm. CalculiX's matched rows give `*CONTROLS, PARAMETERS=FIELD` q_u = that "
        f"force level and R_n = R_p = R_l = {MATCHED_RTOL:g} (R_l = R_n: the residual alone "
        "decides), its largest residual component against it: a condition ours implies. The "
        "strict rows divide by sqrt(free DoFs), a condition that implies ours. Not at our "
        "default 1e-8: ours ends each step at its measured round-off floor far above it, and "
        "ccx's largest residual stalls near 1e-8 of the force level and it stops.\n\n"
        "Wall time: ours from the scene to the last step in one process (mesh, model, every "
        "step; after a warm-up that loads numba's kernels; MKL PARDISO on the machine's "
        "cores); CalculiX the whole `ccx` process (reading the deck, every increment, its "
        f"output), with OMP_NUM_THREADS = the cores (ccx used {', '.join(map(str, threads))} "
        "thread(s)). CPU: user + system seconds of all threads (ours: the process's over the "
        "same span), less moved than wall time by other jobs on a shared machine. Medians of "
        "the repeats; iteration counts and tips do not vary between repeats.\n\n")
    out = "## The cantilever beside CalculiX\n\n" + text + markdown_table(rows, COLS)
    if material:
        out += ("\n## The material law\n\nThe linear prism against C3D6 on the same mesh and "
                "rule, at the matched tolerance, with each of CalculiX's laws that have our "
                "small-strain limit:\n\n" + markdown_table(material, MATERIAL_COLS))
    return out

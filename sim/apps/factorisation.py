"""The factorisation comparison of the paper's Fig. 7: the Hessian at rest factorised again and
again, every element at every mesh level (``q3t study --factorisation`` and ``q3t bench``)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from sim.apps.study_report import FACTOR_COLS, markdown_table, write_factorisation
from sim.apps.tasks import cluster_text, run_tasks

FACTOR_REPEAT = 15  # factorisations per case: medians and minima of >= 10 calls


def factorisation_case(scene_path: str, element: str, edge: float, repeat: int,
                       overrides: dict) -> dict:
    """Times of ``repeat`` calls of ``solver.factor`` on the Hessian at rest (paper Fig. 7)."""
    from sim.scene.load import load_scene
    from sim.stepping.simulation import Simulation

    sim = Simulation.from_scene(load_scene(scene_path, {**overrides, "shell.element": element,
                                                        "mesh.edge_length": edge}))
    P = sim.model.problem
    _, data = P.gradient_hessian(sim.model.shell.rest)
    times = []
    for _ in range(repeat + 1):  # the first includes one-off allocations: dropped
        t0 = time.perf_counter()
        P.solver.factor(data)
        times.append(time.perf_counter() - t0)
    c = sim.result()["counts"]
    t = np.array(times[1:])
    return {"element": element, "edge_length": edge, "elements": c["elements"],
            "nodes": c["nodes"], "dofs": c["dofs"], "nnz_upper": int(P.pattern.nnz),
            "solver": P.solver.name, "factorisation": float(np.median(t)),
            "factorisation_min": float(t.min()), "repeat": repeat, "status": "converged"}


def factorisation_times(scene_path: str, elements: list[str], levels: list[float],
                        repeat: int = FACTOR_REPEAT, overrides: dict | None = None,
                        workers: int = 1, threads: int = 1, scheduler: str | None = None,
                        timeout: float | None = None) -> list[dict]:
    """``factorisation_case`` of every element at every level, on Dask (one case at a time
    by default: the times are the point)."""
    calls = [(factorisation_case, scene_path, el, edge, repeat, dict(overrides or {}))
             for el in elements for edge in levels]
    labels = [{"element": el, "edge_length": edge} for el in elements for edge in levels]
    rows, _ = run_tasks(calls, labels, workers, threads, scheduler, timeout)
    return rows


def factorisation_report(scene_path: str, elements: list[str], levels: list[float], out: Path,
                         repeat: int = FACTOR_REPEAT, overrides: dict | None = None,
                         **cluster: float | str | None) -> list[dict]:
    """Fig. 7: time the factorisations, print the table, write report.md / .json and plots.
    ``q3t bench`` runs this too."""
    rows = factorisation_times(scene_path, elements, levels, repeat, overrides, **cluster)
    print(markdown_table(rows, FACTOR_COLS), flush=True)
    write_factorisation(scene_path, rows, out, cluster_text(cluster.get("workers", 1),
                                                            cluster.get("threads", 1),
                                                            cluster.get("scheduler")))
    return rows

"""Running one case of a scene: in this process (``run_case``), or in a child process with a
wall-clock budget (``run_isolated``), which ``q3t check`` and each task of ``q3t sweep`` use.

A case is a scene file and overrides; its result is a small dict that pickles small (no
arrays), whatever happened: a scene that does not validate, a solver that fails, a case over
its budget, a child that crashes or hangs are each a ``status`` with a ``reason``.
"""

from __future__ import annotations

import json
import math
import multiprocessing as mp
import os
import shutil
import signal
import sys
import threading
import time
from collections.abc import Callable
from multiprocessing.connection import Connection
from multiprocessing.context import ForkServerContext, ForkServerProcess
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from sim.stepping.simulation import Simulation, StepRecord

# what a case needs, imported once by the forkserver its children are forked from
PRELOAD = ["sim.apps.cases", "sim.stepping.simulation", "sim.scene.load"]
# a case with a folder saves its state every this many steps and at its end, as ``q3t run``
# and ``q3t serve`` do by default (``--record-every``)
FRAMES_EVERY = 10


class _OverBudget(Exception):
    """A case that spent its budget (``run_case``), raised between two steps."""


def run_case(scene_path: str, overrides: dict, series: bool = False,
             measure: Callable[[Simulation], dict] | None = None,
             budget: float | None = None, out_dir: str | None = None) -> dict:
    """Run one scene with ``overrides``; a summary that pickles small (no arrays).

    status: ``converged``, ``failed`` (solver diagnostic in ``reason``), ``invalid`` (the scene
    was rejected, message in ``reason``), ``nan`` (converged with a non-finite probe) or
    ``timeout`` (``budget`` seconds of building and stepping spent before the last step: the
    run stops after the step that used it up, so a single step is never cut short).
    ``series``: also every step's time and probes (``history``) and the recorded sections.
    ``measure(sim) -> dict``, when given, adds its numbers as ``measured`` after the run.
    ``out_dir``: the case's folder (``write_case``) is written there once the run has ended.
    """
    from sim.scene.load import load_scene
    from sim.stepping.simulation import Simulation

    out = _invalid_row(overrides, None)
    t0 = time.perf_counter()
    try:
        sim = Simulation.from_scene(load_scene(scene_path, overrides))
    except ValueError as exc:  # SceneError is a ValueError; so are model-building errors
        out["reason"] = str(exc)
        return out
    out["build"] = time.perf_counter() - t0
    starts = sim.tool_poses()  # where the punches' strokes start (case.json)
    def check_budget(sim: Simulation, rec: StepRecord) -> None:
        spent = time.perf_counter() - t0
        if spent > budget and not sim.done:
            raise _OverBudget(f"over its budget of {budget:g} s after step {sim.step_index} "
                              f"of {sim.n_steps} ({spent:.1f} s)")

    if out_dir is not None:  # the time series the service compares at a stroke
        frames = Path(out_dir) / "frames"
        shutil.rmtree(frames, ignore_errors=True)  # a case run again keeps no earlier frames
        sim.save_frames(frames, FRAMES_EVERY)
    over = None
    try:
        ok = sim.run(progress=None if budget is None else check_budget)
    except _OverBudget as exc:
        ok, over = False, str(exc)
    res = sim.result()
    out.update(converged=ok, wall=sim.wall, dofs=res["counts"]["dofs"],
               elements=res["counts"]["elements"], iterations=res["timing"]["newton_iterations"],
               cutbacks=sum(r.cutbacks for r in sim.records))
    if series:  # the loading steps only: a release (springback) stage does not advance time
        recs = [r for r in sim.records if r.step <= sim.stroke_steps]
        out["history"] = {"time": [r.time for r in recs],
                          **{k: [r.probes[k] for r in recs]
                             for k in (recs[0].probes if recs else {})}}
        out["sections"] = sim.sections
    if sim.records:
        out["probes"] = dict(sim.records[-1].probes)
        out["residual"] = float(sim.records[-1].residual)
    # what an engineer reads of the run (sim.frames.summary) and the fields' min / mean / max,
    # final state; a released part's probes also at the end of the stroke (the loaded shape)
    out.update(summary=res["summary"], fields=res["fields"])
    loaded = [r for r in sim.records if r.step == sim.stroke_steps]
    if sim.loaded is not None and loaded:
        out["loaded_probes"] = dict(loaded[-1].probes)
    if measure is not None:
        out["measured"] = measure(sim)
    if over is not None:
        out.update(status="timeout", converged=False, reason=over)
    elif not ok:
        f = sim.failure
        out.update(status="failed", reason=f["reason"], cutbacks=out["cutbacks"] + f["cutbacks"],
                   residual=float(f["residuals"][-1]) if f["residuals"] else None)
    elif all(math.isfinite(v) for v in out["probes"].values()):
        out["status"] = "converged"
    else:
        out.update(status="nan", reason="non-finite probe after a converged run")
    if out_dir is not None:
        write_case(sim, scene_path, out, starts, Path(out_dir))
    return out


def write_case(sim: Simulation, scene_path: str, row: dict, starts: dict[str, np.ndarray],
               folder: Path) -> None:
    """A case's folder, which the service opens as a finished run (server/sweeps.py): the
    scene file as it was (scene.toml), result.json and final.npz (``Simulation.write``), the
    frames saved as it ran (``frames/``, from ``run_case``), and
    case.json: the row's overrides, status and reason, and what the plots need that the step
    records do not say (``sim.frames.punch.plotted`` of the tools' ``starts``). case.json is
    written last: a folder with case.json is complete."""
    from sim.frames import results
    from sim.frames.punch import plotted

    folder.mkdir(parents=True, exist_ok=True)
    (folder / "scene.toml").write_text(Path(scene_path).read_text())
    sim.write(folder)
    case = {"overrides": row["overrides"], "status": row["status"], "reason": row.get("reason"),
            **plotted(sim.model.scene, starts)}
    results.write(folder / "case.json", case)


def _invalid_row(overrides: dict, reason: str | None) -> dict:
    return {"overrides": dict(overrides), "status": "invalid", "converged": False,
            "reason": reason, "probes": {}, "wall": 0.0, "build": 0.0, "dofs": None,
            "elements": None, "iterations": 0, "cutbacks": 0, "residual": None}


def scene_row(scene_path: str, overrides: dict) -> dict | None:
    """The ``invalid`` row of a case whose scene does not validate, else None. Cheap (no
    model is built): a sweep sorts these out before any case starts, so no clock - a case's
    budget, the sweep's --timeout - ever runs for them."""
    from sim.scene.load import load_scene

    try:
        load_scene(scene_path, overrides)
    except ValueError as exc:
        return _invalid_row(overrides, str(exc))
    return None


def force_balance(sim: Simulation) -> dict:
    """Force balance in z and the residual's round-off floor at the final state.

    The elastic forces sum to zero over the nodes (translation invariance), so at equilibrium
    the supports carry exactly what the other terms apply: ``support`` = sum of the total
    gradient's z over the DoFs held in z (the clamp reaction), ``applied`` = sum of the z
    gradient of the loads, inertia and tools over the shell's nodes (the weight, for the
    static cantilever). ``balance`` = |support - applied| over the sum of the magnitudes (a
    punch and a die balance each other: their sum is no scale)."""
    from sim.solve.problem import measure_floor

    m = sim.model
    n = m.shell.n_nodes
    x = sim.x
    g = m.problem.gradient(x)
    support = float(g[:n, 2][m.problem.fixed[:n, 2]].sum())
    applied = scale = abs(support)
    applied = 0.0
    for t in m.problem.terms:
        if t.name != "elasticity":
            gt = np.zeros_like(x)
            t.add_gradient(x, gt)
            applied += (s := float(gt[:n, 2].sum()))
            scale += abs(s)
    free = ~m.problem.fixed
    gf = np.where(free, g, 0.0)
    E = m.problem.energy(x)
    floor = measure_floor(m.problem, x, E, gf, free, abs(E)).force if np.isfinite(E) else None
    return {"support_z": support, "applied_z": applied,
            "balance": abs(support - applied) / scale if scale > 0 else 0.0, "floor": floor}


def _child(conn: Connection, scene_path: str, overrides: dict, out_dir: str | None) -> None:
    # on SIGTERM exit through Python, so numba's process lock is released and not reported as a
    # leaked semaphore; a child stuck in a kernel gets SIGKILL after a grace period
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    try:
        conn.send(run_case(scene_path, overrides, measure=force_balance, out_dir=out_dir))
    except Exception as exc:  # noqa: BLE001 - anything but a diagnosed failure is a crash
        conn.send({"status": "crashed", "reason": f"{type(exc).__name__}: {exc}", "probes": {}})


def run_isolated(scene_path: str, overrides: dict, budget: float,
                 ctx: ForkServerContext | WatchedContext | None = None,
                 out_dir: str | None = None) -> dict:
    """``run_case`` in a child process, with its ``force_balance`` as ``measured``; killed
    after ``budget`` seconds (status ``timeout``). The budget and ``elapsed`` start once the
    child is forked: the first ``start`` also starts the forkserver, whose imports are no
    case's time. ``ctx``: ``isolated_context()`` by default, a ``WatchedContext`` on a Dask
    worker. ``out_dir``: the case's folder (``write_case``)."""
    ctx = ctx or isolated_context()
    parent, child = ctx.Pipe(duplex=False)
    p = ctx.Process(target=_child, args=(child, scene_path, overrides, out_dir),
                    daemon=True)
    p.start()
    t0 = time.perf_counter()
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


def isolated_context() -> ForkServerContext:
    """Children forked from a clean server that has the solver imported (saves ~1 s a case);
    never forked from this process, whose numba/MKL threads may hold locks."""
    ctx = mp.get_context("forkserver")
    ctx.set_forkserver_preload(PRELOAD)
    return ctx


class _WatchedProcess(ForkServerProcess):
    """A case's child that exits once the Dask worker that started it is gone: a worker closed
    with its cluster (a sweep's --timeout) would otherwise leave a hung case running until its
    budget, as an orphan of the forkserver."""

    def __init__(self, *args: Any, **kw: Any):
        super().__init__(*args, **kw)
        self.watch_pid = os.getpid()

    def run(self) -> None:
        def watch() -> None:
            while True:
                time.sleep(1.0)
                try:
                    os.kill(self.watch_pid, 0)
                except ProcessLookupError:
                    os._exit(143)

        threading.Thread(target=watch, daemon=True).start()
        super().run()


class WatchedContext:
    """The ``ctx`` that ``run_isolated`` takes on a Dask worker: ``isolated_context()``, its
    processes watched (``_WatchedProcess``)."""

    def __init__(self) -> None:
        self._ctx = isolated_context()
        self.Pipe = self._ctx.Pipe

    def Process(self, **kw: Any) -> _WatchedProcess:  # noqa: N802 - multiprocessing's name
        return _WatchedProcess(**kw)


_WARM: set[str] = set()  # warm-ups done in this (worker) process


def study_case(scene_path: str, overrides: dict, warmup: dict,
               budget: float | None = None) -> dict:
    """One timed case on a Dask worker: ``run_case`` with its series, after a warm-up run
    (``warmup`` overrides, once per worker process) that loads every kernel the element needs
    from numba's cache. ``budget``: the case's seconds (``run_case``), the warm-up's too."""
    key = json.dumps([scene_path, warmup], sort_keys=True, default=str)
    if key not in _WARM:
        run_case(scene_path, warmup, budget=budget)
        _WARM.add(key)
    return run_case(scene_path, overrides, series=True, budget=budget)

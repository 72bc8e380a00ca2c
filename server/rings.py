"""Split rings cut from finished cup runs (sim.stepping.split_ring), for
/api/runs/{id}/split_ring.

A ring is released twice by Newton, seconds to minutes of work. It is done in a child process
of its own (a ``ProcessPoolExecutor`` of one spawned process, started at the first ring and
kept for the next) that the route awaits, so the event loop goes on meanwhile. Not in a thread
of the server: the server never imports the solver (its page is up in about a second,
server.runs), numba's loops hold the GIL the event loop and the bridge's viewer pushes need,
and a solver that crashes or runs out of memory would take the server with it. Not on a run's
solver process either: that steps the queue's runs and reads commands only between steps, so a
ring would wait for whole runs. One process: rings take turns (a ring uses a core as a run's
solver does; the machine has few). One ring per run at a time: a second request while one is
cut is a 409, and a run is not deleted under a ring being cut from it.
"""

from __future__ import annotations

import asyncio
import math
import multiprocessing as mp
import threading
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

import numpy as np

from server.problems import Conflict, Invalid, Unsolved
from sim.frames import rings

WALL_NOTE = ("a ring is cut from the steep wall of a drawn cup, between two heights above its "
             "bottom")


def cut_ring(folder: str, z1: float, z2: float, cut_angle: float) -> dict:
    """In the child process: the ring between ``z1 < z2`` (m above the cup's bottom), cut at
    ``cut_angle`` (deg), released, split, released again and saved into the run in
    ``folder``. Returns ``{"ring": summary}`` (SI), ``{"invalid": why}`` naming the field, or
    ``{"failed": why}``: the solver's types stay in the child."""
    from sim.stepping.split_ring import SplitRingError, open_formed, split_ring

    path = Path(folder)
    try:
        formed = open_formed(path)
        res = split_ring(formed, z1, z2, math.radians(cut_angle))
    except SplitRingError as exc:
        # the command line's RUN is the request's run_id; the server's folder is no business
        # of the client's
        text = str(exc)
        for where, name in ((path / "final.npz", "run_id: final.npz"), (path, "run_id")):
            text = text.replace(f"RUN: {where}", name)
        return {"invalid": text}
    except RuntimeError as exc:
        return {"failed": str(exc)}
    try:
        rings.save(path, res, formed.ep[res.ring.elements].mean(1))
    except ValueError as exc:  # a number not finite: nothing written
        return {"failed": str(exc)}
    return {"ring": res.summary}


class RingCutter:
    """The child process that cuts rings, and the runs a ring is being cut from."""

    def __init__(self) -> None:
        self._pool: ProcessPoolExecutor | None = None
        self._lock = threading.Lock()
        self.cutting: dict[str, dict] = {}  # run id -> the ring being cut (mm, deg)

    def executor(self) -> ProcessPoolExecutor:
        """The process rings are cut in (started now if need be)."""
        with self._lock:
            if self._pool is None:
                self._pool = ProcessPoolExecutor(1, mp_context=mp.get_context("spawn"))
            return self._pool

    def check_idle(self, run_id: str) -> None:
        """Conflict while a ring is being cut from the run."""
        ring = self.cutting.get(run_id)
        if ring is not None:
            raise Conflict(f"run {run_id!r}: a split ring ({_band(ring)}) is being cut from "
                           "it; wait until it is done")

    async def cut(self, run_id: str, folder: Path, heights_mm: list[float],
                  cut_angle: float) -> dict:
        """The ring's summary (SI), saved into the run; Conflict while another ring is cut
        from the run, Invalid naming the field, Unsolved (naming ``heights``) when a release
        failed."""
        ring = {"heights_mm": list(heights_mm), "cut_angle_deg": cut_angle}
        with self._lock:
            if run_id in self.cutting:
                raise Conflict(f"run {run_id!r}: a split ring ({_band(self.cutting[run_id])}) "
                               "is being cut from it; ask again when it is done")
            self.cutting[run_id] = ring
        try:
            z1, z2 = (1e-3 * z for z in heights_mm)
            job = self.executor().submit(cut_ring, str(folder), z1, z2, cut_angle)
            out = await asyncio.wrap_future(job)
        except BrokenProcessPool:
            with self._lock:
                self._pool = None  # a new process for the next ring
            raise Unsolved(f"heights: {_band(ring)}: the process cutting the ring died (out of "
                             "memory, or killed); nothing was written") from None
        finally:
            with self._lock:
                self.cutting.pop(run_id, None)
        if "invalid" in out:
            raise Invalid(out["invalid"])
        if "failed" in out:
            raise Unsolved(f"heights: {_band(ring)}: {out['failed']}; nothing was written")
        return out["ring"]

    def close(self) -> None:
        """At shutdown: a ring being cut is abandoned (its files are written through
        temporary names: the run keeps what it had)."""
        with self._lock:
            pool, self._pool = self._pool, None
        if pool is None:
            return
        # no public way to end a busy worker before Python 3.14 (terminate_workers)
        procs = list((getattr(pool, "_processes", None) or {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        for p in procs:
            p.terminate()
        for p in procs:
            p.join(5.0)


def _band(ring: dict) -> str:
    z1, z2 = ring["heights_mm"]
    return f"ring {z1:g}-{z2:g} mm, cut at {ring['cut_angle_deg']:g} deg"


def cuttable(state: str, folder: Path) -> tuple[str | None, tuple[float, float] | None]:
    """Why no ring can be cut from a run in ``state`` with its ``folder`` (None: it can be
    tried), and how far its wall reaches (mm above the bottom, sim.frames.rings.wall): whether
    the heights are on the wall and hold a closed ring only the cut says."""
    if state != "finished":
        return f"the run is {state}: {WALL_NOTE} of a finished run", None
    final = folder / "final.npz"
    if not final.is_file():
        return "the run has no final.npz (its final state)", None
    with np.load(final) as z:  # the names only: nothing is read
        names = set(z.files)
    if not {"fp_inv", "ep"} <= names:
        return ("its material is not plastic: the ring opens by the residual stresses of "
                "plastic forming"), None
    wall = rings.wall(folder)
    if wall is None:
        return (f"no steep wall: no element of the formed part is inclined more than "
                f"{rings.WALL:g} deg from the horizontal ({WALL_NOTE})"), None
    return None, (1e3 * wall[0], 1e3 * wall[1])

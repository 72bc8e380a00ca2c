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
cut is a 409, and a run is not deleted under a ring being cut from it, nor a ring cut from a
run being deleted.

The child says what it is doing as it goes (its stage, and each Newton iterate of a release):
messages on a queue, shaped as a run's solver sends its events (server.worker), which a thread
of the server's reads onto the ring being cut, for GET /api/runs/{id}/split_ring to list while
the POST waits.
"""

from __future__ import annotations

import asyncio
import itertools
import math
import multiprocessing as mp
import queue
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import lru_cache
from multiprocessing.queues import Queue
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from server.problems import Conflict, Invalid, NotFound, Unsolved
from sim.frames import rings

if TYPE_CHECKING:
    from sim.stepping.split_ring import Report

WALL_NOTE = ("a ring is cut from the steep wall of a drawn cup, between two heights above its "
             "bottom")
# the ring's stages before and after the solver's (sim.stepping.split_ring.STAGES), in words
READ = "reading the cup's final state"
SAVE = "saving the ring into the run"
HEAR_S = 1.0  # s: how often the reader of a process's reports looks whether it still should

_reports: Queue | None = None  # in the child: where it reports (None: nobody listens)


def _report_to(reports: Queue) -> None:
    """In the child, as it starts: its reports go to ``reports``."""
    global _reports
    _reports = reports


def _reporter(run_id: str, cut: int, words: dict[str, str]) -> Callable[[Report], None]:
    """In the child: reports of the solver's kind (sim.stepping.split_ring.Report) as the
    server's messages about the cut numbered ``cut`` from the run ``run_id``, each stage in
    ``words``."""
    def tell(r: Report) -> None:
        newton = None if r.iteration is None else {
            "iteration": r.iteration, "residual_N": r.residual, "target_N": r.target}
        if _reports is not None:  # looked up at each report: a test may hold the child here
            _reports.put({"kind": "ring", "run": run_id, "cut": cut, "stage": words[r.stage],
                          "newton": newton})
    return tell


def cut_ring(run_id: str, cut: int, folder: str, z1: float, z2: float,
             cut_angle: float) -> dict:
    """In the child process: the ring between ``z1 < z2`` (m above the cup's bottom), cut at
    ``cut_angle`` (deg), released, split, released again and saved into the run ``run_id`` in
    ``folder``, each stage reported as it starts (as the cut numbered ``cut``). Returns
    ``{"ring": summary}`` (SI), ``{"invalid": why}`` naming the field, or ``{"failed": why}``:
    the solver's types stay in the child. An OSError (the folder gone) reaches the parent as
    itself."""
    from sim.stepping.split_ring import STAGES, Report, SplitRingError, open_formed, split_ring

    tell = _reporter(run_id, cut, {"read": READ, **STAGES, "save": SAVE})
    path = Path(folder)
    try:
        tell(Report("read"))
        formed = open_formed(path)
        res = split_ring(formed, z1, z2, math.radians(cut_angle), tell)
    except SplitRingError as exc:
        return {"invalid": _as_run(str(exc), run_id, path)}
    except RuntimeError as exc:
        return {"failed": str(exc)}
    try:
        tell(Report("save"))
        rings.save(path, res, formed.ep[res.ring.elements].mean(1))
    except ValueError as exc:  # a number not finite: nothing written
        return {"failed": str(exc)}
    return {"ring": res.summary}


def _as_run(text: str, run_id: str, folder: Path) -> str:
    """The command line's RUN (a folder) as the request's ``run_id``: the server's folder is no
    business of the client's."""
    for where, name in ((folder / "final.npz", f"run_id: {run_id}: final.npz"),
                        (folder, f"run_id: {run_id}")):
        text = text.replace(f"RUN: {where}", name)
    return text


@dataclass
class Cut:
    """A ring being cut from a run: what was asked (mm, deg), its number (the child's reports
    name it: a report of the run's last ring, come late, is not this one's), when it was
    asked for (time.monotonic) and what the child last said it is doing."""

    heights_mm: list[float]
    cut_angle_deg: float
    number: int
    stage: str
    newton: dict | None = None  # in a release: its last iterate
    asked: float = field(default_factory=time.monotonic)

    def shown(self, now: float) -> dict:
        """As the API lists it: the ring, its stage and the seconds since it was asked for."""
        return {"heights_mm": list(self.heights_mm), "cut_angle_deg": self.cut_angle_deg,
                "stage": self.stage, "newton": dict(self.newton) if self.newton else None,
                "elapsed_s": max(now - self.asked, 0.0)}


class RingCutter:
    """The child process that cuts rings, and the runs a ring is being cut from or that are
    being deleted: both marked under one lock, so that no ring is cut from a folder being
    removed."""

    def __init__(self) -> None:
        self._pool: ProcessPoolExecutor | None = None
        self._reports: Queue | None = None  # where the pool's process reports
        self._lock = threading.Lock()
        self.cutting: dict[str, Cut] = {}  # run id -> the ring being cut
        self._deleting: set[str] = set()
        self._numbers = itertools.count(1)

    def executor(self) -> ProcessPoolExecutor:
        """The process rings are cut in (started now if need be), and a thread that reads its
        reports."""
        with self._lock:
            if self._pool is None:
                ctx = mp.get_context("spawn")
                self._reports = ctx.Queue()
                self._pool = ProcessPoolExecutor(1, mp_context=ctx, initializer=_report_to,
                                                 initargs=(self._reports,))
                threading.Thread(target=self._hear, args=(self._reports,), daemon=True,
                                 name="q3t-ring-reports").start()
            return self._pool

    def progress(self, run_id: str) -> dict | None:
        """The ring being cut from the run as the API lists it (Cut.shown); None: none is."""
        with self._lock:
            ring = self.cutting.get(run_id)
            return ring.shown(time.monotonic()) if ring else None

    def _hear(self, reports: Queue) -> None:
        """In a thread: the child's reports onto the rings they are of, for as long as the
        process is this cutter's. A report is a few hundred bytes, written to the pipe at once:
        a child killed mid-report leaves no half of one to wait for."""
        while self._reports is reports:
            try:
                msg = reports.get(timeout=HEAR_S)
            except queue.Empty:
                continue
            except (EOFError, OSError, ValueError):  # the queue closed under it
                return
            self._heard(msg)

    def _heard(self, msg: dict) -> None:
        """A child's report (cut_ring's): the stage of the ring it names, if that one is
        still being cut."""
        with self._lock:
            ring = self.cutting.get(msg["run"])
            if ring is not None and ring.number == msg["cut"]:
                ring.stage, ring.newton = msg["stage"], msg["newton"]

    @contextmanager
    def deleting(self, run_id: str) -> Iterator[None]:
        """Around deleting a run: Conflict while a ring is being cut from it, and a ring asked
        for meanwhile is refused (Conflict), so the check and the deletion are one step for
        the rings."""
        with self._lock:
            ring = self.cutting.get(run_id)
            if ring is not None:
                raise Conflict(f"run {run_id!r}: a split ring ({_band(ring)}) is being cut "
                               "from it; wait until it is done")
            self._deleting.add(run_id)
        try:
            yield
        finally:
            with self._lock:
                self._deleting.discard(run_id)

    async def cut(self, run_id: str, folder: Path, heights_mm: list[float], cut_angle: float,
                  check: Callable[[], None]) -> dict:
        """The ring's summary (SI), saved into the run; Conflict while another ring is cut
        from the run or the run is being deleted, Invalid naming the field, Unsolved (naming
        ``heights``) when a release failed, NotFound naming ``run_id`` when its folder went
        away. ``check`` (run in a thread once the ring is marked as being cut, so that the
        run cannot be deleted from then on) raises when no ring can be cut from the run."""
        with self._lock:
            if run_id in self._deleting:
                raise Conflict(f"run {run_id!r} is being deleted")
            if run_id in self.cutting:
                raise Conflict(f"run {run_id!r}: a split ring ({_band(self.cutting[run_id])}) "
                               "is being cut from it; ask again when it is done")
            ring = self.cutting[run_id] = Cut(list(heights_mm), cut_angle,
                                              next(self._numbers), self._waiting())
        try:
            await asyncio.to_thread(check)
            out = await self._solve(run_id, folder, ring)
        except OSError:
            if folder.is_dir():
                raise  # not a folder gone: the server's trouble (a 500)
            raise _gone(run_id) from None
        finally:
            with self._lock:
                self.cutting.pop(run_id, None)
        if "ring" not in out and not folder.is_dir():
            raise _gone(run_id)
        if "invalid" in out:
            raise Invalid(out["invalid"])
        if "failed" in out:
            raise Unsolved(f"heights: {_band(ring)}: {out['failed']}; nothing was written")
        return out["ring"]

    def _waiting(self) -> str:
        """What a ring asked for now waits for, in words (under the lock)."""
        if self.cutting:
            return "waiting for another run's ring to be cut"
        return "starting the process that cuts rings" if self._pool is None else \
            "waiting for the process that cuts rings"

    async def _solve(self, run_id: str, folder: Path, ring: Cut) -> dict:
        """The child's answer for ``ring`` (cut_ring's); Unsolved when the child died."""
        z1, z2 = (1e-3 * z for z in ring.heights_mm)
        pool = self.executor()
        try:
            job = pool.submit(cut_ring, run_id, ring.number, str(folder), z1, z2,
                              ring.cut_angle_deg)
            return await asyncio.wrap_future(job)
        except BrokenProcessPool:
            with self._lock:
                if self._pool is pool:  # not one another request started meanwhile
                    # a new process for the next ring; the reader of this one's reports ends
                    self._pool = self._reports = None
            pool.shutdown(wait=False)
            raise Unsolved(f"heights: {_band(ring)}: the process cutting the ring died (out of "
                           "memory, or killed); nothing was written") from None

    def close(self) -> None:
        """At shutdown: a ring being cut is abandoned (its files are written through
        temporary names: the run keeps what it had)."""
        with self._lock:
            pool, self._pool, self._reports = self._pool, None, None
        if pool is None:
            return
        # no public way to end a busy worker before Python 3.14 (terminate_workers)
        procs = list((getattr(pool, "_processes", None) or {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        for p in procs:
            p.terminate()
        for p in procs:
            p.join(5.0)


def _gone(run_id: str) -> NotFound:
    return NotFound(f"run_id: {run_id}: its folder is gone (deleted outside the service); no "
                    "ring was saved")


def _band(ring: Cut) -> str:
    z1, z2 = ring.heights_mm
    return f"ring {z1:g}-{z2:g} mm, cut at {ring.cut_angle_deg:g} deg"


def cuttable(state: str, folder: Path) -> tuple[str | None, tuple[float, float] | None]:
    """Why no ring can be cut from a run in ``state`` with its ``folder`` (None: it can be
    tried), and how far its wall reaches (mm above the bottom, sim.frames.rings.wall): whether
    the heights are on the wall and hold a closed ring only the cut says. OSError when the
    folder goes meanwhile."""
    if state != "finished":
        return f"the run is {state}: {WALL_NOTE} of a finished run", None
    final = folder / "final.npz"
    try:
        st = final.stat()
    except FileNotFoundError:
        return "the run has no final.npz (its final state)", None
    return _final_facts(str(final), st.st_mtime_ns, st.st_size)


@lru_cache(maxsize=64)
def _final_facts(final: str, mtime_ns: int, size: int) -> tuple[str | None,
                                                                 tuple[float, float] | None]:
    """cuttable's answer for a final.npz, read once per version of the file (by its
    modification time and size): the page asks again every few seconds."""
    with np.load(final) as z:  # the names only: nothing is read
        names = set(z.files)
    if not {"fp_inv", "ep"} <= names:
        return ("its material is not plastic: the ring opens by the residual stresses of "
                "plastic forming"), None
    wall = rings.wall(Path(final).parent)
    if wall is None:
        return (f"no steep wall: no element of the formed part is inclined more than "
                f"{rings.WALL:g} deg from the horizontal ({WALL_NOTE})"), None
    return None, (1e3 * wall[0], 1e3 * wall[1])

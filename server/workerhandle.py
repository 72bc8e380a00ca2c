"""The server's side of a solver process: spawn, send commands, notice death, restart; and
the slot it fills (``q3t serve --solvers N``: N slots, each with one process and its run)."""

from __future__ import annotations

import itertools
import multiprocessing as mp
from collections.abc import Callable
from dataclasses import dataclass

from server.worker import worker_main

# the process's entry point: (commands, events, frames, record_every, step_delay) -> None
WorkerTarget = Callable[..., None]
_ids = itertools.count(1)


class WorkerHandle:
    def __init__(self, frame_queue: int, record_every: int, step_delay: float,
                 target: WorkerTarget = worker_main):
        """``target``: the process's entry point (``worker_main``; the benchmark passes a
        frame generator with the same signature)."""
        ctx = mp.get_context("spawn")
        self.commands, self.events = ctx.Queue(), ctx.Queue()
        self.frames = ctx.Queue(maxsize=max(1, frame_queue))
        self.process = ctx.Process(target=target, name="q3t-solver", daemon=True,
                                   args=(self.commands, self.events, self.frames,
                                         record_every, step_delay))
        self.process.start()

    @property
    def pid(self) -> int | None:
        return self.process.pid

    def alive(self) -> bool:
        return self.process.is_alive()

    def send(self, cmd: str, **kw: object) -> int:
        rid = next(_ids)
        self.commands.put({"id": rid, "cmd": cmd, **kw})
        return rid

    def close(self, timeout: float = 3.0) -> bool:
        """Ask the process to exit, kill it if it does not. Returns whether it exited itself."""
        clean = True
        if self.alive():
            self.send("shutdown")
            self.process.join(timeout)
        if self.alive():
            clean = False
            self.process.kill()
            self.process.join(1.0)
        for q in (self.commands, self.events, self.frames):
            q.cancel_join_thread()
            q.close()
        return clean


@dataclass
class Slot:
    """One solver process and the run it steps (None: free for the next queued run). Each
    has its own queues: a process killed while it writes to a queue may leave that queue's
    lock held, which must stall no other process."""

    worker: WorkerHandle
    run: str | None = None

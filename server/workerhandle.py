"""The server's side of a solver process: spawn, send commands, notice death, restart; the
slot it fills (``q3t serve --solvers N``: N slots, each with one process and its run); and the
one place that chooses where the solvers run: local processes, or the workers of a Dask
cluster (``--scheduler``, ``server.cluster``), whose handles have the same interface."""

from __future__ import annotations

import multiprocessing as mp
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

from server.worker import request_id, worker_main

if TYPE_CHECKING:
    from server.cluster import DaskWorkerHandle
    from server.settings import Settings

# the process's entry point: (commands, events, frames, record_every, step_delay) -> None
WorkerTarget = Callable[..., None]
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
        rid = request_id()
        self.commands.put({"id": rid, "cmd": cmd, **kw})
        return rid

    def kill(self) -> str:
        """End the process at once; says so (for the reason of the run it had)."""
        self.process.kill()
        return "its solver process was ended"

    def join(self, timeout: float) -> None:
        self.process.join(timeout)

    def death(self) -> str:
        """Why it is not alive, for the reason of the run it had."""
        code = self.process.exitcode
        why = f"killed by signal {-code}" if code and code < 0 else f"exit code {code}"
        return f"solver process died ({why})"

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


class LocalSolvers:
    """Solver processes on this machine (the default)."""

    def __init__(self, settings: Settings, target: WorkerTarget):
        self.settings, self.target = settings, target

    def new(self) -> WorkerHandle:
        s = self.settings
        return WorkerHandle(s.frame_queue, s.record_every, s.step_delay, self.target)

    def close(self) -> None:
        pass


class Solvers(Protocol):
    def new(self) -> WorkerHandle | DaskWorkerHandle: ...
    def close(self) -> None: ...


def solvers(settings: Settings, target: WorkerTarget = worker_main) -> Solvers:
    """Where the solvers run: on the Dask cluster of ``settings.scheduler`` (``target`` is then
    always the solver's loop), else in local processes running ``target``."""
    if settings.scheduler:
        from server.cluster import DaskSolvers  # imports distributed: only when asked for

        return DaskSolvers(settings)
    return LocalSolvers(settings, target)


@dataclass
class Slot:
    """One solver process and the run it steps (None: free for the next queued run). Each
    has its own queues: a process killed while it writes to a queue may leave that queue's
    lock held, which must stall no other process."""

    worker: WorkerHandle | DaskWorkerHandle
    run: str | None = None

"""The server's side of the solver process: spawn, send commands, notice death, restart."""

from __future__ import annotations

import itertools
import multiprocessing as mp

from server.worker import worker_main

_ids = itertools.count(1)


class WorkerHandle:
    def __init__(self, frame_queue: int, keyframe_every: int, step_delay: float):
        ctx = mp.get_context("spawn")
        self.commands, self.events = ctx.Queue(), ctx.Queue()
        self.frames = ctx.Queue(maxsize=frame_queue)
        self.process = ctx.Process(target=worker_main, name="q3t-solver", daemon=True,
                                   args=(self.commands, self.events, self.frames,
                                         keyframe_every, step_delay))
        self.process.start()

    @property
    def pid(self) -> int | None:
        return self.process.pid

    def alive(self) -> bool:
        return self.process.is_alive()

    def send(self, cmd: str, **kw) -> int:
        rid = next(_ids)
        self.commands.put({"id": rid, "cmd": cmd, **kw})
        return rid

    def close(self, timeout: float = 3.0) -> None:
        if self.alive():
            self.send("shutdown")
            self.process.join(timeout)
        if self.alive():
            self.process.kill()
            self.process.join(1.0)
        for q in (self.commands, self.events, self.frames):
            q.cancel_join_thread()
            q.close()

"""The solver on a Dask worker (``q3t serve --scheduler``): a Dask actor that runs worker.py's
loop (``server.worker.serve``) in a thread of its own, over local queues, and the server's
handle (``server.cluster``) calls it to send commands and pull events.

A run writes its files (result.json, final.npz, run.rrd, the frames) into a folder of the
worker's own (its ``local_directory``): no file system is shared with the server. When the run
ends, each file goes up the events as a ``file`` event, before the state that ends the run, so
the server has them when it books that state; then the folder is removed.

This module is imported on the workers: it must not import the server's web stack.
"""

from __future__ import annotations

import asyncio
import os
import queue
import shutil
import threading
import time
from collections.abc import Iterator
from pathlib import Path

from server.worker import serve

ENDED = ("finished", "stopped", "failed")  # a state that ends the run: its files go up first
PULL_EVENTS = 500  # at most this many events in one pull (a file counts as many)


def run_files(folder: Path) -> Iterator[tuple[str, bytes]]:
    """Every file under ``folder``: (path relative to it, with '/', its bytes), read one at a
    time."""
    for p in sorted(folder.rglob("*")):
        if p.is_file():
            yield p.relative_to(folder).as_posix(), p.read_bytes()


class Shipping:
    """The events channel of a solver on a worker: a run's ending state is preceded by its
    files (``file`` events). A file that cannot be read fails the run, naming it."""

    def __init__(self, events: queue.Queue):
        self.events = events
        self.folders: dict[str, Path] = {}  # run id -> the worker's folder of its files

    def put(self, msg: dict) -> None:
        if msg.get("kind") == "state" and msg.get("state") in ENDED \
                and msg.get("run") in self.folders:
            msg = self._ship(msg)
        self.events.put(msg)

    def _ship(self, msg: dict) -> dict:
        folder = self.folders.pop(msg["run"])
        try:
            for name, data in run_files(folder):
                self.events.put({"kind": "file", "run": msg["run"], "name": name,
                                 "data": data})
        except OSError as exc:
            reason = f"{msg.get('reason') or msg['state']}; sending its files back failed: {exc}"
            msg = {**msg, "state": "failed", "reason": reason}
        shutil.rmtree(folder, ignore_errors=True)
        return msg


class SolverActor:
    """One solver on a Dask worker. ``start`` starts its loop; ``send`` gives it commands;
    ``pull`` takes what it sent. The loop ends on ``shutdown``, or once the server lets go of
    the actor (its client released it, or is gone)."""

    def __init__(self, frame_queue: int, record_every: int, step_delay: float):
        from distributed import get_worker

        self.worker = get_worker()
        self.commands: queue.Queue = queue.Queue()
        self.events = Shipping(queue.Queue())
        self.frames: queue.Queue = queue.Queue(maxsize=max(1, frame_queue))
        self.args = (record_every, step_delay)
        self.thread: threading.Thread | None = None
        self.key: str | None = None
        self.scratch = Path(self.worker.local_directory) / "q3t-runs"

    def is_alive(self) -> bool:
        """The server still holds this actor (the loop's owner)."""
        return self.worker.state.actors.get(self.key) is self

    async def start(self) -> dict:
        """Start the loop (once); where it runs: the worker's address and process id."""
        if self.thread is None:
            self.key = next(k for k, v in self.worker.state.actors.items() if v is self)
            self.thread = threading.Thread(
                target=serve, name="q3t-solver", daemon=True,
                args=(self.commands, self.events, self.frames, *self.args, self))
            self.thread.start()
        return {"address": self.worker.address, "pid": os.getpid()}

    async def send(self, msgs: list[dict]) -> None:
        """Commands, in order. A start writes the run's files into this worker's folder."""
        for msg in msgs:
            if msg["cmd"] == "start":
                folder = self.scratch / msg["run"]
                folder.mkdir(parents=True, exist_ok=True)
                self.events.folders[msg["run"]] = folder
                msg = {**msg, "out": str(folder)}
            self.commands.put(msg)

    async def pull(self, wait: float) -> dict:
        """What the solver sent since the last pull (``events`` and ``frames``), waiting up
        to ``wait`` s for something; ``done``: the loop has ended (after these)."""
        deadline = time.monotonic() + wait
        while True:
            ended = not self.thread.is_alive()  # before the take: all it sent is queued
            events = _take(self.events.events, PULL_EVENTS)
            frames = _take(self.frames, self.frames.maxsize)
            done = ended and self.events.events.empty() and self.frames.empty()
            if events or frames or done or time.monotonic() >= deadline:
                return {"events": events, "frames": frames, "done": done}
            await asyncio.sleep(0.01)  # on the worker's event loop: never block it


def _take(q: queue.Queue, limit: int) -> list:
    """At most ``limit`` items of ``q`` (fewer after a file: one file per pull keeps each
    message to the server about the size of that file)."""
    out: list = []
    while len(out) < limit:
        try:
            item = q.get_nowait()
        except queue.Empty:
            break
        out.append(item)
        if item.get("kind") == "file":
            break
    return out

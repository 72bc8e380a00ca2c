"""Solvers on the workers of an existing Dask cluster (``q3t serve --scheduler ADDRESS``).

Each slot's solver is a Dask actor (``server.solveractor.SolverActor``) on a worker, running
worker.py's loop. Its handle here has the interface of a local ``WorkerHandle`` (``send``,
``events``, ``frames``, ``alive``, ``close``...), so the run manager and the bridge do not know
where a solver runs. Why an actor, not Dask queues: its calls go from the server to the worker
directly (``direct_to_workers``), so frames do not pass through the scheduler; a lost worker
shows at once as a call that fails; and a queue's ``get`` with a timeout logs an error on the
scheduler each time it times out (distributed 2026.8), which a poll does many times a second.
Dask's pub/sub is gone from distributed 2026.8.

A pump thread per handle makes the actor, forwards the commands in order and pulls what the
solver sent into local queues, which the bridge reads as it reads a local solver's. A run's
files come up as ``file`` events before its ending state (``server.solveractor.Shipping``) and
are written here into the run's folder, atomically: no file system is shared with the workers.
A worker lost mid-run fails that run (the run manager's ``worker_died``, as for a local process);
its files were on that worker and are lost with it, except the step records the server has.
"""

from __future__ import annotations

import collections
import os
import queue
import threading
from pathlib import Path
from typing import TYPE_CHECKING

from server.solveractor import ENDED, SolverActor
from server.worker import request_id

if TYPE_CHECKING:  # imports distributed
    from distributed import Client, Future

    from server.settings import Settings

PULL_WAIT = 0.05  # s the actor waits for something to send: the commands' latency at most
ANSWER_S = 120.0  # s an actor may take to answer a call; then its worker counts as lost
# s a handle that could not make its solver waits before it says so: the run manager replaces
# it at once, and the cause (the scheduler gone) usually lasts
RETRY_S = 5.0


class SchedulerError(RuntimeError):
    """The scheduler cannot be reached, or its workers cannot run the solver."""


def connect(address: str, timeout: float, default: bool = False) -> Client:
    """A client of the scheduler at ``address`` whose workers can import the solver; else
    SchedulerError naming the address and why, within about ``timeout`` s. ``default``: the
    process's default client, which actor handles call through (distributed 2026.8 binds them
    to ``get_client()``)."""
    from distributed import Client

    try:  # direct_to_workers: actor calls go to the worker, not proxied by the scheduler
        client = Client(address, timeout=timeout, set_as_default=default,
                        direct_to_workers=True)
    except Exception as exc:  # OSError: unreachable; ValueError: not an address; and others
        raise SchedulerError(f"--scheduler {address}: no Dask scheduler answered within "
                             f"{timeout:g} s ({type(exc).__name__}: {exc})") from None
    try:
        client.run(_probe)  # on every worker; fails when one cannot import this module
    except Exception as exc:
        client.close()
        raise SchedulerError(f"--scheduler {address}: a worker cannot run q3t's solver "
                             f"({type(exc).__name__}: {exc}); install q3t-forming, the same "
                             "version as the server, in the workers' environment") from None
    workers = list(client.scheduler_info(n_workers=-1)["workers"])
    try:
        client.sync(_reach, workers, timeout, client.connection_args)
    except Exception as exc:
        client.close()
        raise SchedulerError(f"--scheduler {address}: the server cannot reach a worker "
                             f"directly ({type(exc).__name__}: {exc}); the solvers' frames go "
                             "from the workers to the server: run it where it can reach "
                             "them") from None
    return client


async def _reach(workers: list[str], timeout: float, connection_args: dict) -> None:
    from distributed.comm import connect

    for address in workers:
        comm = await connect(address, timeout=timeout, **connection_args)
        await comm.close()


def _probe() -> None:
    """Runs on each worker at start-up: unpickling it imports this module, and the solver's."""
    import server.solveractor  # noqa: F401


class DaskSolvers:
    """The cluster's side of the run manager: makes a handle per slot, placing each solver on
    the worker with the fewest of them per thread."""

    def __init__(self, settings: Settings):
        self.settings = settings
        self.client = connect(settings.scheduler, settings.scheduler_timeout, default=True)
        self.lock = threading.Lock()
        self.placed: collections.Counter[str] = collections.Counter()

    def new(self) -> DaskWorkerHandle:
        s = self.settings
        return DaskWorkerHandle(self, s.frame_queue, s.record_every, s.step_delay)

    def submit(self, args: tuple) -> tuple[Future, str | None]:
        """A new solver actor, and the worker it was meant for (a preference: another worker
        takes it if that one has gone)."""
        if self.client.status != "running":  # it gave up reconnecting: for good
            raise SchedulerError(f"the Dask scheduler {self.settings.scheduler} is gone (its "
                                 f"client is {self.client.status}); restart the server once "
                                 "it is back")
        with self.lock:
            workers = self.client.scheduler_info(n_workers=-1)["workers"]
            address = min(workers, default=None,
                          key=lambda a: self.placed[a] / max(1, workers[a]["nthreads"]))
            if address is not None:
                self.placed[address] += 1
        future = self.client.submit(SolverActor, *args, actor=True, pure=False,
                                    workers=[address] if address else None,
                                    allow_other_workers=True)
        return future, address

    def moved(self, meant: str | None, address: str | None) -> None:
        with self.lock:
            if meant is not None:
                self.placed[meant] -= 1
            if address is not None:
                self.placed[address] += 1

    def close(self) -> None:
        self.client.close()


class DaskWorkerHandle:
    """A solver on a Dask worker, with a local ``WorkerHandle``'s interface."""

    def __init__(self, pool: DaskSolvers, frame_queue: int, record_every: int,
                 step_delay: float):
        self.pool, self.args = pool, (frame_queue, record_every, step_delay)
        self.events: queue.Queue = queue.Queue()
        self.frames: queue.Queue = queue.Queue(maxsize=max(1, frame_queue))
        self.commands: queue.Queue = queue.Queue()  # to forward, in order
        self.outs: dict[str, Path] = {}  # run id -> the server's folder of its files
        self.unwritten: dict[str, str] = {}  # run id -> a file of it that could not be written
        self.address: str | None = None
        self.pid: int | None = None
        self.lost: str | None = None  # why the worker counts as lost
        self.ended = threading.Event()  # the solver's loop has ended (a shutdown)
        self.let_go = threading.Event()  # the server no longer wants this solver
        self.thread = threading.Thread(target=self._pump, name="q3t-dask-pump", daemon=True)
        self.thread.start()

    def alive(self) -> bool:
        return self.lost is None and not self.ended.is_set() and not self.let_go.is_set()

    def send(self, cmd: str, **kw: object) -> int:
        rid = request_id()
        if cmd == "start":
            self.outs[str(kw["run"])] = Path(str(kw["out"]))
        self.commands.put({"id": rid, "cmd": cmd, **kw})
        return rid

    def kill(self) -> str:
        """Let go of the solver at once; says so. Its thread cannot be killed: a build under
        way goes on to its end on the worker, then the loop sees it was let go and ends."""
        self.let_go.set()
        where = f" on Dask worker {self.address}" if self.address else ""
        return f"its solver{where} was let go (it ends once its build is over)"

    def join(self, timeout: float) -> None:
        self.thread.join(timeout)

    def death(self) -> str:
        if self.address is None:
            return f"no solver could be started on the Dask cluster ({self.lost})"
        if self.lost is None:
            return f"its solver on Dask worker {self.address} ended"
        return (f"Dask worker {self.address}, which ran its solver, was lost ({self.lost}); "
                "the run's files were on it")

    def close(self, timeout: float = 3.0) -> bool:
        """Ask the solver to end, let go of it if it does not. Returns whether it ended."""
        if self.alive():
            self.send("shutdown")
            self.ended.wait(timeout)
        clean = self.ended.is_set()
        self.let_go.set()
        self.thread.join(timeout)
        return clean

    # ---- the pump thread ----------------------------------------------------------------------
    def _pump(self) -> None:
        future, meant = None, None
        try:
            future, meant = self.pool.submit(self.args)
            actor = self._actor(future)
            if actor is not None:
                where = actor.start().result(ANSWER_S)
                self.address, self.pid = where["address"], where["pid"]
                self.pool.moved(meant, self.address)
                meant = self.address
                self._serve(actor)
        except Exception as exc:  # the worker is gone, or does not answer
            if self.address is None:  # none made: a new handle would fail as fast
                self.let_go.wait(RETRY_S)
            if not self.let_go.is_set():
                self.lost = str(exc) if isinstance(exc, SchedulerError) \
                    else f"{type(exc).__name__}: {exc}"
        finally:
            self.pool.moved(meant, None)
            if future is not None:
                try:  # the worker drops the actor; an orphaned loop sees it and ends
                    future.cancel()
                except Exception:  # the client is closed: the scheduler drops it anyway
                    pass

    def _actor(self, future: Future) -> object | None:
        """The actor once the cluster has made it (None if let go before)."""
        while not self.let_go.is_set():
            try:
                return future.result(timeout=0.5)
            except TimeoutError:  # no worker free yet: wait on
                continue
        return None

    def _serve(self, actor: object) -> None:
        while not self.let_go.is_set():
            msgs = _drain(self.commands)
            if msgs:
                actor.send(msgs).result(ANSWER_S)
            got = actor.pull(PULL_WAIT).result(ANSWER_S)
            for ev in got["events"]:
                self._event(ev)
            for frame in got["frames"]:
                try:
                    self.frames.put_nowait(frame)
                except queue.Full:  # the bridge shows a newer frame soon
                    pass
            if got["done"]:
                self.ended.set()
                return

    def _event(self, ev: dict) -> None:
        run = ev.get("run") or ""
        if ev.get("kind") == "file":
            self._write(run, ev["name"], ev["data"])
            return
        if ev.get("kind") == "state" and ev.get("state") in ENDED:
            self.outs.pop(run, None)
            if run in self.unwritten:
                ev = {**ev, "state": "failed",
                      "reason": f"{ev.get('reason') or ev['state']}; {self.unwritten.pop(run)}"}
        self.events.put(ev)

    def _write(self, run: str, name: str, data: bytes) -> None:
        """One of the run's files into its folder, atomically."""
        out = self.outs.get(run)
        if out is None:
            return
        path = (out / name).resolve()
        try:
            if not path.is_relative_to(out.resolve()):
                raise OSError(f"{name!r} is not a path inside the run's folder")
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_name(f".{path.name}.tmp")
            tmp.write_bytes(data)
            os.replace(tmp, path)
        except OSError as exc:
            self.unwritten[run] = f"writing its file {name} on the server failed: {exc}"


def _drain(q: queue.Queue) -> list:
    out = []
    while True:
        try:
            out.append(q.get_nowait())
        except queue.Empty:
            return out

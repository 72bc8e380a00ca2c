"""Dask task running for ``q3t sweep`` and ``q3t study``: a list of calls as tasks on a local
cluster of worker processes (or an existing one, ``--scheduler``), gathered as they finish,
and the words a report uses for where they ran.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from distributed import Client, Future

# Numba's own pool would give every worker all cores: one thread each, the cluster is the pool.
WORKER_ENV = {"NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def worker_env(threads: int = 1) -> dict[str, str]:
    """Thread counts of a worker's numba, OpenMP and MKL pools, pinned before they start."""
    return {k: str(threads) for k in WORKER_ENV}


def cluster_text(workers: int, threads: int, scheduler: str | None) -> str:
    """Where tasks run, as a report says it."""
    if scheduler:
        return f"the Dask cluster at {scheduler}"
    return (f"a local Dask cluster of {workers} worker process{'es' * (workers != 1)}, one "
            f"task at a time each, numba/OpenMP/MKL pinned to {threads} thread"
            f"{'s' * (threads != 1)}")


def run_tasks(calls: list[tuple], labels: list[dict], workers: int = 1, threads: int = 1,
              scheduler: str | None = None, timeout: float | None = None,
              on_result: Callable[[int, dict], None] | None = None) -> tuple[list[dict], bool]:
    """Every ``(fn, *args)`` of ``calls`` as a Dask task, gathered as they finish; rows in the
    order of ``calls``, which is also the order of their priorities on the cluster.

    A task that raised is an ``error`` row, one still unfinished after ``timeout`` s is
    cancelled and becomes a ``timeout`` row (``labels[i]`` is merged into both). ``on_result(i,
    row)`` runs after each result; an exception it raises ends the run (and propagates).
    Returns (rows, finished: no timeout hit). The local cluster is closed on every way out,
    which ends its worker processes and any case still running in them."""
    import dask
    from distributed import Client, LocalCluster, as_completed

    rows: list[dict | None] = [None] * len(calls)
    finished = True

    def gather(client: Client) -> None:
        nonlocal finished
        futures = [client.submit(fn, *args, pure=False, priority=len(calls) - i)
                   for i, (fn, *args) in enumerate(calls)]
        where = {f.key: i for i, f in enumerate(futures)}
        try:
            for f in as_completed(futures, timeout=timeout):
                i = where[f.key]
                rows[i] = _row(f, labels[i])
                if on_result:
                    on_result(i, rows[i])
        except TimeoutError:
            finished = False
        finally:
            client.cancel([f for f in futures if not f.done()])
        for i, r in enumerate(rows):
            if r is None:
                rows[i] = {**labels[i], "status": "timeout", "converged": False, "probes": {},
                           "reason": f"not finished within the --timeout of {timeout:g} s"}

    if scheduler:
        with Client(scheduler, timeout=30) as client:
            gather(client)
        return rows, finished
    # non-daemonic workers may start the child processes that enforce per-case budgets
    with (dask.config.set({"distributed.worker.daemon": False}),
          LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                       dashboard_address=None, env=worker_env(threads), silence_logs=40)
          as cluster, Client(cluster) as client):
        gather(client)
    return rows, finished


def _row(future: Future, label: dict) -> dict:
    """A task that raised (a bug, a lost worker) is still a row, not the end of the sweep."""
    if future.status == "finished":
        return future.result()
    try:
        reason = repr(future.exception(timeout=1))
    except Exception as exc:  # noqa: BLE001 - cancelled or lost: say which
        reason = f"{future.status}: {exc!r}"
    return {**label, "status": "error", "converged": False, "reason": reason, "probes": {}}

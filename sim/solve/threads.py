"""The element kernels on the cores: a serial numba kernel (``nogil``) over a range of elements
or of colour blocks, called from Python threads, one contiguous share each.

Not numba's ``parallel=True``: a prange kernel is compiled over again (the parfor's gufunc and
its wrapper each link in and optimise again everything the loop body calls), several times
the compile of the same loop serial, and that was most of the minutes a first run on a new
machine, or after an edit of sim/, waits for. numba's threading layer, never started, also
cannot meet MKL's threads (with it, NUMBA_NUM_THREADS=1 crashed PARDISO's factorisation).
A share is a contiguous range and blocks of one colour share no node
(sim.solve.assembly.Schedule), so the sums do not depend on the number of threads.

The threads: ``NUMBA_NUM_THREADS`` (numba's own setting, default the cores; one where a
stamped result or a Dask worker asks for one), read at import.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np

COUNT = max(1, int(numba.config.NUMBA_NUM_THREADS))
_pool: ThreadPoolExecutor | None = None


def _forget_pool() -> None:
    # A forked child inherits the pool but not its threads: work submitted to it would wait
    # forever. It makes its own at its first kernel.
    global _pool
    _pool = None


os.register_at_fork(after_in_child=_forget_pool)


def shares(lo: int, hi: int, parts: int) -> list[tuple[int, int]]:
    """[lo, hi) cut into at most ``parts`` contiguous, non-empty ranges of near-equal length."""
    n = hi - lo
    parts = max(1, min(parts, n))
    edges = lo + (np.arange(parts + 1) * n) // parts
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)]


def over_ranges(kernel: Callable[..., object], lo: int, hi: int, *args: object) -> None:
    """``kernel(*args, a, b)`` for each share [a, b) of [lo, hi): the first in this thread, the
    others in the pool, all finished (or the first error raised) on return."""
    global _pool
    parts = shares(lo, hi, COUNT)
    if len(parts) == 1:
        kernel(*args, *parts[0])
        return
    if _pool is None:  # made once, at the first kernel that needs it
        _pool = ThreadPoolExecutor(COUNT - 1, thread_name_prefix="q3t-kernel")
    others = [_pool.submit(kernel, *args, a, b) for a, b in parts[1:]]
    try:
        kernel(*args, *parts[0])
    finally:
        for f in others:
            f.result()


def over_colours(kernel: Callable[..., object], order: np.ndarray, block_ptr: np.ndarray,
                 color_ptr: np.ndarray, *args: object, scatter: bool = True) -> None:
    """``kernel(*args, elements)`` per colour, its blocks shared out among the threads
    (``elements``: a thread's blocks' elements, contiguous in ``order``), one colour after the
    other: a colour's blocks touch no node another of its blocks does. Without ``scatter``
    (an energy alone, written per element) the colours need not wait for each other: all of
    ``order`` is shared out at once."""
    if not scatter:
        def elements(*a: object) -> None:
            kernel(*a[:-2], order[a[-2]:a[-1]])

        over_ranges(elements, 0, len(order), *args)
        return

    def blocks(*a: object) -> None:
        b0, b1 = a[-2], a[-1]
        kernel(*a[:-2], order[block_ptr[b0]:block_ptr[b1]])

    for c in range(len(color_ptr) - 1):
        over_ranges(blocks, int(color_ptr[c]), int(color_ptr[c + 1]), *args)


@numba.njit(cache=True, nogil=True)
def total(energies: np.ndarray) -> float:
    """The elements' energies summed in order with one accumulator, as numba sums an array:
    the same bits on any number of threads (a prange kernel's sum was split per thread), and
    those a single thread gave before."""
    return energies.sum()

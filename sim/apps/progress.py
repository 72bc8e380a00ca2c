"""``q3t run``'s progress and its closing summary, as text.

On a terminal the progress is one bar rewritten in place; in a log (a pipe, a file) it is one
plain line per step, so the log holds no carriage returns or half-lines."""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, TextIO

import numpy as np

from sim.frames.summary import rows, tools_of

if TYPE_CHECKING:
    from sim.stepping.simulation import Simulation, StepRecord

BAR = 24  # characters of the bar
# the remaining time: the mean cost of the last few steps times the steps left. The stroke's
# steps grow dearer as the contact spreads, so the recent steps foretell the next ones better
# than the mean over the run does.
RECENT = 5


def clock(seconds: float) -> str:
    """``42 s``, ``3:07``, ``1:02:03``."""
    s = round(seconds)
    if s < 60:
        return f"{s} s"
    h, rest = divmod(s, 3600)
    return f"{h}:{rest // 60:02d}:{rest % 60:02d}" if h else f"{rest // 60}:{rest % 60:02d}"


def where(sim: Simulation, rec: StepRecord) -> str:
    """Where the forming is at ``rec``: the punch's travel from its start (mm), the release
    stage, or the load factor of a scene without a punch."""
    if rec.step > sim.model.scene.stepping.steps:
        return "release"
    for t in tools_of(sim.model, "punch"):
        if t.tool in rec.tools:
            r = rec.tools[t.tool]
            travel = np.linalg.norm([r["x"], r["y"], r["z"]] - sim.summary.starts[t.tool])
            return f"stroke {travel * 1e3:.2f} mm"
    return f"t {rec.time:.3g}"


def columns(stream: TextIO) -> int:
    """The width of the terminal ``stream`` writes to (80 when it does not say): a line wider
    than that wraps, and a carriage return then rewrites only its last part."""
    try:
        return os.get_terminal_size(stream.fileno()).columns or 80
    except (OSError, ValueError, AttributeError):
        return 80


@dataclass
class Progress:
    """``progress(sim, record)`` of ``Simulation.run``, writing to ``stream``; ``close()``
    once the run has ended."""

    stream: TextIO
    tty: bool
    start: float = field(default_factory=time.perf_counter)
    costs: list[float] = field(default_factory=list)  # s, each step's (wall clock)
    _last: float = field(init=False)
    _open: bool = False  # a bar is on the line

    def __post_init__(self) -> None:
        self._last = self.start

    def __call__(self, sim: Simulation, rec: StepRecord) -> None:
        now = time.perf_counter()
        self.costs.append(now - self._last)
        self._last = now
        n = sim.n_steps
        left = n - rec.step
        remaining = left * float(np.mean(self.costs[-RECENT:]))
        times = f"{clock(now - self.start)} elapsed, ~{clock(remaining)} left"
        if self.tty:
            done = round(BAR * rec.step / n)
            line = f"[{'#' * done}{'.' * (BAR - done)}] step {rec.step}/{n}  " \
                   f"{where(sim, rec)}  {times}"
            width = columns(self.stream) - 1
            self.stream.write("\r" + line[:width].ljust(width))
            self._open = True
        else:
            self.stream.write(f"step {rec.step}/{n}: {where(sim, rec)}, {rec.iterations} "
                              f"Newton iterations, {self.costs[-1]:.2f} s ({times})\n")
        self.stream.flush()

    def close(self) -> None:
        """End the bar's line, so what follows starts on a line of its own."""
        if self._open:
            self.stream.write("\n")
            self.stream.flush()
            self._open = False


def summary_text(entries: list[dict]) -> str:
    """The run summary (result.json's ``summary``) as an aligned table for a terminal."""
    table = [("quantity", "value", "where"), *rows(entries)]
    widths = [max(len(r[i]) for r in table) for i in range(2)]
    return "\n".join(f"{q:<{widths[0]}}  {v:>{widths[1]}}  {w}".rstrip() for q, v, w in table)

"""The frames of the current run, kept in the server process so a paused or finished run can be
scrubbed: positions (float32), every per-vertex field (float32), the tools' translations and the
probes of each kept step.

Memory is capped by a frame count and a byte budget. Past either, the history keeps every k-th
step only (k doubles each time: 1, 2, 4, ...), so it always spans the whole run at an even
spacing; the newest frame is always kept, whatever its step, so the last state can be shown.
At 1,510 display vertices (the cup at 2 mm edges, 4 fields) a frame takes about 42 kB; at
40,000 vertices about 1.1 MB.
"""

from __future__ import annotations

import bisect
import threading

import numpy as np

from server.problems import NotFound


def frame_bytes(frame: dict) -> int:
    return int(frame["positions"].nbytes + sum(v.nbytes for v in frame["fields"].values()))


class FrameHistory:
    def __init__(self, max_frames: int = 400, max_bytes: int = 256 * 2**20):
        self.max_frames, self.max_bytes = max(2, max_frames), max_bytes
        self.lock = threading.Lock()
        self.reset(None)

    def reset(self, run_id: str | None) -> None:
        with self.lock:
            self.run = run_id
            self.steps: list[int] = []
            self.frames: list[dict] = []
            self.stride = 1
            self.bytes = 0

    def _keep(self, step: int) -> bool:
        return step % self.stride == 0

    def add(self, frame: dict) -> None:
        """Keep one frame of the current run (ignored if from another run, or kept already).
        Frames may arrive out of order: the rest frame and a paused run's frames come on the
        solver's event queue, the running frames on the frame queue, and the bridge reads
        both, so a loaded machine may hand it step 1 before step 0. An older frame is put in
        its place if the stride keeps it (the first step always)."""
        kept = {"step": int(frame["step"]), "time": float(frame["time"]),
                "positions": np.asarray(frame["positions"], np.float32),
                "fields": {k: np.asarray(v, np.float32) for k, v in frame["fields"].items()},
                "tools": {k: np.asarray(v, np.float32) for k, v in
                          (frame.get("tools") or {}).items()},
                "tool_rotations": {k: np.asarray(v, np.float32) for k, v in
                                   (frame.get("tool_rotations") or {}).items()},
                "probes": dict(frame.get("probes") or {}),
                "iterations": frame.get("iterations", 0), "residual": frame.get("residual", 0.0)}
        step = kept["step"]
        with self.lock:
            i = bisect.bisect_left(self.steps, step)
            if frame.get("run") != self.run or (i < len(self.steps) and self.steps[i] == step):
                return
            if i < len(self.steps):  # older than the newest
                if i > 0 and not self._keep(step):
                    return
            elif len(self.steps) > 1 and not self._keep(self.steps[-1]):
                self._pop(-1)  # the previous newest was only kept for being the newest
                i -= 1
            self.steps.insert(i, step)
            self.frames.insert(i, kept)
            self.bytes += frame_bytes(kept)
            while len(self.steps) > self.max_frames or (self.bytes > self.max_bytes
                                                        and len(self.steps) > 2):
                self.stride *= 2
                for i in range(len(self.steps) - 2, 0, -1):  # the first and newest stay
                    if not self._keep(self.steps[i]):
                        self._pop(i)

    def _pop(self, i: int) -> None:
        self.bytes -= frame_bytes(self.frames[i])
        del self.steps[i], self.frames[i]

    def at(self, step: int) -> dict | None:
        """The kept frame at ``step``, or the nearest kept one before it (the first if none)."""
        with self.lock:
            if not self.steps:
                return None
            i = max(bisect.bisect_right(self.steps, int(step)) - 1, 0)
            return self.frames[i]

    def summary(self) -> dict:
        with self.lock:
            return {"run": self.run, "steps": list(self.steps), "stride": self.stride,
                    "bytes": self.bytes, "max_frames": self.max_frames,
                    "max_bytes": self.max_bytes}


class Histories:
    """The kept frames of the runs started last, one ``FrameHistory`` each: ``keep`` of them
    (one per solver process), each with its share of the byte budget. A new run's history
    replaces the oldest one whose run is not active; the frames of a run not kept are
    ignored."""

    def __init__(self, keep: int, max_frames: int, max_bytes: int):
        self.keep = max(1, keep)
        self.max_frames, self.max_bytes = max_frames, max_bytes // self.keep
        self.lock = threading.Lock()
        self.by_run: dict[str, FrameHistory] = {}  # in the order the runs started

    def start(self, run_id: str, active: set[str]) -> None:
        history = FrameHistory(self.max_frames, self.max_bytes)
        history.reset(run_id)
        with self.lock:
            self.by_run[run_id] = history
            for old in [r for r in self.by_run if r not in active and r != run_id]:
                if len(self.by_run) <= self.keep:
                    break
                del self.by_run[old]

    def get(self, run_id: str | None) -> FrameHistory | None:
        with self.lock:
            return self.by_run.get(run_id or "")

    def kept(self, run_id: str) -> FrameHistory:
        """The frames kept of ``run_id`` (a known run): only the latest runs' are."""
        history = self.get(run_id)
        if history is None:
            n = self.keep
            raise NotFound(f"no frames kept for run {run_id!r} (only the latest "
                           f"{'run' if n == 1 else f'{n} runs'}'s are)")
        return history

    def at(self, run_id: str, step: int) -> dict:
        """A kept frame of one of the latest runs: the one at ``step`` or the nearest before."""
        frame = self.kept(run_id).at(step)
        if frame is None:
            raise NotFound(f"no frames kept for run {run_id!r} yet")
        return frame

    def add(self, frame: dict) -> None:
        history = self.get(frame.get("run"))
        if history is not None:
            history.add(frame)

    def forget(self, run_id: str) -> None:
        with self.lock:
            self.by_run.pop(run_id, None)

"""The bridge: the one thread that carries the solvers' events to the run records and the
viewer. It reads every solver process's queues in turn (``RunManager.slots``); each event names
its run, and only an active run's events are booked.

Each event kind has one small handler in ``HANDLERS``. A handler books its event under the run
manager's ``lock``, held only for a few dict and list updates, and returns what is left to do
once the lock is released: the viewer's updates and the file writes (``Booked.later``), and the
frame to show. The error estimate, which reads files, is made before the lock is taken; the
recording repairs of a dead solver run outside it too. So a status request never waits on the
viewer, the disk or the estimate. Frames reach the viewer at most ``push_hz`` times a second
per run, the newest one.

One bad event never stops the bridge: an error while booking it fails the event's run with the
reason (its solver is told to stop), a viewer error is noted on the run, and the bridge's
liveness and errors are part of ``/api/health``.
"""

from __future__ import annotations

import collections
import queue
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

from server.estimate import EstimateCache
from server.events import Changes
from server.history import Histories
from server.plots import probe_text
from server.records import ACTIVE, Run
from server.settings import Settings
from server.views import Views
from server.worker import Channel
from server.workerhandle import Slot, WorkerHandle
from sim.stepping.parameters import log_change

if TYPE_CHECKING:  # imports viser
    from server.viewer import Viewer

HEARTBEAT_S = 5.0  # a bridge silent for longer than this is reported dead
EMPTY = (queue.Empty, OSError, ValueError, EOFError)  # a queue with nothing (more) to read


class Books(Protocol):
    """What the bridge books into: the run manager (``server.runs.RunManager``)."""

    settings: Settings
    lock: threading.RLock
    runs: dict[str, Run]
    ready: threading.Event
    parameter_ranges: dict
    logs: collections.deque
    history: Histories
    estimates: EstimateCache
    waiters: dict[int, dict]
    sent: dict[int, str]
    viewer: Viewer | None
    slots: list[Slot]
    closing: threading.Event
    changes: Changes
    views: Views

    def finish(self, run: Run, state: str, reason: str | None) -> None: ...
    def save(self, run: Run) -> None: ...
    def note(self, run_id: str | None, text: str) -> None: ...
    def fail_run(self, run_id: str | None, reason: str) -> None: ...
    def worker_died(self, w: WorkerHandle) -> None: ...
    def close_retired(self) -> None: ...


@dataclass
class Booked:
    """What booking an event leaves for after the lock: viewer updates and file writes, and
    the frame to show."""

    later: list[Callable[[], None]] = field(default_factory=list)
    shown: dict | None = None


Handler = Callable[[Books, dict], Booked]
HANDLERS: dict[str, Handler] = {}


def handles(kind: str) -> Callable[[Handler], Handler]:
    def register(handler: Handler) -> Handler:
        HANDLERS[kind] = handler
        return handler
    return register


def _active(m: Books, ev: dict) -> Run | None:
    """Under ``lock``: the event's run if it is active (an ended run's late events are not
    booked)."""
    run = m.runs.get(ev.get("run") or "")
    return run if run is not None and run.state in ACTIVE else None


@handles("ready")
def _ready(m: Books, ev: dict) -> Booked:
    booked = Booked()
    if not m.ready.is_set():
        m.parameter_ranges = ev["parameters"]
        m.ready.set()
        if m.viewer:
            booked.later.append(lambda: m.viewer.add_parameters(m.parameter_ranges))
    return booked


@handles("log")
def _log(m: Books, ev: dict) -> Booked:
    m.logs.append(ev["text"])
    return Booked()


@handles("reply")
def _reply(m: Books, ev: dict) -> Booked:
    """Wakes a request waiting for this reply; the command is no longer pending. A refusal
    nobody waits for is noted on the run, which goes on."""
    with m.lock:
        waiter = m.waiters.get(ev.get("id"))
        if waiter is not None:
            waiter["reply"] = ev
            waiter["event"].set()
        sender = m.runs.get(m.sent.pop(ev.get("id"), ""))
        if sender is not None and ev["cmd"] in sender.pending:
            sender.pending.remove(ev["cmd"])
        run = _active(m, ev)
        if run is not None and not ev["ok"] and waiter is None:
            run.reason = ev["error"]
    return Booked()


@handles("state")
def _state(m: Books, ev: dict) -> Booked:
    if ev["state"] == "finished":
        run = m.runs.get(ev.get("run") or "")
        if run is not None and run.state in ACTIVE:
            m.estimates.get(run, finished=True)  # reads files: before taking the lock
    booked = Booked()
    with m.lock:
        run = _active(m, ev)
        if run is None:
            return booked
        run.frames.update(ev.get("frames") or {})
        if ev["state"] in ACTIVE:
            if run.state == "starting":  # run.json said queued: a solver has it now
                booked.later.append(lambda: m.save(run))
            run.state = ev["state"]
        else:
            run.field_ranges = ev.get("field_ranges") or {}
            run.stepping_s += ev.get("wall_s") or 0.0  # a step that failed took time too
            m.finish(run, ev["state"], ev.get("reason"))
            booked.later.append(lambda: m.save(run))
        if m.viewer:
            line, active, controls = run.line(), run.state in ACTIVE, run.controls()
            booked.later.append(lambda: m.viewer.run_status(run.id, line, active, controls))
    return booked


@handles("meta")
def _meta(m: Books, ev: dict) -> Booked:
    """The run's model is built: its size, probes and tools (meshes for the viewer)."""
    booked = Booked()
    with m.lock:
        run = _active(m, ev)
        if run is None:
            return booked
        run.n_steps, run.counts, run.probes = ev["n_steps"], ev["counts"], ev["probes"]
        tools = ev.get("tools") or []
        run.tools = [t["name"] for t in tools]
        run.timing.update(ev.get("timing") or {})
        # the solver's values of every live parameter (those it was given applied): what the
        # page's and the viewer's sliders show
        run.parameters.update(ev.get("parameters") or {})
        run.punches, run.probe_kinds = ev.get("punches") or {}, ev.get("probe_kinds") or {}
        run.scaled = ev.get("scaled") or {}
        run.thinning_limit = ev.get("thinning_limit")
        if ev.get("note"):  # a problem that does not end the run (the tools not shown)
            run.reason = ev["note"]
        line, values = run.line(), dict(run.parameters)
    booked.later.append(lambda: m.save(run))
    if m.viewer:
        booked.later.append(lambda: m.viewer.new_run(run.id, ev["faces"], tools, line, values,
                                                     run.thinning_limit))
    return booked


@handles("preview")
def _preview(m: Books, ev: dict) -> Booked:
    """A scene's rest state for the viewer (``Views.show_scene``)."""
    return Booked(later=[lambda: m.views.show_preview(ev)])


@handles("step")
def _step(m: Books, ev: dict) -> Booked:
    with m.lock:
        run = _active(m, ev)
        if run is not None:
            run.records.append(ev["record"])
            run.step = ev["record"]["step"]
            run.stepping_s += ev.get("wall_s") or 0.0
            run.paced_s += ev.get("delay_s") or 0.0
            run.n_steps = ev.get("n_steps", run.n_steps)  # tool_speed changes the count
            run.frames.update(ev.get("frames") or {})
    return Booked()


@handles("parameter")
def _parameter(m: Books, ev: dict) -> Booked:
    booked, entry = Booked(), ev["entry"]
    with m.lock:
        run = _active(m, ev)
        if run is None:
            return booked
        log_change(run.parameter_log, entry)
        run.parameters[entry["name"]] = entry["value"]
        run.n_steps = ev.get("n_steps", run.n_steps)
    if m.viewer:
        booked.later.append(lambda: m.viewer.set_parameter_value(run.id, entry["name"],
                                                                 entry["value"]))
    return booked


@handles("frame")
def _frame(m: Books, ev: dict) -> Booked:
    """Kept in the history (for scrubbing), and shown. Frames and the run's states come by
    two queues, so a frame the solver made before the run ended can be read after its end:
    it is still kept (the history takes the latest run's frames only), not shown or counted."""
    with m.lock:
        run = _active(m, ev)
        if run is None:
            m.history.add(ev)
            return Booked()
        if "first_frame_s" not in run.timing:
            run.timing["first_frame_s"] = time.time() - run.created
        elif ev["step"] == 1 and "first_step_s" not in run.timing:
            run.timing["first_step_s"] = time.time() - run.created
        run.frames["received"] = run.frames.get("received", 0) + 1
        m.history.add(ev)
    return Booked(shown=ev)


def _book(m: Books, ev: dict) -> Booked:
    handler = HANDLERS.get(ev.get("kind"))
    if handler is None:
        raise ValueError(f"unknown event kind {ev.get('kind')!r}")
    return handler(m, ev)


def drain(q: Channel, limit: int = 1000) -> list:
    """What ``q`` holds now, at most ``limit`` items, without waiting."""
    out = []
    for _ in range(limit):
        try:
            out.append(q.get_nowait())
        except EMPTY:
            break
    return out


class Bridge:
    def __init__(self, manager: Books):
        self.m = manager
        self.thread = threading.Thread(target=self._loop, name="q3t-bridge", daemon=True)
        self.heartbeat = time.monotonic()
        self.repairing: str | None = None  # the run whose recording the bridge is repairing
        self.errors = 0
        self.error: str | None = None
        # per run: the frame to push next (the newest received), whether it is the run's
        # last, and when it is due
        self._newest: dict[str, dict] = {}
        self._final: dict[str, bool] = {}
        self._next_push: dict[str, float] = {}

    def start(self) -> None:
        self.thread.start()

    def join(self, timeout: float) -> None:
        """Wait for the loop to end (it ends once the manager is ``closing``)."""
        self.thread.join(timeout)

    # ---- health -----------------------------------------------------------------------------
    def running(self) -> bool:
        return self.thread.is_alive()

    def alive(self) -> bool:
        """Running, and not stuck: it came round within ``HEARTBEAT_S`` or is repairing a
        recording."""
        return self.thread.is_alive() and (
            self.repairing is not None or time.monotonic() - self.heartbeat < HEARTBEAT_S)

    @contextmanager
    def repairing_recording(self, run_id: str) -> Iterator[None]:
        """A repair (rerun rrd merge) can outlast the heartbeat: health says what the bridge
        does meanwhile."""
        self.repairing = run_id
        try:
            yield
        finally:
            self.repairing = None
            self.heartbeat = time.monotonic()

    def fault(self, exc: BaseException, what: str) -> None:
        self.errors += 1
        self.error = f"{what}: {type(exc).__name__}: {exc}"
        print(f"q3t: {self.error}\n{traceback.format_exc()}", file=sys.stderr)

    # ---- one event ----------------------------------------------------------------------------
    def handle(self, ev: dict) -> dict | None:
        """Book one event, then do what it left for after the lock; returns the frame to
        show, if any."""
        try:
            booked = _book(self.m, ev)
        except Exception as exc:
            what = f"the server could not handle the solver's {ev.get('kind')!r} event"
            self.fault(exc, what)
            try:
                self.m.fail_run(ev.get("run"), f"{what}: {exc}")
            except Exception as exc2:
                self.fault(exc2, "failing the run")
            return None
        for update in booked.later:
            try:
                update()
            except Exception as exc:  # display and files only: the run goes on
                self.fault(exc, "viewer or file update")
                self.m.note(ev.get("run"), f"viewer: {exc}")
        return booked.shown

    # ---- the loop -----------------------------------------------------------------------------
    def _loop(self) -> None:
        while not self.m.closing.is_set():
            self.heartbeat = time.monotonic()
            try:
                self._step()
            except Exception as exc:  # never let the bridge die; health reports the errors
                self.fault(exc, "bridge")
                time.sleep(0.05)

    def _step(self) -> None:
        self.m.close_retired()  # here, the one thread that reads their queues
        workers = [s.worker for s in self.m.slots]
        wait = 0.05 / len(workers)  # a round waits about as long as with one solver
        for w in workers:
            self._read(w, wait)
        self._push_due()

    def _read(self, w: WorkerHandle, wait: float) -> None:
        """Book what one solver process sent; notice its death once its queue is empty."""
        try:
            events = [w.events.get(timeout=wait), *drain(w.events)]
        except EMPTY:
            events = []
        for ev in events + drain(w.frames, 64):
            shown = self.handle(ev)
            if shown is not None:
                self._offer(shown)
        if events:
            self.m.changes.touch()
        if not events and not w.alive() and not self.m.closing.is_set():
            self.m.worker_died(w)

    def _offer(self, shown: dict) -> None:
        """Keep the run's newest frame to push; a run's last frame stays marked final."""
        run = shown["run"]
        newest = self._newest.get(run)
        if newest is not None and shown["step"] < newest["step"]:
            return  # an older frame from the bounded queue, after a newer one
        keep_final = self._final.get(run, False) and newest is not None \
            and shown["step"] == newest["step"]
        self._newest[run], self._final[run] = shown, bool(shown.get("final")) or keep_final

    def _push_due(self) -> None:
        if self.m.viewer is None:
            self._newest.clear()  # nothing to show it on: a viewer added later starts afresh
            return
        now = time.perf_counter()
        for run in list(self._newest):
            due = self._next_push.get(run, 0.0)
            if not (self._final[run] or now >= due):
                continue
            self._push(self._newest.pop(run), self._final.pop(run))
            # on a fixed grid of 1/push_hz, not "that long after the last push", so the rate
            # is push_hz and not less by the loop's jitter; never a burst after a pause
            self._next_push[run] = max(due + 1.0 / self.m.settings.push_hz, now)
        for run in [r for r in self._next_push if r not in self._newest]:
            if self._next_push[run] < now:  # no frame due: an ended run's entry goes
                del self._next_push[run]

    def _push(self, frame: dict, final: bool) -> None:
        run = self.m.runs.get(frame["run"])
        if run is None:
            return
        probes = ", ".join(probe_text(k, v, run.probe_kinds.get(k))
                           for k, v in list(frame["probes"].items())[:3])
        status = (f"{run.line()}  \nstep {frame['step']}: {frame['iterations']} Newton "
                  f"iterations  \n{probes}")
        try:
            self.m.viewer.show(frame, status, final=final)
        except Exception as exc:  # a viewer problem must never stop the bridge
            self.fault(exc, "viewer")
            self.m.note(run.id, f"viewer: {exc}")
            return
        with self.m.lock:
            run.frames["pushed"] = run.frames.get("pushed", 0) + 1

"""A run's events for scripts: a server-sent-events stream of what changes (state, step
records, live parameters) and a wait until the run ends, so a client never polls.

The stream does not keep a second copy of the runs: it reads the run's status as a request
does and sends what differs from what it sent last. ``Changes`` only wakes it: the bridge
touches it when the solver's events are booked, the manager when it ends a run itself. A
touch that is missed costs latency, never an event: the stream also looks every
``LOOK_S`` seconds.
"""

from __future__ import annotations

import asyncio
import json
import threading
from collections.abc import AsyncIterator, Awaitable, Callable

from server.records import ACTIVE

LOOK_S = 1.0  # the longest a missed touch delays an event
KEEPALIVE_S = 15.0  # a comment line keeps proxies from closing a quiet stream
# what a step record, a parameter change or a state change sends; the rest of the status
# (estimate, progress) rides along with the state
STATE_KEYS = ("state", "reason", "pending", "n_steps")


class Changes:
    """Touched from any thread when the runs changed; awaited in the server's event loop."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.version = 0
        self._waiting: list[tuple[asyncio.AbstractEventLoop, asyncio.Future]] = []

    def touch(self) -> None:
        with self._lock:
            self.version += 1
            waiting, self._waiting = self._waiting, []
        for loop, future in waiting:
            try:
                loop.call_soon_threadsafe(_wake, future)
            except RuntimeError:  # that loop has closed: nobody waits on it any more
                pass

    async def wait(self, version: int, timeout: float) -> int:
        """The version once it differs from ``version``, or after ``timeout`` seconds."""
        loop = asyncio.get_running_loop()
        future = loop.create_future()
        with self._lock:
            if self.version != version:
                return self.version
            self._waiting.append((loop, future))
        try:
            await asyncio.wait_for(future, timeout)
        except TimeoutError:
            with self._lock:
                if (loop, future) in self._waiting:
                    self._waiting.remove((loop, future))
        return self.version


def _wake(future: asyncio.Future) -> None:
    if not future.done():
        future.set_result(None)


def sse(kind: str, data: dict, event_id: int | None = None) -> str:
    """One server-sent event (text/event-stream): ``data`` as one line of strict JSON."""
    head = f"id: {event_id}\n" if event_id is not None else ""
    return f"{head}event: {kind}\ndata: {json.dumps(data, allow_nan=False)}\n\n"


def ended(status: dict) -> bool:
    return status["state"] not in ACTIVE


Status = Callable[[int], Awaitable[dict | None]]  # since step -> status, None: deleted


async def stream(status: Status, changes: Changes, since: int,
                 gone: Callable[[], Awaitable[bool]]) -> AsyncIterator[str]:
    """The events of one run after step ``since``: ``state`` first and on every change of
    STATE_KEYS, ``step`` per step record (its id the step, for Last-Event-ID), ``parameters``
    when a live parameter changed, and ``end`` (the final status) or ``deleted`` last.
    ``status(since)`` reads the run (None once it is deleted); ``gone()`` is true once the
    client has disconnected."""
    sent_state: tuple | None = None
    sent_parameters: dict | None = None
    quiet = 0.0
    while True:
        version = changes.version
        st = await status(since)
        if st is None:
            yield sse("deleted", {})
            return
        records = st.pop("records")
        left = st.pop("records_left")
        state = tuple(json.dumps(st.get(k)) for k in STATE_KEYS)
        if state != sent_state:
            yield sse("state", st)
            sent_state = state
        elif st["parameters"] != sent_parameters:
            yield sse("parameters", {"parameters": st["parameters"], "step": st["step"]})
        sent_parameters = st["parameters"]
        for record in records:
            yield sse("step", record, record["step"])
            since = record["step"]
        if left:
            continue
        if ended(st):
            yield sse("end", st)
            return
        if await gone():
            return
        if await changes.wait(version, LOOK_S) == version:
            quiet += LOOK_S
            if quiet >= KEEPALIVE_S:
                yield ": keepalive\n\n"
                quiet = 0.0
        else:
            quiet = 0.0

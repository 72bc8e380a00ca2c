"""viser's message buffers woken on viser's own event loop only.

viser 1.1 pushes a message from whichever thread calls its API (our bridge, request and
callback threads) and then sets the buffer's ``asyncio.Event`` in that thread, besides
scheduling the same ``set`` on its event loop with ``call_soon_threadsafe``. ``Event.set``
walks the event's waiters while the loop may be adding one in ``wait``: a test once raised
"RuntimeError: deque mutated during iteration" out of a frame the viewer drew. asyncio's
events are not thread-safe; viser's comment says the set in the caller's thread is there so
that synchronous code reads the flag at once. ``LoopEvent`` keeps that (off the loop, ``set``
raises the flag only) and leaves the waking to the set viser schedules on its loop, where
``set`` wakes the waiters even when the flag is already up. ``install()`` gives every buffer
made from then on such an event (the dataclass takes it as a field).
"""

from __future__ import annotations

import asyncio
import functools

from viser.infra import _async_message_buffer as buffers


class LoopEvent(asyncio.Event):
    """An ``asyncio.Event`` whose ``set`` touches its waiters only on the loop they wait on."""

    def set(self) -> None:
        try:
            here = asyncio.get_running_loop()
        except RuntimeError:
            here = None
        self._value = True
        if here is None or here is not getattr(self, "_loop", None):
            return  # another thread: the flag only; the loop's own set wakes the waiters
        for waiter in self._waiters:
            if not waiter.done():
                waiter.set_result(True)


def install() -> None:
    """Every viser message buffer made from now on wakes its sender with a LoopEvent."""
    init = buffers.AsyncMessageBuffer.__init__
    if getattr(init, "loop_event", False):
        return

    @functools.wraps(init)
    def made(self, *args, **kwargs) -> None:  # noqa: ANN001, ANN002, ANN003
        kwargs.setdefault("message_event", LoopEvent())
        init(self, *args, **kwargs)

    made.loop_event = True  # type: ignore[attr-defined]
    buffers.AsyncMessageBuffer.__init__ = made

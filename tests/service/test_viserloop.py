"""viser's message buffers woken on viser's loop only (server.viserloop): a message pushed from
another thread raises the event's flag there and wakes the waiting sender on the loop."""

from __future__ import annotations

import asyncio
import collections
import threading
import time

import pytest
from viser._messages import SetSceneNodeVisibilityMessage
from viser.infra._async_message_buffer import AsyncMessageBuffer

from server import viserloop


class _LoopOnly(collections.deque):
    """An event's waiters that fail when walked off the loop's thread: the race, made to
    show every time (the loop adding a waiter while another thread walks them)."""

    def __init__(self, thread: threading.Thread):
        super().__init__()
        self.thread = thread

    def __iter__(self):  # noqa: ANN204
        assert threading.current_thread() is self.thread, "waiters walked off the loop"
        return super().__iter__()


@pytest.fixture
def loop():
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    yield loop, thread
    # a turn of the loop for a cancelled waiter to end before the loop stops
    asyncio.run_coroutine_threadsafe(asyncio.sleep(0.01), loop).result(10)
    loop.call_soon_threadsafe(loop.stop)
    thread.join(10)
    loop.close()


def _waiting(loop, thread, event):  # noqa: ANN001, ANN202
    """A coroutine waiting on ``event`` on the loop, once its waiter is in place."""
    asyncio.run_coroutine_threadsafe(_swap(event, thread), loop).result(10)
    waiter = asyncio.run_coroutine_threadsafe(event.wait(), loop)
    deadline = time.monotonic() + 10
    while not event._waiters and time.monotonic() < deadline:
        time.sleep(0.001)
    assert event._waiters
    return waiter


async def _swap(event, thread) -> None:  # noqa: ANN001
    event._waiters = _LoopOnly(thread)


def test_a_push_from_another_thread_wakes_the_sender_on_the_loop(loop):
    loop, thread = loop
    viserloop.install()
    viserloop.install()  # once is enough: a second call wraps nothing again
    buffer = AsyncMessageBuffer(loop, persistent_messages=False)
    assert isinstance(buffer.message_event, viserloop.LoopEvent)
    waiter = _waiting(loop, thread, buffer.message_event)
    buffer.push(SetSceneNodeVisibilityMessage(name="/sheet", visible=True))
    assert buffer.message_event.is_set()  # at once, in this thread (viser reads it so)
    assert waiter.result(10) is True  # woken on the loop by the set viser schedules there


def test_asyncios_own_event_walks_its_waiters_in_the_pushing_thread(loop):
    """What the LoopEvent is for: a plain asyncio.Event set from this thread walks the loop's
    waiters here (the deque the loop appends to), which _LoopOnly refuses."""
    loop, thread = loop
    event = asyncio.Event()
    waiter = _waiting(loop, thread, event)
    with pytest.raises(AssertionError, match="waiters walked off the loop"):
        event.set()
    waiter.cancel()  # never woken: the flag went up before the walk failed

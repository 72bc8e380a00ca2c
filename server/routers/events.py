"""/api/runs/{id}/events and /wait: for scripts, a run's events as they happen and a call that
returns when the run has ended (server.events)."""

from __future__ import annotations

import time

from fastapi import APIRouter, Header, Query, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import StreamingResponse

from server import events
from server.errors import CheckedRoute, documented
from server.problems import NotFound
from server.routers.runs import RunSummary
from server.runs import RunManager
from server.settings import RunId

router = APIRouter(prefix="/api/runs", tags=["runs"], route_class=CheckedRoute)
PAGE = 200  # step records read at once: a long run's backlog goes out in pieces
WAIT_MAX_S = 600.0  # a longer wait is a loop of waits: proxies close idle requests


def _runs(request: Request) -> RunManager:
    return request.app.state.manager


@router.get("/{run_id}/events", response_class=StreamingResponse, responses={
    200: {"content": {"text/event-stream": {}},
          "description": "server-sent events: `state`, `step`, `parameters`, then `end` (or "
                         "`deleted`); each event's data is one line of JSON"},
    **documented(404, 422)})
async def run_events(run_id: RunId, request: Request,
                     since: int = Query(0, ge=0, description="send step records after this "
                                        "step (0: all)"),
                     last_event_id: int | None = Header(None, ge=0, description=(
                         "set by a reconnecting EventSource: the last step record it got"))
                     ) -> StreamingResponse:
    """The run's events as they happen, as server-sent events (an `EventSource` in a browser,
    any SSE client in a script): `state` first (the run's summary, as `GET /api/runs/{id}`)
    and again when its state, reason, pending commands or step count change; `step` for each
    step record (its event id the step number); `parameters` when a live parameter changed;
    last `end` with the final summary once the run has ended, or `deleted`. A run that has
    already ended sends its state, its records and `end` at once."""
    m = _runs(request)
    m.get(run_id)  # 404 before the stream starts
    start = max(since, last_event_id or 0)

    async def status(after: int) -> dict | None:
        try:  # the status reads the estimate's files: not in the event loop
            return await run_in_threadpool(m.status, run_id, after, PAGE)
        except NotFound:
            return None

    body = events.stream(status, m.changes, start, request.is_disconnected)
    # no-transform and X-Accel-Buffering: proxies must not hold the events back
    return StreamingResponse(body, media_type="text/event-stream", headers={
        "Cache-Control": "no-cache, no-transform", "X-Accel-Buffering": "no"})


@router.get("/{run_id}/wait", response_model=RunSummary, responses=documented(404, 422))
async def wait_run(run_id: RunId, request: Request,
                   timeout: float = Query(60.0, gt=0, le=WAIT_MAX_S, allow_inf_nan=False,
                                          description="seconds to wait at most")) -> dict:
    """Return once the run has ended (its state finished, failed, stopped or cancelled; a
    queued run has not begun), or after `timeout` seconds with the run as it is then (its
    state still queued or active: wait again). A script's `wait` is one request, not a poll
    loop."""
    m = _runs(request)
    deadline = time.monotonic() + timeout
    while True:
        version = m.changes.version
        with m.lock:  # bookkeeping only: held for a dict read
            summary = m.get(run_id).summary()
        left = deadline - time.monotonic()
        if events.ended(summary) or left <= 0 or await request.is_disconnected():
            return summary
        await m.changes.wait(version, min(left, events.LOOK_S))

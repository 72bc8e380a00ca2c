"""Errors become clear 4xx answers, all of one shape (``Problem``: ``{"detail": "<field>:
<reason>"}``, documented on each route); oversize bodies 413, bodies that never finish 408; an
optional access token.

Only the problems a request can cause are mapped (``server.problems``, ``SceneError`` and what
FastAPI finds wrong with a request); any other exception is a server bug and stays a 500,
logged by uvicorn."""

from __future__ import annotations

import asyncio
import hmac
import json
from collections.abc import Awaitable, Callable, Iterable
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, Response
from fastapi.routing import APIRoute
from pydantic import BaseModel
from starlette.exceptions import HTTPException
from starlette.routing import Match
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from server.problems import Busy, Conflict, Invalid, NotFound, NotReady, Unsolved
from server.settings import Settings
from sim.scene.load import SceneError
from sim.scene.tree import MAX_DEPTH, tree_problem


class Problem(BaseModel):
    """Every error answer: what is wrong, naming the field (``material.nu: ...``)."""

    detail: str


ERRORS = {
    400: "The request cannot be read (e.g. a Content-Length that is not a number)",
    401: "Missing or wrong access token",
    404: "No such scene, run, frame or file",
    405: "Method not allowed here (the Allow header lists those that are); a reserved scene "
         "name (parse, render, schema, validate) is a route of its own",
    408: "The request body did not arrive in time",
    409: "The request does not fit the run's state, or the name is taken",
    413: "The request body is too large",
    422: "Invalid input; the detail names the field and the reason (or the solve asked for "
         "failed on it, with the solver's numbers)",
    429: "The run queue is full (the server's --queue): retry when a queued run has started",
    503: "The solver process is still starting; retry (Retry-After)",
}


Endpoint = Callable[[Request], Awaitable[Response]]  # a request in, its answer out

BODY = (400, 408, 413, 422)  # what any request with a JSON body can get
# requests whose route streams its body to disk and limits it itself (an upload is larger than
# max_body and must not be held in memory: server.routers.files, Settings.max_upload)
STREAMED = {("POST", "/api/files")}


def documented(*codes: int) -> dict:
    """The ``responses`` of a route that can answer ``codes``."""
    return {c: {"model": Problem, "description": ERRORS[c]} for c in sorted(set(codes))}


def _json(status: int, detail: str, headers: dict | None = None) -> JSONResponse:
    return JSONResponse({"detail": detail}, status_code=status, headers=headers)


def _where(loc: Iterable) -> str:
    return ".".join(str(p) for p in loc)


def validation_text(errors: Iterable[dict]) -> str:
    """FastAPI's request errors as one line naming each field: ``body.value: Input should
    be a valid number``."""
    return "; ".join(f"{_where(e['loc'])}: {e['msg'].removeprefix('Value error, ')}"
                     for e in errors)


def checked_json(body: bytes) -> Any:
    """The request's JSON, refused (422 naming where) when it nests deeper than any request
    needs or holds a lone surrogate (``"\\ud800"``: valid JSON, but no text: it cannot be
    written to a file or sent back)."""
    try:
        data = json.loads(body)
    except RecursionError:  # json recurses once per level
        raise HTTPException(422, f"body: nested deeper than {MAX_DEPTH} levels") from None
    except UnicodeDecodeError as exc:
        raise HTTPException(422, f"body: not UTF-8 ({exc.reason} at byte {exc.start})") \
            from None
    problem = tree_problem(data, prefix=("body",))
    if problem:
        raise HTTPException(422, problem)
    return data


class CheckedRequest(Request):
    async def json(self) -> Any:
        if not hasattr(self, "_json"):
            self._json = checked_json(await self.body())
        return self._json


class CheckedRoute(APIRoute):
    """Routes whose JSON body goes through ``checked_json``."""

    def get_route_handler(self) -> Endpoint:
        handler = super().get_route_handler()

        async def route(request: Request) -> Response:
            return await handler(CheckedRequest(request.scope, request.receive))

        return route


class BodyLimit:
    """Pure ASGI middleware: 413 when the declared or the received body exceeds ``limit`` bytes,
    408 when it has not all arrived within ``timeout`` seconds (a client that stops sending
    would otherwise hold its connection, and the request, open for ever).

    The body is read here in full (at most ``limit`` bytes) before the app sees it: a chunked
    body has no length to check up front, and an error raised while the app reads the body
    would reach FastAPI's body parser, which turns every error into a 400."""

    def __init__(self, app: ASGIApp, limit: int, timeout: float):
        self.app, self.limit, self.timeout = app, limit, timeout

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or (scope["method"], scope["path"]) in STREAMED:
            return await self.app(scope, receive, send)
        declared = dict(scope["headers"]).get(b"content-length")
        try:
            if declared is not None and int(declared) > self.limit:
                return await self._too_big(scope, receive, send)
        except ValueError:
            return await _json(400, "Content-Length is not a number")(scope, receive, send)
        try:
            async with asyncio.timeout(self.timeout):
                body = await self._read(receive)
        except TimeoutError:
            close = {"Connection": "close"}  # the rest of this body is never read
            return await _json(408, f"request body not received within {self.timeout:g} s",
                               close)(scope, receive, send)
        if body is None:  # the client went away
            return
        if len(body) > self.limit:
            return await self._too_big(scope, receive, send)
        done = False

        async def replay() -> Message:
            nonlocal done
            if not done:
                done = True
                return {"type": "http.request", "body": body, "more_body": False}
            return await receive()  # after the body: wait for the disconnect, as ASGI does

        await self.app(scope, replay, send)

    async def _read(self, receive: Receive) -> bytes | None:
        """The body, or None when the client went away; stops a byte past ``limit``."""
        chunks, seen = [], 0
        while True:
            msg = await receive()
            if msg["type"] != "http.request":
                return None
            chunks.append(msg.get("body", b""))
            seen += len(chunks[-1])
            if seen > self.limit or not msg.get("more_body"):
                return b"".join(chunks)

    def _too_big(self, scope: Scope, receive: Receive, send: Send) -> Awaitable[None]:
        return _json(413, f"request body larger than {self.limit} bytes")(scope, receive, send)


METHODS = ("GET", "POST", "PUT", "DELETE", "PATCH")


def allowed_methods(app: FastAPI, scope: Scope) -> list[str]:
    """The methods some route answers at this path (Starlette's 405 names only those of the
    first route that matches the path)."""
    return [m for m in METHODS
            if any(r.matches({**scope, "method": m})[0] == Match.FULL for r in app.routes)]


def http_error(request: Request, exc: HTTPException) -> Response:
    """Starlette's HTTP errors in the one error shape; a 405 lists every allowed method, and
    OPTIONS on a path that exists answers 204 with them."""
    headers = dict(exc.headers or {})
    if exc.status_code == 405:
        headers["Allow"] = ", ".join(allowed_methods(request.app, request.scope) + ["OPTIONS"])
        if request.method == "OPTIONS":
            return Response(status_code=204, headers=headers)
    return _json(exc.status_code, str(exc.detail), headers)


def _token_bytes(text: str) -> bytes:
    # surrogateescape: any str a client can send encodes, so a strange token is a 401, not a 500
    return text.encode("utf-8", "surrogateescape")


def install(app: FastAPI, settings: Settings) -> None:
    app.add_exception_handler(SceneError, lambda r, e: _json(422, str(e)))
    app.add_exception_handler(Invalid, lambda r, e: _json(422, str(e)))
    app.add_exception_handler(Unsolved, lambda r, e: _json(422, str(e)))
    app.add_exception_handler(NotFound, lambda r, e: _json(404, str(e)))
    app.add_exception_handler(Conflict, lambda r, e: _json(409, str(e)))
    app.add_exception_handler(NotReady, lambda r, e: _json(503, str(e), {"Retry-After": "1"}))
    app.add_exception_handler(Busy, lambda r, e: _json(429, str(e)))
    app.add_exception_handler(RequestValidationError,
                              lambda r, e: _json(422, validation_text(e.errors())))
    app.add_exception_handler(HTTPException, http_error)
    app.add_middleware(BodyLimit, limit=settings.max_body, timeout=settings.body_timeout)
    if settings.token:
        token = _token_bytes(settings.token)

        @app.middleware("http")
        async def require_token(request: Request, call_next: Endpoint) -> Response:
            given = (request.query_params.get("token") or request.cookies.get("q3t_token")
                     or request.headers.get("authorization", "").removeprefix("Bearer "))
            if not hmac.compare_digest(_token_bytes(given or ""), token):
                return _json(401, "missing or wrong token (?token=..., or Bearer header)")
            response = await call_next(request)
            if request.query_params.get("token"):
                response.set_cookie("q3t_token", settings.token, httponly=True,
                                    samesite="strict")
            return response

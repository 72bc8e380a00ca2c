"""Errors become clear 4xx answers; oversize bodies 413; an optional access token.

Only the problems a request can cause are mapped (``server.problems`` and ``SceneError``); any
other exception is a server bug and stays a 500, logged by uvicorn."""

from __future__ import annotations

import hmac

from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse

from server.problems import Conflict, Invalid, NotFound, NotReady
from server.settings import Settings
from sim.scene import SceneError


def _json(status: int, detail: str, headers: dict | None = None) -> JSONResponse:
    return JSONResponse({"detail": detail}, status_code=status, headers=headers)


class BodyLimit:
    """Pure ASGI middleware: 413 when the declared or the received body exceeds ``limit`` bytes.

    The body is read here in full (at most ``limit`` bytes) before the app sees it: a chunked
    body has no length to check up front, and an error raised while the app reads the body
    would reach FastAPI's body parser, which turns every error into a 400."""

    def __init__(self, app, limit: int):
        self.app, self.limit = app, limit

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        too_big = _json(413, f"request body larger than {self.limit} bytes")
        declared = dict(scope["headers"]).get(b"content-length")
        try:
            if declared is not None and int(declared) > self.limit:
                return await too_big(scope, receive, send)
        except ValueError:
            return await _json(400, "Content-Length is not a number")(scope, receive, send)
        chunks, seen = [], 0
        while True:
            msg = await receive()
            if msg["type"] != "http.request":  # the client went away
                return
            chunks.append(msg.get("body", b""))
            seen += len(chunks[-1])
            if seen > self.limit:
                return await too_big(scope, receive, send)
            if not msg.get("more_body"):
                break
        body, done = b"".join(chunks), False

        async def replay():
            nonlocal done
            if not done:
                done = True
                return {"type": "http.request", "body": body, "more_body": False}
            return await receive()  # after the body: wait for the disconnect, as ASGI does

        await self.app(scope, replay, send)


def _token_bytes(text: str) -> bytes:
    # surrogateescape: any str a client can send encodes, so a strange token is a 401, not a 500
    return text.encode("utf-8", "surrogateescape")


def install(app: FastAPI, settings: Settings) -> None:
    app.add_exception_handler(SceneError, lambda r, e: _json(422, str(e)))
    app.add_exception_handler(Invalid, lambda r, e: _json(422, str(e)))
    app.add_exception_handler(NotFound, lambda r, e: _json(404, str(e)))
    app.add_exception_handler(Conflict, lambda r, e: _json(409, str(e)))
    app.add_exception_handler(NotReady, lambda r, e: _json(503, str(e), {"Retry-After": "1"}))
    app.add_middleware(BodyLimit, limit=settings.max_body)
    if settings.token:
        token = _token_bytes(settings.token)

        @app.middleware("http")
        async def require_token(request: Request, call_next):
            given = (request.query_params.get("token") or request.cookies.get("q3t_token")
                     or request.headers.get("authorization", "").removeprefix("Bearer "))
            if not hmac.compare_digest(_token_bytes(given or ""), token):
                return _json(401, "missing or wrong token (?token=..., or Bearer header)")
            response = await call_next(request)
            if request.query_params.get("token"):
                response.set_cookie("q3t_token", settings.token, httponly=True,
                                    samesite="strict")
            return response

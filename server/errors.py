"""Errors become clear 4xx answers; oversize bodies 413; an optional access token."""

from __future__ import annotations

import hmac

from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse

from server.runs import Conflict
from server.settings import Settings
from sim.scene import SceneError


def _json(status: int, detail: str) -> JSONResponse:
    return JSONResponse({"detail": detail}, status_code=status)


class BodyLimit:
    """Pure ASGI middleware: 413 when the declared or streamed body exceeds ``limit`` bytes."""

    def __init__(self, app, limit: int):
        self.app, self.limit = app, limit

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        declared = dict(scope["headers"]).get(b"content-length")
        too_big = _json(413, f"request body larger than {self.limit} bytes")
        if declared and int(declared) > self.limit:
            return await too_big(scope, receive, send)
        seen = 0

        async def counted():
            nonlocal seen
            msg = await receive()
            seen += len(msg.get("body", b""))
            if seen > self.limit:
                raise _TooBig
            return msg

        try:
            await self.app(scope, counted, send)
        except _TooBig:
            await too_big(scope, receive, send)


class _TooBig(Exception):
    pass


def install(app: FastAPI, settings: Settings) -> None:
    app.add_exception_handler(SceneError, lambda r, e: _json(422, str(e)))
    app.add_exception_handler(ValueError, lambda r, e: _json(422, str(e)))
    app.add_exception_handler(KeyError, lambda r, e: _json(404, str(e.args[0])))
    app.add_exception_handler(Conflict, lambda r, e: _json(409, str(e)))
    app.add_middleware(BodyLimit, limit=settings.max_body)
    if settings.token:
        token = settings.token

        @app.middleware("http")
        async def require_token(request: Request, call_next):
            given = (request.query_params.get("token") or request.cookies.get("q3t_token")
                     or request.headers.get("authorization", "").removeprefix("Bearer "))
            if not hmac.compare_digest(given or "", token):
                return _json(401, "missing or wrong token (?token=..., or Bearer header)")
            response = await call_next(request)
            if request.query_params.get("token"):
                response.set_cookie("q3t_token", token, httponly=True, samesite="strict")
            return response

"""The page at ``/`` and its static files, from the ``web`` package."""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter
from fastapi.responses import FileResponse

import web
from server.problems import NotFound

router = APIRouter(tags=["web"], include_in_schema=False)
ROOT = Path(web.__file__).resolve().parent
FILES = {"app.js": "text/javascript", "form.js": "text/javascript", "style.css": "text/css"}


@router.get("/")
def index() -> FileResponse:
    return FileResponse(ROOT / "index.html", media_type="text/html")


@router.get("/static/{name}")
def static(name: str) -> FileResponse:
    if name not in FILES:
        raise NotFound(f"no file {name!r}")
    return FileResponse(ROOT / name, media_type=FILES[name])

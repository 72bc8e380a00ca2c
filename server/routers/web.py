"""The page at ``/`` and its static files, from the ``web`` package; the browser libraries it
uses from their Python packages (``/static/vendor``): the machines the page runs on often
reach no CDN."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from fastapi import APIRouter
from fastapi.responses import FileResponse

import web
from server.problems import NotFound

router = APIRouter(tags=["web"], include_in_schema=False)
ROOT = Path(web.__file__).resolve().parent
TYPES = {".js": "text/javascript", ".css": "text/css"}
# the page's own modules: every .js and .css file of the web package
FILES = {p.name: TYPES[p.suffix] for p in ROOT.iterdir() if p.suffix in TYPES}
# name -> (package, path in it): plotly's wheel ships plotly.js (the page's plots)
VENDOR = {"plotly.min.js": ("plotly", "package_data/plotly.min.js")}
# vendored files change only with their package's version: a browser may keep them a day
CACHED = {"Cache-Control": "public, max-age=86400"}


@router.get("/")
def index() -> FileResponse:
    return FileResponse(ROOT / "index.html", media_type="text/html")


@router.get("/static/{name}")
def static(name: str) -> FileResponse:
    if name not in FILES:
        raise NotFound(f"no file {name!r}")
    return FileResponse(ROOT / name, media_type=FILES[name])


@router.get("/static/vendor/{name}")
def vendor(name: str) -> FileResponse:
    if name not in VENDOR:
        raise NotFound(f"no file {name!r}")
    package, path = VENDOR[name]
    try:
        found = resources.files(package).joinpath(path)
    except ModuleNotFoundError:
        raise NotFound(f"{name}: the Python package {package!r} is not installed (pip "
                       "install 'q3t-forming[service]')") from None
    if not found.is_file():
        raise NotFound(f"{name}: not in the installed {package!r} package")
    return FileResponse(Path(str(found)), media_type=TYPES[Path(name).suffix], headers=CACHED)

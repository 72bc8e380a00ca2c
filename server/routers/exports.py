"""/api/runs/{id}/export/{format}: a run's results as files other tools read (sim.frames.export):
the probes as CSV, the final state and the saved frames as VTU with a PVD time series (a zip),
the formed part as STL or PLY, the summary as JSON. Made on request from the run's folder, in a
worker thread (the routes are plain functions): the server never blocks on one."""

from __future__ import annotations

import io
import tempfile
import zipfile
from pathlib import Path
from typing import Literal

from fastapi import APIRouter, Request, Response
from pydantic import BaseModel, Field

from server.errors import CheckedRoute, documented
from server.problems import Conflict, NotFound
from server.records import ACTIVE, Run
from server.runs import RunManager
from server.settings import RunId
from sim.frames import export

router = APIRouter(prefix="/api/runs", tags=["exports"], route_class=CheckedRoute)
Format = Literal[tuple(export.FORMATS)]
# the media type and file name (after the run's id) of each format's download
MEDIA = {"csv": ("text/csv; charset=utf-8", ".csv"), "json": ("application/json", "_summary.json"),
         "stl": ("model/stl", ".stl"), "ply": ("application/octet-stream", ".ply"),
         "vtu": ("application/zip", "_vtu.zip")}


class Export(BaseModel):
    format: str
    description: str
    url: str
    available: bool
    reason: str | None = Field(description="why it is not available (the run is still going, "
                               "or ended before it had a final state)")


class Exports(BaseModel):
    run: str
    formats: list[Export]


def _ended(request: Request, run_id: str) -> tuple[Run, Path]:
    """The run and its folder; 404 for no such run, 409 while it is going."""
    m: RunManager = request.app.state.manager
    run = m.get(run_id)
    if run.state in ACTIVE:
        raise Conflict(f"run {run_id!r} is {run.state}: its results are complete when it ends")
    return run, m.files.dir(run.id)


def _why_not(folder: Path, fmt: str) -> str | None:
    try:
        return export.missing(export.open_run(folder), fmt)
    except export.ExportError as exc:
        return str(exc)


@router.get("/{run_id}/exports", response_model=Exports, responses=documented(404, 422))
def exports(run_id: RunId, request: Request) -> dict:
    """The formats the run can be downloaded in, each with its URL, and why one is not
    available (a run still going has none yet)."""
    m: RunManager = request.app.state.manager
    run = m.get(run_id)
    folder = m.files.dir(run.id)
    going = f"the run is {run.state}: its results are complete when it ends"
    out = []
    for fmt, text in export.FORMATS.items():
        why = going if run.state in ACTIVE else _why_not(folder, fmt)
        out.append({"format": fmt, "description": text, "available": why is None,
                    "reason": why, "url": f"/api/runs/{run.id}/export/{fmt}"})
    return {"run": run.id, "formats": out}


@router.get("/{run_id}/export/{format}", response_class=Response, responses={
    **documented(404, 409, 422),
    200: {"description": "The file: CSV, JSON, STL, PLY, or a zip of the VTU files and their "
                         "PVD", "content": {m: {} for m, _ in MEDIA.values()}}})
def export_run(run_id: RunId, format: Format, request: Request) -> Response:
    """The run's results as ``format``: ``csv`` the probes per step (time, each punch's stroke
    and force, every probe; units in the header), ``vtu`` a zip of the final state and the
    frames the run saved as VTU with a ``.pvd`` time series for ParaView, ``stl`` / ``ply``
    the formed part (the closed surface of the deformed sheet, mm), ``json`` the summary.
    Lengths in mm, forces in kN, stresses in MPa."""
    run, folder = _ended(request, run_id)
    media, suffix = MEDIA[format]
    with tempfile.TemporaryDirectory(prefix="q3t-export-") as tmp:
        try:
            written = export.export(folder, format, Path(tmp))
        except export.ExportError as exc:  # no result.json or final.npz: nothing to export
            raise NotFound(str(exc)) from None
        data = _zip(Path(tmp), written) if format == "vtu" else written[0].read_bytes()
    return Response(data, media_type=media, headers={
        "Content-Disposition": f'attachment; filename="{run.id}{suffix}"'})


def _zip(root: Path, files: list[Path]) -> bytes:
    """The files, by their paths under ``root`` (the PVD names the VTU files so)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        for f in files:
            z.write(f, f.relative_to(root).as_posix())
    return buf.getvalue()

"""/api/runs/{id}/export/{format}: a run's results as files other tools read (sim.frames.export):
the probes as CSV, the final state and the saved frames as VTU with a PVD time series (a zip),
the formed part as STL or PLY, the summary as JSON. Made on request from the run's folder, in a
worker thread (the routes are plain functions): the server never blocks on one. And a PNG of the
3-D view, rendered by a browser that has it open (viser's render API: the server draws
nothing itself)."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal

from fastapi import APIRouter, Query, Request, Response
from pydantic import BaseModel, Field

from server.downloads import attachment, content, zipped
from server.errors import CheckedRoute, documented
from server.problems import Conflict, NotFound, NotReady
from server.records import ENDED, QUEUED, Run
from server.routers.view import ViewId
from server.runs import RunManager
from server.settings import RunId
from server.snapshot import with_legend
from sim.frames import export

if TYPE_CHECKING:
    from server.clientview import ClientView

router = APIRouter(prefix="/api/runs", tags=["exports"], route_class=CheckedRoute)
Format = Literal[tuple(export.FORMATS)]
VIEWER_OFF = "the viewer is off (the server runs without it): no 3-D view to capture"
PNG = "a PNG of the 3-D view as a browser shows it (its camera, colours and step)"
# s: a browser renders in software at a few frames a second; one that never answers is a 503
RENDER_TIMEOUT = 60.0
PNG_HEIGHT = 720  # px: the 3-D view's PNG at least this high
CAPTION_CHARS = 110  # a caption line's most: the image's width at 720 px high holds it


class Export(BaseModel):
    format: str = Field(description="csv, vtu, stl, ply, json, or png (the 3-D view)")
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
    if run.state not in ENDED:
        raise Conflict(f"run {run_id!r} is {run.state}: its results are complete when it ends")
    return run, m.files.dir(run.id)


def _why_not(folder: Path) -> dict[str, str | None]:
    """Why the run in ``folder`` cannot be exported in each format (None: it can)."""
    try:
        run = export.open_run(folder)
    except export.ExportError as exc:
        return dict.fromkeys(export.FORMATS, str(exc))
    return {fmt: export.missing(run, fmt) for fmt in export.FORMATS}


@router.get("/{run_id}/exports", response_model=Exports, responses=documented(404, 422))
def exports(run_id: RunId, request: Request, view: ViewId = None) -> dict:
    """The formats the run can be downloaded in, each with its URL, and why one is not
    available (a run still going has none yet). Asked with a view (``X-Q3T-View``), the PNG's
    URL names it: the image is that browser's 3-D view."""
    m: RunManager = request.app.state.manager
    run = m.get(run_id)
    folder = m.files.dir(run.id)
    going = f"the run is {run.state}: its results are complete when it ends"
    why_not = dict.fromkeys(export.FORMATS, going) if run.state not in ENDED else _why_not(folder)
    out = []
    for fmt, text in export.FORMATS.items():
        why = why_not[fmt]
        out.append({"format": fmt, "description": text, "available": why is None,
                    "reason": why, "url": f"/api/runs/{run.id}/export/{fmt}"})
    # the PNG needs a browser showing the run when it is asked for: offered while the viewer
    # is on (its answer says why not, if no browser shows the run then), and for an ended run
    # only if it has a state to show (one that failed before it had one draws nothing)
    why = _no_view(m, run) or (None if m.viewer else VIEWER_OFF)
    out.append({"format": "png", "description": PNG, "available": why is None, "reason": why,
                "url": f"/api/runs/{run.id}/export/png" + (f"?view={view}" if view else "")})
    return {"run": run.id, "formats": out}


def _clipped(text: str, most: int = CAPTION_CHARS) -> str:
    return text if len(text) <= most else text[: most - 1].rstrip("; ") + "…"


def _no_view(m: RunManager, run: Run) -> str | None:
    """Why the run's 3-D view has no sheet to capture, or None: a queued run is not shown
    yet, an ended one without a final state never was."""
    if run.state == QUEUED:
        return f"run {run.id!r} is queued: no view of it until it starts"
    return _why_not(m.files.dir(run.id))["stl"] if run.state in ENDED else None


def _viewer_client(m: RunManager, run_id: str, view: str | None) -> ClientView:
    """The view of the browser whose 3-D view shows ``run_id``: that of ``view`` if it does,
    else the newest connected; Conflict saying why there is none."""
    v = m.viewer
    if v is None:
        raise Conflict(VIEWER_OFF)
    if not v.clients:
        raise Conflict("no browser has the 3-D view open: the image is rendered by a "
                       "browser's viewer (open the page)")
    showing = v.showing(run_id)
    if not showing:
        raise Conflict(f"no browser's 3-D view shows run {run_id!r}: select the run first")
    return next((c for c in showing if c.view == view), showing[0])


# before /export/{format}, which would answer png with a 422
@router.get("/{run_id}/export/png", response_class=Response, responses={
    **documented(404, 409, 422, 503),
    200: {"description": "The 3-D view as PNG", "content": {"image/png": {}}}})
def view_png(run_id: RunId, request: Request, view: Annotated[str | None, Query(
        pattern=r"^[A-Za-z0-9_-]{1,64}$", description="the browser view (X-Q3T-View) whose "
        "3-D view to capture, when it shows the run")] = None) -> Response:
    """A PNG of the 3-D view of the run, as the browser that has it open shows it (its
    camera, colour mode and step), rendered by that browser: 409 when no browser shows the run
    (the viewer off, another run shown, no page open), 503 when it does not answer in time,
    404 for a run that ended without a state to show (its view would be empty)."""
    import imageio.v3 as iio  # viser's dependency, loaded with the viewer

    m: RunManager = request.app.state.manager
    run = m.get(run_id)
    if why := _no_view(m, run):
        raise (NotFound if run.state in ENDED else Conflict)(why)
    shown = _viewer_client(m, run.id, view)
    client = shown.client
    # the browser's camera at its canvas's shape, at least PNG_HEIGHT high (a canvas drawn at
    # a low pixel density, viewer_dpr=0.5, gave 345 x 259 px) and 4:3 wide (the page docks the
    # viewer's panel beside a narrow canvas; the camera's vertical field of view is kept)
    h0 = client.camera.image_height or PNG_HEIGHT
    h = max(h0, PNG_HEIGHT)
    w = max(round((client.camera.image_width or h0) * h / h0), h * 4 // 3)
    try:
        image = client.get_render(h, w,
                                  transport_format="png", timeout=RENDER_TIMEOUT)
    except TimeoutError:
        raise NotReady(f"the browser showing the 3-D view did not render it in "
                       f"{RENDER_TIMEOUT:g} s") from None
    # the browser renders the scene alone: the colour scale and what is shown drawn in
    frame = shown.canvas.frame
    step = "" if frame is None else \
        f", step {frame['step']} of {'?' if run.n_steps is None else run.n_steps}"
    caption = [f"{run.scene}: run {run.id}{step}"]
    if changes := run.changes():  # what it ran besides its saved scene, as the Runs table says
        caption.append(_clipped("as run: " + "; ".join(changes)))
    image = with_legend(image, shown.canvas.scale, caption)
    return attachment(iio.imwrite("<bytes>", image, extension=".png"), "png", run.id)


@router.get("/{run_id}/export/{format}", response_class=Response, responses={
    **documented(404, 409, 422),
    200: {"description": "The file: CSV, JSON, STL, PLY, or a zip of the VTU files and their "
                         "PVD", "content": content(list(export.FORMATS))}})
def export_run(run_id: RunId, format: Format, request: Request) -> Response:
    """The run's results as ``format``: ``csv`` the probes per step (time, each punch's stroke
    and force, every probe; units in the header), ``vtu`` a zip of the final state and the
    frames the run saved as VTU with a ``.pvd`` time series for ParaView, ``stl`` / ``ply``
    the formed part (the closed surface of the deformed sheet, mm), ``json`` the summary.
    Lengths in mm, forces in kN, stresses in MPa."""
    run, folder = _ended(request, run_id)
    with tempfile.TemporaryDirectory(prefix="q3t-export-") as tmp:
        try:
            written = export.export(folder, format, Path(tmp))
        except (export.ExportError, FileNotFoundError) as exc:
            if run.id not in request.app.state.manager.run_ids():  # its files went meanwhile
                raise NotFound(f"run {run.id!r} was deleted while it was exported") from None
            if isinstance(exc, FileNotFoundError):
                raise
            raise NotFound(str(exc)) from None  # no result.json or final.npz: nothing to export
        # the PVD names the VTU files by their paths under tmp
        data = zipped({f.relative_to(tmp).as_posix(): f for f in written}) \
            if format == "vtu" else written[0].read_bytes()
    return attachment(data, format, run.id)

"""/api/runs/{id}/split_ring: the split-ring (Demeri) springback test on a finished cup run,
as ``q3t splitring`` does it (sim.stepping.split_ring; saved by sim.frames.rings): cut a ring
(in a child process, server.rings), list the rings cut, in mm, % and degrees, and hand out a
ring's files (its VTU for ParaView, its npz) as the run's other downloads are
(server.downloads)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal
from urllib.parse import quote

from fastapi import APIRouter, Request, Response
from fastapi import Path as PathParam
from pydantic import BaseModel, ConfigDict, Field, field_validator

from server.downloads import attachment, content, zipped
from server.errors import BODY, CheckedRoute, documented
from server.problems import Invalid, NotFound
from server.rings import RingCutter, cuttable
from server.runs import RunManager
from server.settings import RunId
from sim.frames import rings

router = APIRouter(prefix="/api/runs", tags=["split ring"], route_class=CheckedRoute)
Finite = Annotated[float, Field(allow_inf_nan=False)]
RingFormat = Literal[tuple(rings.DOWNLOADS)]
RingName = Annotated[str, PathParam(description="the ring's name, as the run's list of rings "
                                    "gives it (``split_ring-8-13mm``): only those are served")]


class NewRing(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid", json_schema_extra={"examples": [
        {"heights": [8.0, 13.0], "cut_angle": 0.0}]})
    heights: Annotated[list[Finite], Field(min_length=2, max_length=2, description=(
        "the ring's lower and upper edge, mm above the cup's bottom (the lowest point of its "
        "formed mid-surface); both on the steep wall"))]
    cut_angle: Finite = Field(0.0, description="the split's meridian, degrees about the cup's "
                              "axis (z) from x, the rolling direction; taken modulo 360 (0 and "
                              "360 are the same ring)")

    @field_validator("heights")
    @classmethod
    def _increasing(cls, v: list[float]) -> list[float]:
        if not 0.0 <= v[0] < v[1]:
            raise ValueError(f"{v[0]:g}, {v[1]:g} mm: need 0 <= z1 < z2 (mm above the cup's "
                             "bottom)")
        return v

    @field_validator("cut_angle")
    @classmethod
    def _turn(cls, v: float) -> float:
        return rings.angle(v)


class Opening(BaseModel):
    at_mid_height: float = Field(description="the gap between the cut's faces along the "
                                 "ring's circumference at its mid-height, mm (> 0: it opened)")
    min: float = Field(description="its least value along the cut, mm")
    max: float = Field(description="its largest value along the cut, mm")
    distance_at_mid_height: float = Field(description="the straight distance between the "
                                          "faces at mid-height, mm")


class Diameters(BaseModel):
    mean: float = Field(description="twice the radius of the least-squares circle through "
                        "the ring's mid-surface, mm")
    d0: float = Field(description="across the cut's meridian (0 deg), mm")
    d90: float = Field(description="at 90 deg to it, mm")


class RingFile(BaseModel):
    format: str = Field(description="vtu (a zip of its VTU files and a PVD, for ParaView) or "
                        "npz")
    description: str
    url: str


class Ring(BaseModel):
    """A ring cut from the run (result.json's ``split_ring`` entry, SI, in these units)."""

    name: str = Field(description="its files' name in the run folder (<name>.npz, "
                      "<name>/ring_{formed,released,split}.vtu)")
    heights_mm: list[float]
    cut_angle_deg: float
    section_points: int | None = Field(description="points through the thickness the run "
                                       "integrated its stress on (None: a ring saved before "
                                       "they were recorded)")
    caution: str | None = Field(description="why the opening is not to be trusted as it is "
                                "(too few section points), or None")
    elements: int
    duplicated_nodes: int = Field(description="nodes duplicated along the cut")
    opening_mm: Opening
    diameters_mm: dict[str, Diameters] = Field(description="formed (in the tools), released "
                                               "(the closed ring cut out) and split")
    reyield_pct: dict[str, float] = Field(description="per release (closed, split): the % of "
                                          "the ring's quadrature points that yielded again")
    reyield_max_plastic_strain: dict[str, float] = Field(description="per release: the "
                                                         "largest growth of the plastic strain")
    solver: dict[str, dict] = Field(description="per release: Newton iterations, the force "
                                    "released (N), what the supports carry (N)")
    downloads: list[RingFile] = Field(description="the ring's files, each with its URL")


class CutRing(Ring):
    run: str


class Newton(BaseModel):
    iteration: int = Field(description="Newton iterations the release has made (0: the ring "
                           "as cut, before the first)")
    residual_N: float = Field(description="the out-of-balance force left at that iterate (the "
                              "norm of the residual on the free degrees of freedom), N")
    target_N: float = Field(description="the release has converged once the residual is below "
                            "this, N (a small fraction of the force the release frees)")


class Cutting(BaseModel):
    heights_mm: list[float]
    cut_angle_deg: float
    stage: str = Field(description="what is being done, in words: waiting for the process "
                       "that cuts rings (or starting it, or another run's ring), then reading "
                       "the cup's final state, cutting the band from the wall, releasing the "
                       "closed ring, splitting the ring along its meridian, releasing the split "
                       "ring, measuring the opening and the diameters, saving the ring into "
                       "the run")
    newton: Newton | None = Field(description="in a release: its last Newton iterate")
    elapsed_s: float = Field(description="seconds since the ring was asked for (its wait for "
                             "the process included)")


class Rings(BaseModel):
    run: str
    available: bool = Field(description="a ring can be cut from the run: a finished, plastic, "
                            "drawn cup (whether the heights are on its wall the cut says)")
    reason: str | None = Field(description="why not, when not available")
    wall_mm: list[float] | None = Field(description="how far the cup's steep wall reaches: "
                                        "the lowest and highest centroid of its elements "
                                        "steeper than 60 deg, mm above the bottom (about: the "
                                        "cut uses each element's own mid-surface)")
    cutting: Cutting | None = Field(description="the ring being cut now, if one is, and how "
                                    "far it has got")
    rings: list[Ring] = Field(description="the rings cut, by heights and cut angle")


def _run(request: Request, run_id: str) -> tuple[RunManager, object, Path]:
    m: RunManager = request.app.state.manager
    try:
        run = m.get(run_id)
    except NotFound as exc:
        raise NotFound(f"run_id: {exc}") from None
    return m, run, m.files.dir(run.id)


def _listed(run_id: str, s: dict) -> dict:
    """A ring's summary ``s`` (SI) as the API lists it: in an engineer's units, with the URL
    of each of its files."""
    r = rings.shown(s)
    base = f"/api/runs/{run_id}/split_ring/{quote(r['name'])}"
    return {**r, "downloads": [{"format": f, "description": text, "url": f"{base}/{f}"}
                               for f, text in rings.DOWNLOADS.items()]}


def _ring(folder: Path, run_id: str, ring: str) -> str:
    """``ring`` when the run in ``folder`` lists it (a name from the request is never made
    into a path otherwise); NotFound naming ``ring`` and the run's rings."""
    names = [rings.name_of(s) for s in rings.of_run(folder)]
    if ring not in names:
        raise NotFound(f"ring: {ring!r}: no such ring cut from run {run_id!r} (its rings: "
                       f"{', '.join(names) or 'none'})")
    return ring


@router.get("/{run_id}/split_ring", response_model=Rings, responses=documented(404, 422))
def list_rings(run_id: RunId, request: Request) -> dict:
    """The split rings cut from the run so far (``q3t splitring`` and this API write them
    into its result.json), each with its files' URLs, whether one can be cut, and the ring
    being cut now, if one is: its stage and the time it has taken so far (a page asks again
    every second or so while it waits for the POST)."""
    _, run, folder = _run(request, run_id)
    try:
        why, wall = cuttable(run.state, folder)
        cut = [_listed(run.id, s) for s in rings.of_run(folder)]
    except OSError:  # deleted since _run found it
        raise NotFound(f"run_id: {run.id}: its folder is gone") from None
    cutter: RingCutter = request.app.state.rings
    return {"run": run.id, "available": why is None, "reason": why, "wall_mm": wall,
            "cutting": cutter.progress(run.id), "rings": cut}


@router.post("/{run_id}/split_ring", response_model=CutRing,
             responses=documented(404, 409, *BODY))
async def cut_ring(run_id: RunId, body: NewRing, request: Request) -> dict:
    """Cut a ring from the finished cup's wall between ``heights`` (mm above its bottom),
    release it, split it along the meridian at ``cut_angle`` (deg, taken modulo 360) and
    release it again, as ``q3t splitring``; saved into the run (result.json's ``split_ring``,
    the same heights and cut replaced; its states as npz and VTU in the run folder). Answers
    when done (seconds to minutes). 409 while another ring is being cut from the run or the
    run is being deleted; 404 naming ``run_id`` when the run (or its folder) is gone; 422
    naming ``run_id`` (not a finished plastic cup, no final state), ``heights`` (not
    increasing, off the wall, not one closed ring; or a release that failed, with the
    solver's numbers: nothing is written) or ``cut_angle``. Meanwhile the GET lists the ring
    as ``cutting``, with its stage."""
    m, run, folder = _run(request, run_id)

    def check() -> None:
        # once the ring is marked as being cut: a DELETE before that has removed the run
        why, _ = cuttable(m.get(run.id).state, folder)
        if why:
            raise Invalid(f"run_id: {run.id}: {why}")

    cutter: RingCutter = request.app.state.rings
    summary = await cutter.cut(run.id, folder, body.heights, body.cut_angle, check)
    return {"run": run.id, **_listed(run.id, summary)}


# the ring's name may hold a "/" (a %2F): it reaches the check and is refused there, naming it
@router.get("/{run_id}/split_ring/{ring:path}/{format}", response_class=Response, responses={
    **documented(404, 422),
    200: {"description": "The file: a zip of the ring's VTU files and their PVD, or its npz",
          "content": content(list(rings.DOWNLOADS))}})
def ring_file(run_id: RunId, ring: RingName, format: RingFormat, request: Request) -> Response:
    """A ring's files, as ``q3t splitring`` and this API saved them: ``vtu`` a zip of its
    VTU files formed, released and split (mm), with a ``.pvd`` that steps through them in
    ParaView; ``npz`` its states (SI). Saved as ``<run>_<ring>_vtu.zip`` / ``<run>_<ring>.npz``.
    404 naming ``run_id`` (no such run, or its folder gone) or ``ring`` (not a ring the run
    lists)."""
    _, run, folder = _run(request, run_id)
    try:
        name = _ring(folder, run.id, ring)
        stem = f"{run.id}_{name}"
        data = rings.npz_file(folder, name).read_bytes() if format == "npz" else \
            zipped(rings.vtu_series(folder, name, stem))
    except FileNotFoundError:  # deleted since _run found it (a DELETE, or by hand)
        raise NotFound(f"ring: {ring!r}: its files are gone from the run's folder"
                       if folder.is_dir() else f"run_id: {run.id}: its folder is gone") from None
    return attachment(data, format, stem)

"""/api/runs/{id}/plots: what the page plots of a run (server.plots), live as steps arrive."""

from __future__ import annotations

import json

from fastapi import APIRouter, Request
from pydantic import BaseModel, Field

from server.errors import CheckedRoute, documented
from server.plots import plots
from server.records import ACTIVE
from server.settings import RunId

router = APIRouter(prefix="/api/runs", tags=["runs"], route_class=CheckedRoute)


class Series(BaseModel):
    unit: str = Field(description="the unit of ``values``: kN, mm, MPa, %, ... ('' a count)")
    values: list[float | None]


class PunchCurve(BaseModel):
    tool: str
    steps: list[int]
    force: Series = Field(description="the force resisting the punch's motion")
    stroke: Series | None = Field(description="its travel from the start along its direction "
                                  "of largest excursion; null for a punch that never moved")


class ProbeSeries(Series):
    name: str
    kind: str | None = Field(description="the probe's kind (sim.frames.probes), null: not "
                             "known (a run recorded before its probes' kinds were kept)")
    steps: list[int]
    si_unit: str | None = Field(description="the probe's SI unit (null: not known)")


class SectionStep(BaseModel):
    step: int
    position: Series = Field(description="rest radius of the section's vertices")
    thickness: Series


class Section(BaseModel):
    name: str
    angle: float | None = Field(None, description="its ray's angle from the x axis, deg (null "
                                "for a run recorded before sections said it)")
    steps: list[SectionStep]


class SheetSeries(BaseModel):
    steps: list[int]
    min_thickness: Series = Field(description="the least thickness over the vertices")
    max_thinning: Series = Field(description="the largest thinning over the vertices")


class Plots(BaseModel):
    run: str
    step: int
    stride: int = Field(description="every stride-th step is plotted (and the last): a long "
                        "run's plots are thinned to about 2000 points")
    punches: list[PunchCurve]
    probes: list[ProbeSeries]
    solver: dict[str, list[float | None]] = Field(description="steps, residual, iterations")
    parameter_log: list[dict] = Field(description="live parameter changes: {step (the first "
                                      "it applies to), name, value, label (as the page's "
                                      "slider names it)}")
    sections: list[Section] = Field(description="the scene's [[sections]] at their steps "
                                    "(once the run has written its result)")
    sheet: SheetSeries = Field(description="the sheet at each step, while the run goes (its "
                               "summary comes at the end)")
    forming_limits: bool = Field(description="its result has a forming limit diagram "
                                 "(/api/runs/{id}/forming_limits): a plastic run, finished")


@router.get("/{run_id}/plots", response_model=Plots, responses=documented(404, 422))
def run_plots(run_id: RunId, request: Request) -> dict:
    """The run's plots: each punch's force (kN) against its stroke (mm), each probe against
    the step in its unit, the solver's residual and iterations, the live parameter changes,
    and the thickness along the scene's sections (mm). Live runs: up to the last step made."""
    m = request.app.state.manager
    status = m.status(run_id)
    path = m.files.dir(status["id"]) / "result.json"
    result = None
    if path.is_file() and status["state"] not in ACTIVE:
        try:
            result = json.loads(path.read_text())
        except ValueError:  # being written by a solver that outlived its server: next time
            result = None
    return plots(status, result)

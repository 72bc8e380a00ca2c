"""/api/view: which run the page and the viewer show. One selection for every browser today
(the viewer is one viser scene); a new run is selected when it starts."""

from __future__ import annotations

from fastapi import APIRouter, Request
from pydantic import BaseModel, ConfigDict, Field

from server.errors import BODY, CheckedRoute, documented
from server.runs import RunManager
from server.settings import RunId

router = APIRouter(prefix="/api/view", tags=["view"], route_class=CheckedRoute)


class View(BaseModel):
    run: str | None = Field(description="the selected run's id (null: no runs)")


class Selection(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid", json_schema_extra={"examples": [{
        "run": "cantilever-q3t-20261122-101500-ab12"}]})
    run: RunId


def _runs(request: Request) -> RunManager:
    return request.app.state.manager


@router.get("", response_model=View)
def read_view(request: Request) -> dict:
    return _runs(request).view()


@router.put("", response_model=View, responses=documented(404, *BODY))
def select_run(body: Selection, request: Request) -> dict:
    """Show this run on the page (in every browser) and in the viewer: live if it is the
    latest run, else its recording."""
    return _runs(request).select(body.run)

"""/api/view: which run the page and the viewer show, or which scene the viewer previews before
any run. One selection for every browser today (the viewer is one viser scene); a new run is
selected when it starts."""

from __future__ import annotations

from fastapi import APIRouter, Request
from pydantic import BaseModel, ConfigDict, Field

from server.errors import BODY, CheckedRoute, documented
from server.runs import RunManager
from server.settings import RunId, SceneName

router = APIRouter(prefix="/api/view", tags=["view"], route_class=CheckedRoute)


class View(BaseModel):
    run: str | None = Field(description="the selected run's id (null: no runs)")
    scene: str | None = Field(None, description="the scene the viewer previews instead of the "
                                                "run (null: it shows the run)")
    preview: str | None = Field(None, description="the preview's state: building, shown or "
                                                  "failed (null: no preview)")
    preview_error: str | None = Field(None, description="why the preview failed to build")


class Selection(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid", json_schema_extra={"examples": [{
        "run": "cantilever-q3t-20261122-101500-ab12"}]})
    run: RunId


class ScenePreview(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid", json_schema_extra={"examples": [{
        "scene": "cup_drawing"}]})
    scene: SceneName
    toml: str | None = Field(None, description="the scene as the page shows it, edits not "
                                               "saved yet (null: the saved file)")


def _runs(request: Request) -> RunManager:
    return request.app.state.manager


@router.get("", response_model=View)
def read_view(request: Request) -> dict:
    """The run the page and the viewer show, or the scene the viewer previews instead."""
    return _runs(request).views.view()


@router.put("", response_model=View, responses=documented(404, *BODY))
def select_run(body: Selection, request: Request) -> dict:
    """Show this run on the page (in every browser) and in the viewer: live if it is the
    latest run, else its recording."""
    return _runs(request).views.select(body.run)


@router.put("/scene", response_model=View, responses=documented(404, 409, *BODY))
def preview_scene(body: ScenePreview, request: Request) -> dict:
    """Preview this scene in the viewer before any run: its blank and its tools at the start.
    Built by the solver process in the background (``preview`` in ``GET /api/view`` says when
    it is shown); the selected run stays selected and shows again when selected."""
    return _runs(request).views.show_scene(body.scene, body.toml)

"""/api/view: what a browser shows, the run selected on its page and in its viewer, or the
scene its viewer previews before any run. Each page names its own view with the
``X-Q3T-View`` header; a request without one (a script) uses the ``default`` view."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Header, Query, Request
from pydantic import BaseModel, ConfigDict, Field

from server.errors import BODY, CheckedRoute, documented
from server.runs import RunManager
from server.settings import RunId, SceneName

router = APIRouter(prefix="/api/view", tags=["view"], route_class=CheckedRoute)

# the page's view: an id it makes for its tab and also puts in its embedded viewer's address,
# so the page and that viewer show the same run while another browser's show their own
ViewId = Annotated[str | None, Header(
    alias="X-Q3T-View", pattern=r"^[A-Za-z0-9_-]{1,64}$",
    description="the browser page's view id (letters, digits, _ and -): the page and its "
                "embedded viewer show this view's run; without it the `default` view, which "
                "a viewer opened on its own port shows too")]


class Notice(BaseModel):
    model_config = ConfigDict(extra="allow")
    seq: int = Field(description="numbers the notices: ask with `since` for newer ones")
    run: str
    action: str = Field(description="pause, resume, step, stop, delete or set <parameter>")
    by: str = Field(description="who acted: another browser, or a script")
    at: float = Field(description="Unix time")
    step: int
    text: str = Field(description="the notice in words, as the page shows it")


class View(BaseModel):
    view: str = Field(description="the view's id (`default` without the header)")
    run: str | None = Field(description="the selected run's id (null: no runs)")
    scene: str | None = Field(None, description="the scene the viewer previews instead of the "
                                                "run (null: it shows the run)")
    preview: str | None = Field(None, description="the preview's state: building, shown or "
                                                  "failed (null: no preview)")
    preview_error: str | None = Field(None, description="why the preview failed to build")
    preview_edited: bool | None = Field(None, description="whether the preview shows edits "
                                        "not saved yet (`toml` in `PUT /api/view/scene`)")
    step: int | None = Field(None, description="the step this view's viewer shows after its "
                             "time slider was moved (null: the run's latest)")
    notices: list[Notice] = Field(default_factory=list, description=(
        "what other browsers or scripts did to the runs this view started (stop, pause, "
        "parameter changes, delete), after `since`"))


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


@router.get("", response_model=View, responses=documented(422))
def read_view(request: Request, view: ViewId = None,
              since: Annotated[int, Query(ge=0)] = 0) -> dict:
    """The run this view (the `X-Q3T-View` header; else the `default` view) shows on its page
    and in its viewer, or the scene its viewer previews instead; the step its viewer's time
    slider shows; the notices numbered above `since`."""
    return _runs(request).views.view(view, since)


@router.put("", response_model=View, responses=documented(404, *BODY))
def select_run(body: Selection, request: Request, view: ViewId = None) -> dict:
    """Show this run in this view (the `X-Q3T-View` header; else the `default` view): on its
    page and in its viewer, live if it is one of the latest runs, else its recording. Other
    browsers' views keep their own run."""
    return _runs(request).views.select(view, body.run)


@router.put("/scene", response_model=View, responses=documented(404, 409, *BODY))
def preview_scene(body: ScenePreview, request: Request, view: ViewId = None) -> dict:
    """Preview this scene in this view's viewer before any run: its blank and its tools at
    the start. Built by the solver process in the background (``preview`` in ``GET
    /api/view`` says when it is shown); the selected run stays selected and shows again when
    selected."""
    return _runs(request).views.show_scene(view, body.scene, body.toml)

"""/api/runs: start, list, status, pause/resume/step/stop, live parameters, result, recording,
delete. Every call returns at once; the solver process does the work."""

from __future__ import annotations

import json
from typing import Annotated, Literal

from fastapi import APIRouter, Query, Request, Response
from fastapi import Path as FastPath
from fastapi.responses import FileResponse
from pydantic import BaseModel, ConfigDict, Field

from server.errors import BODY, CheckedRoute, documented
from server.problems import Conflict, NotFound
from server.records import ACTIVE
from server.routers.view import ViewId
from server.runs import RunManager
from server.settings import RunId, SceneName

router = APIRouter(prefix="/api/runs", tags=["runs"], route_class=CheckedRoute)
# a list's integers stay integers (a section's steps; list[float] made them 0.0 and 2.0,
# which the scene then refused as not integers)
Scalar = float | int | bool | str | list[int | float]
RUN = documented(404, 422)  # any route naming a run


class NewRun(BaseModel):
    # strict: a JSON 0 is no boolean, as the schema says
    model_config = ConfigDict(strict=True, extra="forbid", json_schema_extra={"examples": [{
        "scene": "cantilever", "element": "linear", "overrides": {"mesh.edge_length": 0.035},
        "paused": True}]})
    scene: SceneName
    element: str | None = Field(default=None, min_length=1, description=(
        "the element to run (default: the scene's)"))
    overrides: dict[str, Scalar] = Field(default_factory=dict,
                                         description='scene overrides, e.g. {"material.nu": 0.3}')
    parameters: dict[str, float] = Field(default_factory=dict, description="live parameters")
    paused: bool = False
    toml: str | None = Field(default=None, description=(
        "the scene's text as the page shows it, edits not saved yet: validated as a saved "
        "scene is, it runs instead of the saved file (kept as the run's scene.toml; the run "
        "says `edited` when it differs from the saved scene)"))


class ParameterValue(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid",
                              json_schema_extra={"examples": [{"value": 1.5}]})
    value: float


class Progress(BaseModel):
    step: int = Field(description="steps done")
    steps: int | None = Field(description="steps of the run (release included); null while "
                              "it builds")
    fraction: float | None = Field(description="step / steps")
    elapsed_s: float | None = Field(description="wall time since the start, to the end once "
                                    "it ended (null for a run whose end was not recorded)")
    remaining_s: float | None = Field(description="the steps left at the mean wall time of "
                                      "those done: 0 once finished, null before the first "
                                      "step and for a run that ended early")


class RunSummary(BaseModel):
    """A run as the server holds it (fields added later pass through)."""

    model_config = ConfigDict(extra="allow")
    id: str
    scene: str
    element: str
    overrides: dict
    edited: bool = Field(default=False, description="it ran unsaved edits of its scene, not "
                         "the saved file (its scene.toml holds what ran)")
    edits: list[str] = Field(default_factory=list, description=(
        "what the unsaved edits changed of the saved scene, each setting as 'key saved → "
        "edited unit' in the form's units (empty when the saved scene no longer validates)"))
    created: float = Field(description="Unix time")
    state: Literal["queued", "starting", "building", "running", "paused", "finished",
                   "failed", "stopped", "cancelled"] = Field(description=(
        "queued: it waits for a solver process (``place``); cancelled: stopped or deleted "
        "while queued, or the server stopped before its turn: it never ran"))
    place: int | None = Field(None, description="its place in the run queue while queued "
                              "(1: the next to start), else null")
    reason: str | None = Field(description="why it failed or stopped, or a note")
    step: int
    n_steps: int | None
    estimate: dict | None = Field(description="a finished run's error estimate and cost")
    pending: list[str] = Field(description="commands sent to the solver that it has not acted "
                               "on yet, in order: empty once a pause has taken effect and a "
                               "step asked for is made")
    controls: list[Literal["pause", "resume", "step", "stop"]] = Field(
        default_factory=list, description=(
            "the commands that act on it now: pause while it runs, resume while it is paused "
            "or a pause is pending (the later of the two pending decides), step either way; "
            "stop while it is active or queued"))
    parameters: dict[str, float] = Field(default_factory=dict, description=(
        "every live parameter's value from the next step on (as the solver last said)"))
    progress: Progress
    stepping_s: float = Field(0.0, description=(
        "the wall time its steps took on the solver process, s: what runs compare by "
        "(progress.elapsed_s also holds the build, pauses and the viewer's pacing)"))
    changes: list[str] = Field(default_factory=list, description=(
        "what the run changed of its saved scene, in words, values in the scene form's units "
        "(mm, MPa, kN): unsaved edits, an element other than the scene's, overrides, live "
        "parameter values and the step each "
        "applied from"))
    override_units: dict[str, str | None] = Field(default_factory=dict, description=(
        "the SI unit of each override's scene field (null: none), as the scene schema gives "
        "it"))
    thinning_limit: float | None = Field(None, description=(
        "the material card's excessive-thinning limit (flc.max_thinning) in %, from which the "
        "3-D view's thinning bands start (failure from it, marginal from half of it); null "
        "without one or before the run is built"))
    started_by: str | None = Field(None, description=(
        "the view (browser page, `X-Q3T-View`) that started it; `default`: a script"))
    touched: list[dict] = Field(default_factory=list, description=(
        "pause, resume, step, stop and parameter changes from another view than the one that "
        "started it: {action, by, at, step, detail}"))


class Acted(RunSummary):
    notice: str | None = Field(None, description=(
        "set when the run was started by another view (browser or script): it was done all "
        "the same, and that view is told"))


class Shown(BaseModel):
    value: float
    unit: str = Field(description="kN, mm, %")
    flag: str | None = Field(None, description="a forming limit reached (SummaryEntry.flag)")


class RunListEntry(RunSummary):
    results: dict[str, Shown] = Field(default_factory=dict, description=(
        "of an ended run's result: peak_punch_force (the largest of its punches), "
        "min_thickness, max_thinning, forming_limit_margin (with its flag), as the page shows "
        "them; those the scene has"))


class ToolReport(BaseModel):
    """What a tool felt at the end of a step (sim.terms.tool_contact's report; SI). Every
    field optional: a run saved by an older version may lack one."""

    model_config = ConfigDict(extra="allow")
    fx: float | None = Field(None, description="force the sheet exerts on the tool, x (N)")
    fy: float | None = Field(None, description="the same, y (N)")
    fz: float | None = Field(None, description="the same, z (N)")
    contact_nodes: int | None = Field(None, description="nodes within the contact layer")
    penetration: float | None = Field(None, description="deepest penetration (m)")
    x: float | None = Field(None, description="the tool's position, x (m)")
    y: float | None = Field(None, description="y (m)")
    z: float | None = Field(None, description="z (m)")
    rx: float = Field(0.0, description="rotation vector, x (rad)")
    ry: float = Field(0.0, description="y (rad)")
    rz: float = Field(0.0, description="z (rad)")


class StepRecord(BaseModel):
    """One step as the solver made it (result.json's `steps` hold the same; SI units)."""

    model_config = ConfigDict(extra="allow")
    step: int
    time: float = Field(description="the scene's time at the step's end (s)")
    iterations: int = Field(description="Newton iterations of the step (its cut-backs' "
                            "included)")
    residual: float | None = Field(description="the residual's norm at the end (N)")
    energy: float | None = Field(description="the total energy at the end (J)")
    cutbacks: int = Field(description="times the step was halved")
    probes: dict[str, float | None] = Field(description="each probe's value (SI)")
    tools: dict[str, ToolReport] = Field(default_factory=dict, description="per tool")
    friction_change: float = Field(0.0, description="how far from settled friction's lagged "
                                   "normal forces are (relative; settled at 1e-3)")
    sheet: dict[str, float] = Field(default_factory=dict, description=(
        "the sheet at the step's end: min_thickness (m), max_thinning (a fraction) over its "
        "vertices"))


class Holder(BaseModel):
    id: str
    state: str


class RunStatus(RunSummary):
    records: list[StepRecord] = Field(description="step records after ``since``, in step "
                                      "order")
    waiting_for: list[Holder] = Field(default_factory=list, description=(
        "a queued run: the runs on the solver processes now, one of which it waits for (a "
        "paused one holds its solver until resumed or stopped); [] otherwise"))
    records_left: int = Field(description="records after these: ask again from the last step")


class ParameterAnswer(BaseModel):
    run: str
    name: str
    value: float
    applied: bool = Field(description="the solver has answered (else it is inside a step)")
    applies_from_step: int | None
    detail: str | None = None
    notice: str | None = Field(None, description=(
        "set when the run was started by another view (browser or script): changed all the "
        "same, and that view is told"))


class KeptFrames(BaseModel):
    run: str | None
    steps: list[int]
    stride: int = Field(description="every stride-th step is kept")
    bytes: int
    max_frames: int
    max_bytes: int


class FrameStats(BaseModel):
    step: int
    time: float
    n_vertices: int
    tools: dict[str, list[float]] = Field(description="each tool's translation")
    fields: dict[str, dict[str, float]] = Field(description="min, max and mean of each field")
    bounds: list[list[float]]
    probes: dict


# what a new run's id leads to (OpenAPI links: clients and fuzzers follow them); not
# forming_limits, which only a plastic scene's run has (a link promises the resource)
RUN_LINKS = {op: {"operationId": op, "parameters": {"run_id": "$response.body#/id"}}
             for op in ("status", "pause", "resume", "step", "stop", "set_parameter", "result",
                        "summary", "scene", "frames", "recording", "delete_run")}


def _runs(request: Request) -> RunManager:
    return request.app.state.manager


@router.get("", response_model=list[RunListEntry])
def list_runs(request: Request) -> list[dict]:
    """Every run the runs folder holds, newest first, as `GET /api/runs/{id}` gives it
    without its step records, and with what the page's Runs table shows (one request for the
    whole table): ``results``, the headline values of its result."""
    return _runs(request).list()


@router.post("", status_code=201, response_model=RunSummary,
             responses={201: {"links": RUN_LINKS}, **documented(404, 429, 503, *BODY)})
def start_run(body: NewRun, request: Request, view: ViewId = None) -> dict:
    """Start a run of the saved scene, or of ``toml`` (the page's unsaved edits): at once on
    a free solver process, else it is ``queued`` (its ``place`` says where) and starts when
    the runs before it have; 429 when the queue is full. The new run is the selected one of
    the view that started it (``X-Q3T-View``, else the `default` view; ``/api/view``)."""
    run = _runs(request).start_run(body.scene, body.element, body.overrides, body.parameters,
                                   body.paused, body.toml, by=view)
    return run.summary()


# exclude_unset: a step record saved by an older version keeps the fields it has, none
# made up from the model's defaults
@router.get("/{run_id}", response_model=RunStatus, response_model_exclude_unset=True,
            responses=RUN)
def status(run_id: RunId, request: Request, since: int = 0,
           limit: Annotated[int, Query(ge=1, le=100_000)] = 1000) -> dict:
    """The run's state and its step records after step ``since``, at most ``limit`` of them
    (``records_left`` says how many more there are: ask again from the last step returned);
    for a finished run also ``estimate``: its error from a study of the scene (``q3t study``)
    and its cost."""
    return _runs(request).status(run_id, since, limit)


def _command(request: Request, run_id: str, cmd: str, view: str | None) -> dict:
    """The command done, and a ``notice`` when the run is another view's (its starter is
    told: ``server.views``); header ``X-Q3T-View``: the view that asks."""
    m = _runs(request)
    out = m.command(run_id, cmd)
    return {**out, "notice": m.views.acted(m.get(run_id), cmd, view)}


@router.post("/{run_id}/pause", response_model=Acted,
             responses=documented(409, 404, 422))
def pause(run_id: RunId, request: Request, view: ViewId = None) -> dict:
    """Pause after the current step."""
    return _command(request, run_id, "pause", view)


@router.post("/{run_id}/resume", response_model=Acted,
             responses=documented(409, 404, 422))
def resume(run_id: RunId, request: Request, view: ViewId = None) -> dict:
    """Go on stepping a paused run, or a run started paused once it is built (409 when it
    is running or is over)."""
    return _command(request, run_id, "resume", view)


@router.post("/{run_id}/step", response_model=Acted,
             responses=documented(409, 404, 422))
def step(run_id: RunId, request: Request, view: ViewId = None) -> dict:
    """One step, then paused (a running run pauses after its current step)."""
    return _command(request, run_id, "step", view)


@router.post("/{run_id}/stop", response_model=Acted,
             responses=documented(409, 404, 422))
def stop(run_id: RunId, request: Request, view: ViewId = None) -> dict:
    """Stop the run: it ends as ``stopped``, with its result.json and a closed recording. A
    queued run is cancelled: it ends as ``cancelled`` and never starts."""
    return _command(request, run_id, "stop", view)


@router.put("/{run_id}/parameters/{name}", status_code=202, response_model=ParameterAnswer,
            responses=documented(404, 409, 503, *BODY))
def set_parameter(run_id: RunId, name: str, body: ParameterValue, request: Request,
                  view: ViewId = None) -> dict:
    """Applied from the next step. Waits briefly for the solver: ``applied`` and
    ``applies_from_step`` say from which step it acts (the step is also in the run's
    ``parameter_log``); a solver inside a long step answers later (``applied`` false).
    ``notice``: the run was started by another view (``X-Q3T-View``), which is told."""
    m = _runs(request)
    out = m.set_parameter(run_id, name, body.value)
    return {**out, "notice": m.views.acted(m.get(run_id), f"set {name}", view,
                                           f" to {body.value:g}")}


class Measure(BaseModel):
    value: float | list[float]
    unit: str = Field(description="SI: N, m, 1 (a ratio), deg")
    display: dict = Field(description="the same value in the unit the page shows: "
                          '{"value", "unit"} in kN, mm, %, deg')


class SummaryEntry(Measure):
    """One quantity of the run summary (sim.frames.summary)."""

    model_config = ConfigDict(extra="allow")
    name: str = Field(description="e.g. peak_punch_force, min_thickness, max_draw_in")
    label: str
    at: dict = Field(description="where or when: step and vertex as numbers, stroke, point "
                     "and the like as a Measure")
    tool: str | None = Field(None, description="the punch, for a punch's quantity")
    note: str | None = Field(None, description="how the quantity is defined, where needed")
    flag: str | None = Field(None, description=(
        "a forming limit reached: 'marginal' or 'failure' of the forming limit margin, "
        "'failure' of the maximum thinning at the material card's flc.max_thinning; 'mesh' of "
        "an earing whose rim's six-fold wave (a blank meshed in one lattice) outgrows its four "
        "ears; null when none is"))


class RunResultSummary(BaseModel):
    run: str
    converged: bool
    step: int = Field(description="the last step the run made: the state summarised")
    summary: list[SummaryEntry] = Field(description="what applies to the scene, in order")


class FormingLimits(BaseModel):
    """The forming limit diagram at the end of the stroke (sim.frames.forming_limits)."""

    model_config = ConfigDict(extra="allow")
    run: str
    strain: str
    step: int
    minor: list[float] = Field(description="per element, true strain")
    major: list[float] = Field(description="per element, true strain")
    curve: dict | None = Field(description="the forming limit curve {kind, minor, major, flc0}"
                               ", null without one in the material card")
    zone: list[int] | None = Field(None, description="per element zone code (with a curve)")
    zones: dict[str, str] | None = Field(None, description="zone code -> name")
    zone_counts: dict[str, int] | None = None
    margin: float | None = Field(None, description="marginal zone: this far below the curve")
    insufficient_stretch: float | None = None
    warnings: list[str] = Field(default_factory=list, description=(
        "why the curve may not hold for this material card (a correlation used outside the "
        "range it was fitted on), each naming the scene field"))


def _result(request: Request, run_id: str) -> tuple[RunManager, object, dict]:
    m = _runs(request)
    run = m.get(run_id)
    path = m.files.dir(run.id) / "result.json"
    if not path.is_file():
        raise NotFound(f"run {run_id!r} has no result yet")
    return m, run, json.loads(path.read_text())


@router.get("/{run_id}/result", responses=RUN)
def result(run_id: RunId, request: Request) -> dict:
    """The run's result.json, with ``estimate`` as in the status."""
    m, run, res = _result(request, run_id)
    return {**res, "estimate": m.estimates.get(run)}


@router.get("/{run_id}/summary", response_model=RunResultSummary, responses=RUN)
def summary(run_id: RunId, request: Request) -> dict:
    """The run's summary (result.json's ``summary``): peak punch force and its stroke,
    thinning, draw-in, part height, wrinkles, springback, volume change, as the scene has
    them; SI values with their display values (kN, mm, %)."""
    _, run, res = _result(request, run_id)
    steps = res.get("steps") or []
    return {"run": run.id, "converged": bool(res.get("converged")),
            "step": steps[-1]["step"] if steps else 0, "summary": res.get("summary") or []}


@router.get("/{run_id}/forming_limits", response_model=FormingLimits, responses=RUN)
def forming_limits(run_id: RunId, request: Request) -> dict:
    """The forming limit diagram of the run's end of stroke: each element's minor and major
    true strain, and with a forming limit curve in the material card the curve and each
    element's zone (0 safe, 1 insufficient stretch, 2 wrinkling tendency, 3 marginal,
    4 failure)."""
    _, run, res = _result(request, run_id)
    fl = res.get("forming_limits")
    if fl is None and not res.get("steps"):
        why = (res.get("failure") or {}).get("reason")
        raise NotFound(f"run {run_id!r} has no forming limits: it ended before its first step"
                       + (f" ({why})" if why else ""))
    if fl is None:
        raise NotFound(f"run {run_id!r} has no forming limits (its material is not plastic)")
    return {"run": run.id, **fl}


# response_class Response, as for the recording: the errors stay documented as JSON
@router.get("/{run_id}/scene", response_class=Response, responses={
    **RUN, 200: {"content": {"text/plain": {}}, "description": "The scene as it ran"}})
def scene(run_id: RunId, request: Request) -> Response:
    """The scene's TOML as the run ran it (its scene.toml: with unsaved edits when
    ``edited``)."""
    m = _runs(request)
    path = m.files.dir(m.get(run_id).id) / "scene.toml"
    if not path.is_file():
        raise NotFound(f"run {run_id!r} has no scene.toml")
    return Response(path.read_text(), media_type="text/plain; charset=utf-8")


@router.get("/{run_id}/frames", response_model=KeptFrames, responses=RUN)
def frames(run_id: RunId, request: Request) -> dict:
    """The steps whose frames the server keeps (of the latest runs only, one per solver
    process; every k-th when long)."""
    m = _runs(request)
    return m.history.kept(m.get(run_id).id).summary()


@router.get("/{run_id}/frames/{step}", response_model=FrameStats, responses=RUN)
def frame(run_id: RunId, step: Annotated[int, FastPath(ge=0, description="0: the rest state")],
          request: Request) -> dict:
    """One kept frame (the one at ``step`` or the nearest before): tool translations, probes,
    and each field's min, max and mean over the display vertices."""
    m = _runs(request)
    f = m.history.at(m.get(run_id).id, step)
    return {"step": f["step"], "time": f["time"], "n_vertices": len(f["positions"]),
            "tools": {k: [float(x) for x in v] for k, v in f["tools"].items()},
            "fields": {k: {"min": float(v.min()), "max": float(v.max()), "mean": float(v.mean())}
                       for k, v in f["fields"].items()},
            "bounds": [[float(x) for x in f["positions"].min(0)],
                       [float(x) for x in f["positions"].max(0)]],
            "probes": f["probes"]}


@router.get("/{run_id}/recording", response_class=FileResponse, responses={
    **documented(404, 409, 422), 200: {"content": {"application/octet-stream": {}},
                                       "description": "The run's rerun recording (run.rrd)"}})
def recording(run_id: RunId, request: Request) -> FileResponse:
    """The recording of a run that has ended (an active run's grows while it is sent: its
    length would not match what was promised, and the file would end mid-record)."""
    m = _runs(request)
    run = m.get(run_id)
    if run.state in ACTIVE:
        raise Conflict(f"run {run_id!r} is {run.state}: its recording is complete when it "
                       "ends")
    path = m.files.recording(run.id)
    if not path.is_file():
        raise NotFound(f"run {run_id!r} has no recording")
    return FileResponse(path, media_type="application/octet-stream", filename=f"{run_id}.rrd")


@router.delete("/{run_id}", status_code=204, responses=documented(404, 409, 422))
def delete_run(run_id: RunId, request: Request, view: ViewId = None) -> Response:
    """Delete a run that has ended and its folder (scene, results, recording), or a queued
    one (it never starts); 409 while it is active (stop it first) or a split ring is being
    cut from it. A run another view (``X-Q3T-View``) started is deleted all the same: that
    view is told, and the answer's ``X-Q3T-Notice`` header says so."""
    m = _runs(request)
    with request.app.state.rings.deleting(run_id):  # a ring's child writes into its folder
        notice = m.delete(run_id, by=view)
    return Response(status_code=204, headers={"X-Q3T-Notice": notice} if notice else None)

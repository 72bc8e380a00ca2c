"""/api/compare: runs side by side (server.compare); /api/sweeps and /api/sweeps/import: the
cases of a ``q3t sweep`` opened as runs to compare (server.sweeps)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, Request, Response
from pydantic import BaseModel, ConfigDict, Field

from server import compare as cmp
from server import compare_frames, sweeps
from server.downloads import attachment
from server.errors import BODY, CheckedRoute, documented
from server.routers.plots import ProbeSeries, PunchCurve

router = APIRouter(tags=["compare"], route_class=CheckedRoute)
RUNS = Annotated[str, Query(description="run ids, comma-separated: the first is the "
                                        "reference (A), the others B, C, ...",
                            examples=["press-linear-20261202-101500-ab12,"
                                      "press-q3t-20261202-101700-cd34"])]

STROKE = Annotated[float | None, Query(description="punch stroke, mm, within the range both "
                                       "runs saved frames for; omitted: the deepest stroke "
                                       "both reached")]


class ComparedRun(BaseModel):
    id: str
    letter: str = Field(description="A for the reference, then B, C, ...")
    scene: str
    element: str
    state: str
    step: int
    n_steps: int | None
    overrides: dict
    edited: bool
    result: bool = Field(description="its result.json is there: false while it runs (it is "
                         "compared as far as it has got) or when it ended without one")
    note: str | None = Field(description="why a run is compared only in part, or its reason")
    comparable: bool = Field(description=(
        "its summary is of the same stage as A's (both finished, or both ended at the same "
        "step): false, and its differences from A are null but for the mesh's size"))


class Difference(BaseModel):
    what: str = Field(description="scene, or a setting's dotted key (tools.punch.friction)")
    values: list = Field(description="one per run, in order (null: not set)")
    unit: str | None = Field(None, description="the setting's SI unit as the scene file has "
                             "it (m, Pa, N, rad, 1; null for the scene and unitless fields); "
                             "the line shows it in mm, MPa, kN, deg")


class Differences(BaseModel):
    line: str = Field(description="what differs, in a sentence")
    items: list[Difference]
    live: dict[str, list[dict]] = Field(description="per run letter, its live parameter "
                                        "changes {step (the first it applies to), name, value}")
    edited: list[str] = Field(description="letters of the runs that ran unsaved edits")


class SummaryRow(BaseModel):
    name: str
    label: str
    tool: str | None
    unit: str = Field(description="of values and delta (kN, mm, %, s; '' a count)")
    values: list[float | None] = Field(description="one per run (null: not in its result)")
    at: list[str | None] = Field(description="where or when each run's value was found")
    flags: list[str | None] = Field(description="each run's flag of its value (failure, "
                                    "marginal: the forming limit; mesh: the mesh's pattern "
                                    "more than the part's, as an isotropic cup's earing)")
    note: str | None = None
    delta: list[float | None] = Field(description="each run's value minus the reference's")
    delta_pct: list[float | None] = Field(description="delta relative to the reference's "
                                          "value, %; null on a row whose unit is % (its "
                                          "delta is in points)")


class ComparedPunch(PunchCurve):
    run: str
    letter: str


class ComparedProbe(ProbeSeries):
    run: str
    letter: str


class ThicknessAvailable(BaseModel):
    a: str
    b: str
    available: bool = Field(description="A and B have a thickness-difference map")
    reason: str | None = Field(description="why not: a run without a final state, meshes "
                               "that differ")


class Comparison(BaseModel):
    runs: list[ComparedRun]
    differs: Differences
    punches: list[ComparedPunch] = Field(description="each run's punch force (kN) against its "
                                         "stroke (mm)")
    probes: list[ComparedProbe] = Field(description="each run's probes against the step")
    summary: list[SummaryRow]
    thickness: ThicknessAvailable = Field(description="for the first two runs")


class Part(BaseModel):
    id: str
    letter: str
    faces: list[list[int]] = Field(description="mid-surface triangles")
    rest: list[list[float]] = Field(description="mid-surface vertices at rest, mm")
    formed: list[list[float]] = Field(description="mid-surface vertices at the end, mm")
    thickness: list[float] = Field(description="per vertex at the end, mm")


class ThicknessDifference(BaseModel):
    available: bool
    reason: str | None
    values: list[float] | None = Field(description="A - B per vertex of A, mm")
    max_abs: float | None


class Thickness(BaseModel):
    unit: str
    a: Part
    b: Part
    range: list[float] = Field(description="thickness range of both, mm: one colour scale")
    difference: ThicknessDifference


class FrameAt(BaseModel):
    step: int
    stroke: float = Field(description="the punch's stroke at that step, mm")


class SavedFrames(BaseModel):
    id: str
    letter: str
    tool: str = Field(description="the punch whose stroke the frames are matched by")
    frames: list[FrameAt] = Field(description="the frames the run saved during its loading")


class PartAtStroke(BaseModel):
    id: str
    letter: str
    step: int = Field(description="of the run's saved frame nearest the stroke asked for")
    stroke: float = Field(description="the punch's stroke at that frame, mm")
    time: float = Field(description="scene time of that frame, s")
    faces: list[list[int]] = Field(description="mid-surface triangles")
    formed: list[list[float]] = Field(description="mid-surface vertices at that frame, mm")
    thickness: list[float] = Field(description="per vertex at that frame, mm")


class AtStroke(BaseModel):
    unit: str
    stroke: float = Field(description="the stroke asked for (or the deepest in common), mm")
    range: list[float] = Field(description="the strokes both runs saved frames for, mm")
    runs: list[SavedFrames]
    box: list[list[float]] = Field(description="the extent of every saved frame of both, mm "
                                   "([[x0, x1], [y0, y1], [z0, z1]]): one box for all strokes")
    a: PartAtStroke
    b: PartAtStroke
    thickness_range: list[float] = Field(description="thickness range of both at these "
                                         "frames, mm: one colour scale")
    difference: ThicknessDifference


class SweepInfo(BaseModel):
    path: str = Field(description="the sweep's folder inside the runs folder")
    scene: str
    grid: dict
    complete: bool
    cases: int
    with_results: int = Field(description="cases whose folder can be opened as a run")
    imported: int = Field(description="of those, already runs")


class SweepImport(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid",
                              json_schema_extra={"examples": [{"path": "sweep-friction"}]})
    path: str = Field(min_length=1, max_length=300, description="the sweep's folder inside "
                      "the runs folder (q3t sweep ... --out runs/<path>)")


class Skipped(BaseModel):
    case: int
    reason: str


class Imported(BaseModel):
    sweep: str
    imported: list[str] = Field(description="run ids made now")
    present: list[str] = Field(description="run ids imported before")
    skipped: list[Skipped] = Field(description="cases without a complete folder, and why")


@router.get("/api/compare", response_model=Comparison, responses=documented(404, 422))
def compare(runs: RUNS, request: Request) -> dict:
    """Two or more runs side by side: what differs (scene, element, settings, live
    changes), each run's punch force against stroke and probes, their summaries with each
    run's difference from the first (A), and whether A and B have a thickness-difference map.
    A run still going is compared up to its last step (``result`` false, ``note``)."""
    m = request.app.state.manager
    return cmp.compare(cmp.load(m, cmp.run_ids(runs)))


@router.get("/api/compare/summary.csv", response_class=Response, responses={
    **documented(404, 422), 200: {"description": "the summary table as CSV",
                                  "content": {"text/csv": {}}}})
def summary_csv(runs: RUNS, request: Request) -> Response:
    """The comparison's summary table (each quantity per run, each run's difference from A)
    as a CSV file, values in the units the page shows (kN, mm, %)."""
    m = request.app.state.manager
    loaded = cmp.load(m, cmp.run_ids(runs))
    # named by its runs ("compare-A-and-1" said which was A only)
    name = (f"compare-{loaded[0].id}-{loaded[1].id}" if len(loaded) == 2
            else f"compare-{loaded[0].id}-and-{len(loaded) - 1}-more")
    return attachment(cmp.summary_csv(loaded).encode(), "csv", name)


@router.get("/api/compare/thickness", response_model=Thickness,
            responses=documented(404, 409, 422))
def thickness(runs: RUNS, request: Request) -> dict:
    """The final thickness of the first two runs (A, B) on their formed and rest mid-surfaces
    (mm), and A - B where their meshes are the same (else ``difference.reason`` says why).
    409 for a run without a final state (running, or ended before it had one)."""
    m = request.app.state.manager
    a, b, *_ = cmp.load(m, cmp.run_ids(runs))
    return cmp.thickness(a, b)


@router.get("/api/compare/frames", response_model=AtStroke,
            responses=documented(404, 409, 422))
def compare_at_stroke(runs: RUNS, request: Request, stroke_mm: STROKE = None) -> dict:
    """The first two runs (A, B) at the same punch stroke: each run's saved frame nearest
    ``stroke_mm`` (matched by stroke, not step: runs of another speed or step count reach a
    stroke at other steps) with its own stroke and step, its deformed mid-surface and
    thickness (mm), and A - B where the meshes are the same; each run's saved frames by
    stroke. 409 for a run without saved frames (queued, or a sweep case written without
    them); 422 for a stroke outside the range both saved."""
    m = request.app.state.manager
    a, b, *_ = cmp.load(m, cmp.run_ids(runs))
    return compare_frames.at_stroke(a, b, stroke_mm)


@router.get("/api/sweeps", response_model=list[SweepInfo])
def list_sweeps(request: Request) -> list[dict]:
    """The ``q3t sweep`` folders inside the runs folder, and how many of their cases are runs
    already."""
    m = request.app.state.manager
    return sweeps.find(m.files.root, set(m.run_ids()))


@router.post("/api/sweeps/import", response_model=Imported,
             responses=documented(404, *BODY))
def import_sweep(body: SweepImport, request: Request) -> dict:
    """Open the cases of a ``q3t sweep`` written inside the runs folder as runs, to compare
    them: each case with a result becomes a finished (or failed) run; a case imported before
    stays as it is."""
    m = request.app.state.manager
    # the copies outside the lock (the bridge takes it at every step); of two imports at once
    # one makes each run, the other finds it present
    new, report = sweeps.import_sweep(m.files.root, body.path, set(m.run_ids()))
    with m.lock:
        for run in new:
            m.runs[run.id] = run
    if m.viewer and new:
        m.viewer.set_runs(m.run_ids())
    return report

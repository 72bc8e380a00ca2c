"""/api/studies: a refinement study (``q3t study``) of a finished run's scene, from the page:
its plan and predicted cost first, then the study in a process of its own, its progress and a
cancel (server.studies). Its report gives the scene's runs their error estimate."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated, Literal

from fastapi import APIRouter, Request
from pydantic import BaseModel, ConfigDict, Field

from server import studies
from server.errors import BODY, CheckedRoute, documented
from server.problems import Invalid, NotFound
from server.records import Run
from server.runs import RunManager
from server.settings import RunId
from server.store import SceneStore

router = APIRouter(prefix="/api/studies", tags=["studies"], route_class=CheckedRoute)
Finite = Annotated[float, Field(allow_inf_nan=False)]


class Reference(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid")
    element: str = Field(description="the reference run's element (quadratic, as a rule)")
    edge_mm: Finite = Field(description="its mesh edge length, mm")


class Asked(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid", json_schema_extra={"examples": [
        {"run": "20261207-120000-cup_drawing", "levels_mm": [8, 4, 2]}]})
    run: RunId = Field(description="a finished run: its scene is studied, its time predicts "
                       "the cases'")
    elements: Annotated[list[str], Field(min_length=1, max_length=8)] | None = Field(
        None, description="the elements studied (default: the scene's study table's and the "
        "run's own)")
    levels_mm: Annotated[list[Finite], Field(min_length=1, max_length=8)] | None = Field(
        None, description="mesh edge lengths, mm (default: the scene's, or 4, 2 and 1 times "
        "its own)")
    reference: Reference | None = Field(None, description="the numerical reference run "
                                        "(default: the scene's, or the quadratic prism at half "
                                        "the finest level)")


class Which(BaseModel):
    element: str
    edge_mm: float
    reference: bool = Field(description="the reference run: every case's error is against it")
    dofs: int


class Case(Which):
    asking_run: bool = Field(False, description=(
        "the asking run's own element and level: its DoFs are the run's; the others' are "
        "counted from the mesh parameters (an outline's from its area, within a few %)"))
    memory_gib: float = Field(description="the build's peak memory, GiB (sim.model.size)")
    predicted_s: float = Field(description="seconds, predicted from the asking run's")


class Plan(BaseModel):
    scene: str
    probe: str | None = Field(description="what each case's error is measured on")
    elements: list[str]
    levels_mm: list[float]
    reference: Reference | None
    analytic: dict | None = Field(description="a closed-form or published reference instead "
                                  "of a run")
    cases: list[Case]
    predicted_s: float = Field(description="the whole study, seconds, its warm-up included")
    largest_gib: float = Field(description="the largest case's build, GiB")
    basis: dict = Field(description="the run the times are predicted from: run, element, "
                        "dofs, seconds")
    notes: list[str]
    command: str = Field(description="the same study from the command line")


class Done(Which):
    status: str = Field(description="converged, failed, timeout, ... (the case's run)")
    seconds: float = Field(description="its build and solve, as the study times it")


class Progress(BaseModel):
    scene: str
    state: Literal["running", "finished", "failed", "cancelled"]
    done: int = Field(description="cases finished, the reference among them")
    cases: int
    elapsed_s: float
    predicted_s: float
    now: Case | None = Field(description="the case running now, as the plan gave it (the "
                             "study runs them in the plan's order, one at a time)")
    finished: list[Done] = Field(description="the cases done, as the command said")
    reason: str | None = Field(description="why it failed or was cancelled")
    had_report: bool = Field(description="the scene had a study report before this one (a "
                             "study cancelled or failed leaves it)")
    command: str


class Current(BaseModel):
    study: Progress | None = Field(description="the study running, or the last one run since "
                                   "the server started")


def _scene_ran(run: Run, m: RunManager, store: SceneStore) -> tuple[Path, str]:
    """The scene file a study of ``run`` reads and its text: the saved scene's, or for a run
    of unsaved edits a copy of what it ran (its scene.toml) named as the scene, which the
    study's report names (its estimate is found by that name), beside the study's report."""
    if not run.edited:
        path = store.path(run.scene)
        if not path.is_file():
            raise NotFound(f"run: its scene {run.scene!r} is no longer in the scenes folder")
        return path, store.text(run.scene)
    try:
        text = (m.files.dir(run.id) / "scene.toml").read_text()
    except OSError as exc:
        raise NotFound(f"run: {run.id} has no scene.toml of the edits it ran ({exc})") from None
    path = m.files.root / f"study-{run.scene}" / f"ran-{run.id}" / f"{run.scene}.toml"
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".toml.tmp")  # a study of the same run may be reading it
    tmp.write_text(text)
    os.replace(tmp, path)
    return path, text


def _plan(body: Asked, request: Request) -> tuple[dict, object, dict]:
    """The plan of ``body`` (Invalid / NotFound naming the field), the scene's file and the
    solver's overrides (full paths of the files it reads)."""
    m: RunManager = request.app.state.manager
    store: SceneStore = request.app.state.store
    try:
        run = m.get(body.run)
    except NotFound as exc:
        raise NotFound(f"run: {exc}") from None
    if run.state != "finished":
        raise Invalid(f"run: {run.id} is {run.state}: a study's times are predicted from a "
                      "finished run's")
    # the run's cost and mesh edge as its estimate read them (its result.json, its scene);
    # the solver's own time (assembly, factorisation, solve, line search): the service's run
    # also makes and records a frame a step, which a study's cases do not (on the 2 mm cup 11 s
    # of its 25, against 2.4 s of 14.6 from the command line)
    est = m.estimates.get(run) or {}
    cost = est.get("cost") or {}
    if not (cost.get("per_iteration_s") and cost.get("newton_iterations") and cost.get("dofs")):
        raise Invalid(f"run: {run.id} has no timing in its result")
    t, dofs = cost["per_iteration_s"] * cost["newton_iterations"], cost["dofs"]
    path, text = _scene_ran(run, m, store)
    # what ran: the run's unsaved edits (its scene.toml) and its overrides, less the element
    # and the mesh a study varies itself; the files the scene reads by their full paths
    sets = run.studied_overrides()
    overrides = {**sets, **store.solver_overrides(store.validate(text, sets))}
    ran = run.changes(studied=True, live=False)
    basis = {"run": run.id, "element": run.element, "dofs": int(dofs), "seconds": float(t),
             "edge": est.get("edge_length"), "changes": ran,
             "live": run.changes(studied=True)[len(ran):],  # what follows: the live ones
             "scene_arg": str(path) if run.edited else run.scene, "sets": sets}
    ref = (body.reference.element, body.reference.edge_mm) if body.reference else None
    plan = studies.make(path, run.scene, basis, overrides,
                        request.app.state.settings.max_model_bytes, body.elements,
                        body.levels_mm, ref, m.files.root)
    return plan, path, overrides


@router.post("/plan", response_model=Plan, responses=documented(404, *BODY))
def plan_study(body: Asked, request: Request) -> dict:
    """What a study of the run's scene would run: each case's element, mesh level, DoFs and
    memory (from the mesh parameters, nothing built) and its time predicted from the run's
    (scaled by DoFs and element: within a factor of two or three), and the whole study's.
    422 naming the field: a run not finished, an unknown element, a level not a positive
    number of mm, a case above the server's memory limit. 404: no such run, or its scene is
    gone."""
    return _plan(body, request)[0]


@router.post("", status_code=201, response_model=Progress,
             responses=documented(404, 409, *BODY))
def start_study(body: Asked, request: Request) -> dict:
    """Start the study ``plan_study`` shows, as ``q3t study`` in a process of its own; its
    report (runs/study-SCENE/report.json) gives the scene's runs their error estimate when it
    ends. 409 while another study runs (one at a time: a study times its cases)."""
    plan, path, overrides = _plan(body, request)
    return request.app.state.studies.start(path, plan, overrides)


@router.get("", response_model=Current)
def current_study(request: Request) -> dict:
    """The study running, or the last one since the server started (None: none): its cases
    done, time so far against the prediction, the command's last lines."""
    return {"study": request.app.state.studies.shown()}


@router.post("/cancel", response_model=Progress, responses=documented(409))
def cancel_study(request: Request) -> dict:
    """End the running study (its processes stopped; the last report stays as it was). 409
    when none runs."""
    return request.app.state.studies.cancel()


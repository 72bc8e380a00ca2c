"""/api/runs: start, list, status, pause/resume/step/stop, live parameters, result, recording,
delete. Every call returns at once; the solver process does the work."""

from __future__ import annotations

import json
from typing import Literal

from fastapi import APIRouter, Request, Response
from fastapi.responses import FileResponse
from pydantic import BaseModel, ConfigDict, Field

from server.problems import NotFound
from server.runs import RunManager

router = APIRouter(prefix="/api/runs", tags=["runs"])
Scalar = float | int | bool | str | list[float]


class Body(BaseModel):
    model_config = ConfigDict(extra="forbid")


class NewRun(Body):
    scene: str
    element: str | None = None
    overrides: dict[str, Scalar] = Field(default_factory=dict,
                                         description='scene overrides, e.g. {"material.nu": 0.3}')
    parameters: dict[str, float] = Field(default_factory=dict, description="live parameters")
    paused: bool = False


class ParameterValue(Body):
    value: float


def _runs(request: Request) -> RunManager:
    return request.app.state.manager


@router.get("")
def list_runs(request: Request) -> list[dict]:
    return _runs(request).list()


@router.post("", status_code=201)
def start_run(body: NewRun, request: Request) -> dict:
    run = _runs(request).start_run(body.scene, body.element, body.overrides, body.parameters,
                                   body.paused)
    return run.summary()


@router.get("/{run_id}")
def status(run_id: str, request: Request, since: int = 0) -> dict:
    """The run's state and its step records after step ``since``; ``pending``: the commands
    the solver has not acted on yet; for a finished run also ``estimate``: its error from a
    study of the scene (``q3t study``) and its cost."""
    return _runs(request).status(run_id, since)


@router.post("/{run_id}/{action}")
def control(run_id: str, action: Literal["pause", "resume", "step", "stop"],
            request: Request) -> dict:
    return _runs(request).command(run_id, action)


@router.put("/{run_id}/parameters/{name}", status_code=202)
def set_parameter(run_id: str, name: str, body: ParameterValue, request: Request) -> dict:
    """Applied from the next step. Waits briefly for the solver: ``applied`` and
    ``applies_from_step`` say from which step it acts (the step is also in the run's
    ``parameter_log``); a solver inside a long step answers later (``applied`` false)."""
    return _runs(request).set_parameter(run_id, name, body.value)


@router.get("/{run_id}/result")
def result(run_id: str, request: Request) -> dict:
    """The run's result.json, with ``estimate`` as in the status."""
    m = _runs(request)
    run = m.get(run_id)
    path = m.dir(run.id) / "result.json"
    if not path.is_file():
        raise NotFound(f"run {run_id!r} has no result yet")
    return {**json.loads(path.read_text()), "estimate": m.estimate(run)}


@router.get("/{run_id}/frames")
def frames(run_id: str, request: Request) -> dict:
    """The steps whose frames the server keeps (the latest run only; every k-th when long)."""
    m = _runs(request)
    m.get(run_id)
    summary = m.history.summary()
    if summary["run"] != run_id:
        raise NotFound(f"no frames kept for run {run_id!r} (only the latest run's are)")
    return summary


@router.get("/{run_id}/frames/{step}")
def frame(run_id: str, step: int, request: Request) -> dict:
    """One kept frame (the one at ``step`` or the nearest before): tool translations, probes,
    and each field's min, max and mean over the display vertices."""
    f = _runs(request).frame_at(run_id, step)
    return {"step": f["step"], "time": f["time"], "n_vertices": len(f["positions"]),
            "tools": {k: [float(x) for x in v] for k, v in f["tools"].items()},
            "fields": {k: {"min": float(v.min()), "max": float(v.max()), "mean": float(v.mean())}
                       for k, v in f["fields"].items()},
            "bounds": [[float(x) for x in f["positions"].min(0)],
                       [float(x) for x in f["positions"].max(0)]],
            "probes": f["probes"]}


@router.get("/{run_id}/recording")
def recording(run_id: str, request: Request) -> FileResponse:
    m = _runs(request)
    path = m.dir(m.get(run_id).id) / "run.rrd"
    if not path.is_file():
        raise NotFound(f"run {run_id!r} has no recording")
    return FileResponse(path, media_type="application/octet-stream", filename=f"{run_id}.rrd")


@router.delete("/{run_id}", status_code=204)
def delete_run(run_id: str, request: Request) -> Response:
    _runs(request).delete(run_id)
    return Response(status_code=204)

"""/api/config, /api/health: what the page needs to know about this server."""

from __future__ import annotations

from fastapi import APIRouter, Request
from pydantic import BaseModel, Field

router = APIRouter(prefix="/api", tags=["meta"])


class Range(BaseModel):
    min: float
    max: float
    label: str = Field(description="the words a page shows for it (\"Friction ×\")")
    hint: str = Field(description="what it multiplies")


class Config(BaseModel):
    ready: bool = Field(description="the solver process is up and has named the parameters")
    elements: list[str]
    parameters: dict[str, Range] = Field(description="the live parameters and their ranges")
    viewer_port: int | None
    default_scene: str


class Health(BaseModel):
    ok: bool
    worker_alive: bool
    worker_pid: int | None
    worker_restarts: int
    bridge_alive: bool
    repairing_recording: str | None
    bridge_errors: int
    bridge_error: str | None
    active: str | None = Field(description="the active run's id")


@router.get("/config", response_model=Config)
def config(request: Request) -> dict:
    """What the page needs before anything else: whether the solver process is ready, the
    elements, the live parameters with their ranges and labels, the viewer's port."""
    from sim.elements import ELEMENTS
    from sim.stepping.parameters import LABELS

    m = request.app.state.manager
    # the solver process names the live parameters once it is up (a few seconds after the
    # server); until then ``ready`` is false and the page asks again
    return {"ready": m.ready.is_set(), "elements": sorted(ELEMENTS),
            "parameters": {k: {"min": lo, "max": hi, "label": LABELS.get(k, (k, ""))[0],
                               "hint": LABELS.get(k, (k, ""))[1]}
                           for k, (lo, hi) in m.parameter_ranges.items()},
            "viewer_port": m.viewer.port if m.viewer else None,
            "default_scene": m.settings.default_scene}


@router.get("/health", response_model=Health)
def health(request: Request) -> dict:
    """Liveness: the solver process (alive, pid, restarts), the bridge thread (alive, errors)
    and the active run; `ok` is false when either is down."""
    return request.app.state.manager.health()

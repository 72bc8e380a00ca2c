"""/api/config, /api/health: what the page needs to know about this server."""

from __future__ import annotations

from fastapi import APIRouter, Request
from pydantic import BaseModel, Field

from server.settings import loopback

router = APIRouter(prefix="/api", tags=["meta"])


class Range(BaseModel):
    min: float
    max: float
    label: str = Field(description="the words a page shows for it (\"Friction ×\")")
    hint: str = Field(description="what it multiplies")


class Config(BaseModel):
    ready: bool = Field(description="the solver process is up and has named the parameters")
    elements: list[str]
    element_notes: dict[str, str] = Field(description="a line on when to choose each element")
    default_element: str = Field(description=(
        "the element of a scene that names none (shell.element's default): the Run box's "
        "choice until a scene is open"))
    parameters: dict[str, Range] = Field(description="the live parameters and their ranges")
    tool_parameters: dict[str, Range] = Field(description=(
        "the per-tool live parameters: a run has `<name>.<tool>` (as `friction_scale.die`) "
        "for each tool of its scene with the value it multiplies (its status's `parameters` "
        "name them), on top of the run-wide `<name>`"))
    viewer_port: int | None
    viewer_loopback: bool = Field(description=(
        "the viewer listens on this machine's loopback only (viser has no token check; "
        "`--expose-viewer` binds it to `--host`): a page opened from another machine cannot "
        "reach it"))
    default_scene: str


class Solver(BaseModel):
    pid: int | None
    alive: bool
    run: str | None = Field(description="the run it steps (null: free)")


class Health(BaseModel):
    ok: bool
    worker_alive: bool = Field(description="every solver process is alive")
    worker_pid: int | None = Field(description="the first solver process's pid")
    worker_restarts: int
    solvers: list[Solver] = Field(description="the solver processes (q3t serve --solvers)")
    bridge_alive: bool
    repairing_recording: str | None
    bridge_errors: int
    bridge_error: str | None
    active: list[str] = Field(description="the active runs' ids")
    queued: list[str] = Field(description="the queued runs' ids, the next to start first")
    queue_limit: int = Field(description="runs that may wait; then a start is a 429")
    solver_losses: list[str] = Field(description="why the last solver processes were "
                                     "replaced (at most 5, newest last)")
    solver_log: list[str] = Field(description="the solvers' last log lines (at most 5)")


@router.get("/config", response_model=Config)
def config(request: Request) -> dict:
    """What the page needs before anything else: whether the solver process is ready, the
    elements, the live parameters with their ranges and labels, the viewer's port."""
    from sim.elements import ELEMENTS
    from sim.scene.sheet import ShellSpec
    from sim.stepping.parameters import LABELS, PER_TOOL, RANGES, TOOL_LABELS

    m = request.app.state.manager
    # the solver process names the live parameters once it is up (a few seconds after the
    # server); until then ``ready`` is false and the page asks again
    return {"ready": m.ready.is_set(), "elements": sorted(ELEMENTS),
            "element_notes": {k: e.note for k, e in ELEMENTS.items()},
            "default_element": ShellSpec.model_fields["element"].default,
            "parameters": {k: {"min": lo, "max": hi, "label": LABELS.get(k, (k, ""))[0],
                               "hint": LABELS.get(k, (k, ""))[1]}
                           for k, (lo, hi) in m.parameter_ranges.items()},
            "tool_parameters": {k: {"min": RANGES[k][0], "max": RANGES[k][1],
                                    "label": TOOL_LABELS[k][0], "hint": TOOL_LABELS[k][1]}
                                for k in PER_TOOL},
            "viewer_port": m.viewer.port if m.viewer else None,
            "viewer_loopback": loopback(m.settings.viewer_host),
            "default_scene": m.settings.default_scene}


@router.get("/health", response_model=Health)
def health(request: Request) -> dict:
    """Liveness: the solver processes (alive, pid, the run each steps; restarts), the bridge
    thread (alive, errors), the active and the queued runs; `ok` is false when a solver
    process or the bridge is down."""
    return request.app.state.manager.health()

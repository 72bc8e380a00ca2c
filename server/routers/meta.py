"""/api/config, /api/health: what the page needs to know about this server."""

from __future__ import annotations

from fastapi import APIRouter, Request

router = APIRouter(prefix="/api", tags=["meta"])


@router.get("/config")
def config(request: Request) -> dict:
    from sim.elements import ELEMENTS

    m = request.app.state.manager
    # the solver process names the live parameters once it is up (a few seconds after the
    # server); until then ``ready`` is false and the page asks again
    return {"ready": m.ready.is_set(), "elements": sorted(ELEMENTS),
            "parameters": {k: {"min": lo, "max": hi} for k, (lo, hi) in
                           m.parameter_ranges.items()},
            "viewer_port": m.viewer.port if m.viewer else None,
            "default_scene": m.settings.default_scene}


@router.get("/health")
def health(request: Request) -> dict:
    return request.app.state.manager.health()

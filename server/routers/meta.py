"""/api/config, /api/health: what the page needs to know about this server."""

from __future__ import annotations

from fastapi import APIRouter, Request

router = APIRouter(prefix="/api", tags=["meta"])


@router.get("/config")
def config(request: Request) -> dict:
    from sim.elements import ELEMENTS

    m = request.app.state.manager
    m.ready.wait(120)  # the solver process names the live parameters once it is up
    return {"elements": sorted(ELEMENTS),
            "parameters": {k: {"min": lo, "max": hi} for k, (lo, hi) in
                           m.parameter_ranges.items()},
            "viewer_port": m.viewer.port if m.viewer else None,
            "default_scene": m.settings.default_scene}


@router.get("/health")
def health(request: Request) -> dict:
    m = request.app.state.manager
    return {"ok": True, "worker_alive": m.worker.alive(), "worker_pid": m.worker.pid,
            "worker_restarts": m.restarts, "active": m.active}

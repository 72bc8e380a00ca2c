"""The FastAPI app factory: settings in, app out. The lifespan owns the solver process, the
bridge thread and the viewer; routers hold one resource each."""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI
from fastapi_offline import FastAPIOffline

from server import errors
from server.rings import RingCutter
from server.routers import (
    compare,
    events,
    exports,
    files,
    meta,
    plots,
    runs,
    scenes,
    split_ring,
    studies,
    view,
    web,
)
from server.runs import RunManager
from server.settings import Settings
from server.store import SceneStore
from server.studies import Studies
from server.workerhandle import WorkerTarget


def create_app(settings: Settings | None = None,
               worker_target: WorkerTarget | None = None) -> FastAPI:
    """``worker_target``: the solver process's entry point (default ``worker_main``; the
    benchmark passes a frame generator)."""
    settings = settings or Settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        store = SceneStore(settings.scenes_dir)
        manager = RunManager(settings, store, **({"worker_target": worker_target}
                                                  if worker_target else {}))
        if settings.viewer:  # imports viser: only when the viewer is on
            from server.actions import ViewerActions
            from server.viewer import Viewer

            manager.viewer = Viewer(settings.viewer_host, settings.viewer_port,
                                    ViewerActions(manager), live_runs=settings.solvers)
        app.state.store, app.state.manager = store, manager
        app.state.rings = RingCutter()
        app.state.studies = Studies(settings.runs_dir)
        manager.start()
        yield
        app.state.rings.close()
        app.state.studies.close()
        manager.close()
        if manager.viewer:
            manager.viewer.stop()

    # operation ids are the route functions' names (read_scene, start_run, ...): the links
    # between operations name them
    # /docs loads Swagger UI from the app, not from a CDN: forming shops are often air-gapped.
    # No online validator (it would be sent the schema); no /redoc (ReDoc fetches its logo
    # from a CDN, and one docs page is enough).
    app = FastAPIOffline(title="q3t-forming preview", version="0.1.0", lifespan=lifespan,
                         redoc_url=None,
                         generate_unique_id_function=lambda route: route.name,
                         swagger_ui_parameters={"validatorUrl": None})
    app.state.settings = settings
    errors.install(app, settings)
    every = errors.documented(401) if settings.token else None
    for module in (scenes, files, runs, split_ring, studies, events, exports, plots, compare,
                   view, meta, web):
        app.include_router(module.router, responses=every)
    return app

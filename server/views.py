"""What the page and the viewer show: the selected run, or a scene's preview before any run.
One selection for every browser today (the viewer is one viser scene): the run manager
(server.runs) selects a new run and moves the selection off a deleted one, the page
(``/api/view``) and the viewer's "Run" dropdown select the run a user picks. The viewer is told
in the order selections are made (``_showing``): of two made at once it ends on the later."""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING, Protocol

from server.problems import Conflict
from server.records import ACTIVE, Run
from server.settings import Settings
from server.store import SceneStore

if TYPE_CHECKING:  # imports viser
    from server.viewer import Viewer


class Shows(Protocol):
    """What the views read of the run manager (``server.runs.RunManager``)."""

    settings: Settings
    store: SceneStore
    lock: threading.RLock
    runs: dict[str, Run]
    viewer: Viewer | None
    slots: list

    def get(self, run_id: str) -> Run: ...


class Views:
    def __init__(self, manager: Shows, selected: str | None):
        self.m = manager
        # the run the page and the viewer show: a new run, else the newest
        self.selected = selected
        # the scene the viewer previews instead (before any run): {"scene", "request" (the
        # solver's request id), "state" (building, shown, failed), "error"}; None: the run
        self.preview: dict | None = None
        self._showing = threading.Lock()

    def view(self) -> dict:
        preview = self.preview or {}
        return {"run": self.selected, "scene": preview.get("scene"),
                "preview": preview.get("state"), "preview_error": preview.get("error")}

    def select(self, run_id: str) -> dict:
        """Show ``run_id`` on the page (every browser's) and in the viewer."""
        with self.m.lock:
            self.selected = self.m.get(run_id).id
        self.show_selected()
        return self.view()

    def show_scene(self, scene: str, toml: str | None = None) -> dict:
        """Preview ``scene`` in the viewer before any run: its blank and tools at the start
        (``toml``: as the page shows it, edits not saved yet). Validated here (422 naming the
        field, 404 for an unknown scene); the solver process builds it between the steps of
        an active run, which goes on, and the viewer shows it when built. The selected run
        stays selected: selecting it again, or a new run, shows it."""
        if not self.m.viewer:
            raise Conflict("the viewer is off (the server runs without it): nothing to "
                           "preview on")
        text, _ = self.m.store.run_text(scene, toml)
        _, overrides = self.m.store.checked(text, {}, self.m.settings.max_model_bytes)
        with self.m.lock:  # a free solver builds it at once; else between an active run's steps
            worker = min(self.m.slots, key=lambda s: s.run is not None).worker
            rid = worker.send("preview", scene=scene, scene_toml=text, overrides=overrides)
            self.preview = {"scene": scene, "request": rid, "state": "building"}
        self.m.viewer.preview_status(f"Preview of scene `{scene}`: building its model…")
        return self.view()

    def show_selected(self) -> None:
        """The viewer shows the selected run, instead of any scene's preview: live while it is
        the latest, else its recording (loaded by the viewer in the background)."""
        if not self.m.viewer:
            return
        # in order: of two selections made at once, the viewer ends on the later one
        with self._showing:
            with self.m.lock:
                self.preview = None
                run = self.m.runs.get(self.selected or "")
                shown = None if run is None else (run.id, dict(run.parameters),
                                                    run.state in ACTIVE, run.line())
            self.m.viewer.show_run(*(shown or (None, {}, False, "No run yet")))

    def show_preview(self, ev: dict) -> None:
        """The solver built the preview ``ev`` (its ``preview`` event): shown unless another
        scene or a run was chosen since (checked in the order of ``show_selected``)."""
        with self._showing:
            with self.m.lock:
                p = self.preview
                if p is None or p["request"] != ev["request"]:
                    return
                p["state"], p["error"] = ("failed", ev["error"]) if "error" in ev \
                    else ("shown", None)
            if not self.m.viewer:
                return
            scene = ev["scene"]
            if "error" in ev:
                self.m.viewer.preview_status(f"Preview of scene `{scene}` failed: {ev['error']}")
                return
            self.m.viewer.show_preview(scene, ev["faces"], ev["tools"], ev["frame"],
                                     f"Preview of scene `{scene}`: its blank and tools at the "
                                     "start, before any run  \n(choose a run to show it)")

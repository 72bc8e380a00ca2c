"""What each browser shows: its view. A view is the selected run (or a scene previewed before
any run) and the step its 3-D view's time slider was moved to. A page names its view with the
``X-Q3T-View`` header (an id it makes for its tab); its embedded viewer names the same id in
the path of its websocket (server.viewer), so a page and its viewer move together while
another browser's stay where they are. A request without an id (a script) acts on the
``default`` view, which a viewer opened on its own port shows too.

The run manager (server.runs) selects a new run in the view that started it and moves every
view off a deleted run. Who started a run is kept with it (``Run.started_by``); a Pause,
Resume, Step, Stop, parameter change or delete from another view is noted on the run
(``Run.touched``) and told to the starter's view (its ``notices``), and the one who acted is
told whose run it was. The viewer is told in the order selections are made (``_showing``): of
two made at once it ends on the later."""

from __future__ import annotations

import collections
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

from server.problems import Conflict
from server.records import ACTIVE, Run
from server.settings import Settings
from server.store import SceneStore

if TYPE_CHECKING:  # imports viser
    from server.viewer import Viewer

DEFAULT = "default"  # the view of requests that name none (scripts)
MAX_VIEWS = 256  # views kept; the least recently used other than the default makes way
NOTICES = 20  # notices a view keeps (the newest)
ACTED = {"pause": "paused", "resume": "resumed", "step": "stepped", "stop": "stopped",
         "delete": "deleted"}


class Shows(Protocol):
    """What the views read of the run manager (``server.runs.RunManager``)."""

    settings: Settings
    store: SceneStore
    lock: threading.RLock
    runs: dict[str, Run]
    viewer: Viewer | None
    slots: list

    def get(self, run_id: str) -> Run: ...


@dataclass
class View:
    run: str | None  # the selected run
    # the scene previewed instead (before any run): {"scene", "request" (the solver's
    # request id; None: refused before any was sent), "state" (building, shown, failed),
    # "error", "event" (the built preview, for a viewer that connects later), "line" (a
    # refused one's status line)}; None: the run is shown
    preview: dict | None = None
    step: int | None = None  # the step its viewer's time slider was moved to (None: the last)
    notices: collections.deque = field(default_factory=lambda: collections.deque(
        maxlen=NOTICES))


def who(view: str | None) -> str:
    """The starter of a run, in a notice's words."""
    return "a script" if view in (None, DEFAULT) else "another page"


class Views:
    def __init__(self, manager: Shows):
        self.m = manager
        self.views: collections.OrderedDict[str, View] = collections.OrderedDict()
        self._seq = 0  # numbers the notices, so a page shows each once
        self._showing = threading.Lock()

    def _get(self, view: str | None) -> View:
        """Under ``lock``: the view (made on first use, on the newest run), the most recently
        used last."""
        key = view or DEFAULT
        v = self.views.get(key)
        if v is None:
            v = self.views[key] = View(self.newest())
            while len(self.views) > MAX_VIEWS:
                oldest = next(k for k in self.views if k != DEFAULT)
                del self.views[oldest]
        self.views.move_to_end(key)
        return v

    def newest(self) -> str | None:
        runs = self.m.runs.values()
        return max(runs, key=lambda r: r.created).id if runs else None

    def view(self, view: str | None = None, since: int = 0) -> dict:
        """The view as ``/api/view`` gives it; its notices numbered above ``since``."""
        with self.m.lock:
            v = self._get(view)
            preview = v.preview or {}
            return {"view": view or DEFAULT, "run": v.run, "scene": preview.get("scene"),
                    "preview": preview.get("state"), "preview_error": preview.get("error"),
                    "preview_edited": preview.get("edited"), "step": v.step,
                    "notices": [n for n in v.notices if n["seq"] > since]}

    def selected(self, view: str | None) -> str | None:
        with self.m.lock:
            return self._get(view).run

    def select(self, view: str | None, run_id: str) -> dict:
        """Show ``run_id`` in ``view``: its page and its viewer."""
        with self.m.lock:
            v = self._get(view)
            v.run, v.step = self.m.get(run_id).id, None
        self.show_selected(view)
        return self.view(view)

    def started(self, run: Run, view: str | None) -> None:
        """A new run: started by ``view``, which selects it (as does a view with no run)."""
        with self.m.lock:
            run.started_by = view or DEFAULT
            self._get(view)
            for key, v in self.views.items():
                if key == run.started_by or v.run is None:
                    v.run, v.step = run.id, None
            shown = [k for k, v in self.views.items() if v.run == run.id]
        for key in shown:
            self.show_selected(key)

    def deleted(self, run: Run, view: str | None) -> str | None:
        """``run`` was deleted (by ``view``): every view showing it shows the newest run.
        Returns the notice for the one who deleted it (``acted``)."""
        with self.m.lock:
            moved = [k for k, v in self.views.items() if v.run == run.id]
            for key in moved:
                self.views[key].run, self.views[key].step = self.newest(), None
        notice = self.acted(run, "delete", view)
        for key in moved:
            self.show_selected(key)
        return notice

    def acted(self, run: Run, action: str, view: str | None, detail: str = "") -> str | None:
        """``view`` paused, resumed, stepped, stopped, deleted or changed a parameter of
        ``run`` (``action``: a command, "delete" or "set <name>"). When the run is another
        view's, the run notes it, the starter's view is told, and the answer says so (the
        returned sentence); None when it is the actor's own run."""
        actor, owner = view or DEFAULT, run.started_by
        if owner is None or owner == actor:
            return None
        did = ACTED.get(action, action)
        with self.m.lock:
            entry = {"action": action, "by": who(actor), "at": time.time(), "step": run.step,
                     "detail": detail}
            if action != "delete":
                run.touched.append(entry)
            if owner in self.views:
                self._seq += 1
                self.views[owner].notices.append(
                    {**entry, "seq": self._seq, "run": run.id,
                     "text": f"Run {run.id} {did}{detail} by {who(actor)} at step {run.step}"})
        return f"run {run.id} was started by {who(owner)}: {did}{detail} all the same"

    def shows_step(self, view: str, run_id: str | None, step: int | None) -> None:
        """``view``'s viewer shows ``step`` of ``run_id`` (None: follows the run's last)."""
        with self.m.lock:
            v = self.views.get(view)
            if v is not None and v.run == run_id:
                v.step = step

    def show_scene(self, view: str | None, scene: str, toml: str | None = None) -> dict:
        """Preview ``scene`` in ``view``'s viewer before any run: its blank and tools at the
        start (``toml``: as the page shows it, edits not saved yet). Validated here (422
        naming the field, 404 for an unknown scene); the solver process builds it between the
        steps of an active run, which goes on, and the viewer shows it when built. The
        selected run stays selected: selecting it again, or a new run, shows it."""
        if not self.m.viewer:
            raise Conflict("the viewer is off (the server runs without it): nothing to "
                           "preview on")
        try:
            text, edited = self.m.store.run_text(scene, toml)
            _, overrides = self.m.store.checked(text, {}, self.m.settings.max_model_bytes)
        except ValueError as exc:  # refused (422): not the previous geometry under its words;
            # still this scene's preview, failed, so that the edit that fixes it shows
            line = f"Preview of {_named(scene, toml is not None)} refused: {exc}"
            with self._showing:  # in order with an earlier build's drawing (show_preview)
                with self.m.lock:
                    self._get(view).preview = {"scene": scene, "request": None,
                                               "state": "failed", "error": str(exc),
                                               "edited": toml is not None, "line": line}
                self.m.viewer.preview_failed(line, view or DEFAULT)
            raise
        with self.m.lock:  # a free solver builds it at once; else between an active run's steps
            worker = min(self.m.slots, key=lambda s: s.run is not None).worker
            rid = worker.send("preview", scene=scene, scene_toml=text, overrides=overrides)
            self._get(view).preview = {"scene": scene, "request": rid, "state": "building",
                                       "edited": edited}
        self.m.viewer.preview_status(self._building(scene, edited), view or DEFAULT)
        return self.view(view)

    def show_selected(self, view: str | None = None) -> None:
        """``view``'s viewer shows its selected run, instead of any scene's preview: live
        while it is one of the latest, else its recording (loaded by the viewer)."""
        if not self.m.viewer:
            return
        # in order: of two selections made at once, the viewer ends on the later one
        with self._showing:
            self._show_run(view or DEFAULT)

    def _show_run(self, key: str) -> None:
        """Under ``_showing``: ``key``'s viewer shows its selected run, its preview ended."""
        with self.m.lock:
            v = self._get(key)
            v.preview = None
            run = self.m.runs.get(v.run or "")
            shown = None if run is None else (run.id, dict(run.parameters),
                                                run.state in ACTIVE, run.controls(), run.line())
        self.m.viewer.show_run(*(shown or (None, {}, False, (), "No run yet")), key)

    @staticmethod
    def _building(scene: str, edited: bool | None) -> str:
        return f"Preview of {_named(scene, edited)}: building its model…"

    def connected(self, view: str) -> None:
        """A viewer of ``view`` connected: it shows the view's preview (built, or still
        building: it is shown when built), else its run. A preview still building is kept:
        taking the run instead would drop the preview when it comes (a page's viewer connects
        while the preview its page asked for is being built)."""
        with self._showing:
            with self.m.lock:
                p = self._get(view).preview
                p = dict(p) if p else None
            if p is None:
                self._show_run(view)
            elif p.get("line") is not None:  # refused: nothing built to draw
                self.m.viewer.preview_failed(p["line"], view)
            elif p.get("event") is not None:
                self._draw_preview(view, p["event"])
            else:
                self.m.viewer.preview_status(self._building(p["scene"], p.get("edited")), view)

    def show_preview(self, ev: dict) -> None:
        """The solver built the preview ``ev`` (its ``preview`` event): shown in the view that
        asked, unless another scene or a run was chosen there since (checked in the order of
        ``show_selected``)."""
        with self._showing:
            with self.m.lock:
                key = next((k for k, v in self.views.items()
                            if v.preview and v.preview["request"] == ev["request"]), None)
                if key is None:
                    return
                p = self.views[key].preview
                p["state"], p["error"] = ("failed", ev["error"]) if "error" in ev \
                    else ("shown", None)
                p["event"] = ev
            if self.m.viewer:
                self._draw_preview(key, ev)

    def _draw_preview(self, view: str, ev: dict) -> None:
        scene = ev["scene"]
        with self.m.lock:
            named = _named(scene, (self._get(view).preview or {}).get("edited"))
        if "error" in ev:
            self.m.viewer.preview_failed(f"Preview of {named} failed: {ev['error']}", view)
            return
        self.m.viewer.show_preview(scene, ev["faces"], ev["tools"], ev["frame"],
                                   f"Preview of {named}: its blank and tools at the "
                                   "start, before any run  \n(choose a run to show it)",
                                   view=view)


def _named(scene: str, edited: bool | None) -> str:
    """The previewed scene as the viewer's status names it: a preview of edits not saved yet
    says so, since the scene list's entry of that name is the saved file."""
    return f"scene `{scene}`" + (" with its unsaved edits" if edited else "")

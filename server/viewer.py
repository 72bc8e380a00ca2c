"""The viser viewer: one viser server, and for each browser connected to it a view of its own
(``server.clientview.ClientView``: its GUI, its scene, its camera), so that two browsers show
two runs, colour modes and steps side by side.

A page embeds the viewer with its view id in the websocket's path
(``?websocket=ws://host:port/view/<id>``: viser's client connects to the address it is given,
and viser accepts a websocket on any path); the browser's client is then shown what the
server's view of that id holds (``server.views``), the run the page shows. A viewer opened on
its own, without an id, shows the ``default`` view, which scripts select for.

It never sees the solver: the bridge hands it frames (dicts of arrays) and the runs' states;
the views tell it which run (or scene preview) each view shows. Here is what the browsers
share: the latest runs (one per solver process) with their sheet and tools and newest frame,
kept whether shown or not (``Live``), the runs offered, the live parameters; a frame is drawn
by every client showing its run.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np
import viser

from server import viserloop
from server.clientview import Actions, ClientView
from sim.frames.output import grow

DEFAULT = "default"  # server.views.DEFAULT: the view of a viewer opened on its own
VIEW_PATH = "/view/"  # the websocket path a page's viewer names its view under


@dataclass
class Live:
    """A latest run: its sheet's faces, its tools (meshes sent once), its newest frame and its
    fields' ranges so far."""

    faces: np.ndarray
    tools: list[dict]
    frame: dict | None = None
    seen: dict[str, tuple[float, float]] = field(default_factory=dict)
    ended: bool = False  # the run is over: its place may go to a newer run
    thinning_limit: float | None = None  # %, the material card's (flc.max_thinning)


class Viewer:
    def __init__(self, host: str, port: int, actions: Actions, colour_hz: float = 4.0,
                 live_runs: int = 1):
        """``live_runs``: how many of the latest runs are kept live (one per solver)."""
        viserloop.install()
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        # embedded in the page's centre column: the narrow panel, and no share button (a
        # share link would expose the run's controls)
        self.server.gui.configure_theme(control_width="small", show_share_button=False)
        self.server.scene.configure_default_lights(enabled=True, cast_shadow=False)
        # no image-based light: its reflections washed the colour map out (a 1 mm teal drawn
        # pale cyan, the FLD zones' green and purple pastel, unlike their legend swatches),
        # and it was most of a frame's cost in software WebGL; a fill light from above in
        # its place keeps the translucent tools from turning dark
        self.server.scene.configure_environment_map(hdri=None)
        self.server.scene.add_light_hemisphere("/fill", sky_color=(255, 255, 255),
                                               ground_color=(160, 160, 160), intensity=2.5)
        self.actions = actions
        self.colour_period = 1.0 / colour_hz
        self.lock = threading.RLock()  # viser runs update callbacks in the assigning thread
        self._code = threading.local()  # .on while this thread's GUI changes are the code's
        self.live_run: str | None = None  # the latest run built
        self.lives: dict[str, Live] = {}  # the latest runs built, oldest first
        self.live_runs = max(1, live_runs)
        self.run_ids: tuple[str, ...] = ()  # the runs offered, newest first
        self.parameters: dict[str, tuple[float, float]] = {}  # live parameter -> range
        self.clients: dict[int, ClientView] = {}
        self.server.on_client_connect(self._connect)
        self.server.on_client_disconnect(self._disconnect)

    @property
    def port(self) -> int:
        return self.server.get_port()

    # ---- the browsers ---------------------------------------------------------------------
    def view_of(self, client: viser.ClientHandle) -> str:
        """The view a client names in its websocket's path (``/view/<id>``), else the
        default. viser keeps each connection's handshake request, but offers no public way to
        it: read here only."""
        conn = self.server._websock_server._live_connections.get(client.client_id)
        path = getattr(getattr(conn, "request", None), "path", "") or ""
        path = path.partition("?")[0]
        view = path[len(VIEW_PATH):].strip("/") if path.startswith(VIEW_PATH) else ""
        ok = view and len(view) <= 64 and all(c.isalnum() or c in "_-" for c in view)
        return view if ok else DEFAULT

    def _connect(self, client: viser.ClientHandle) -> None:
        view = ClientView(self, client, self.view_of(client))
        with self.lock:
            self.clients[client.client_id] = view
            view.set_runs(self.run_ids)
            view.add_parameters(self.parameters)
        self.actions.connected(view.view)

    def _disconnect(self, client: viser.ClientHandle) -> None:
        with self.lock:
            self.clients.pop(client.client_id, None)

    def of_view(self, view: str) -> list[ClientView]:
        """The connected clients showing ``view`` (a page's iframe, reloaded: one)."""
        with self.lock:
            return [c for c in self.clients.values() if c.view == view]

    def showing(self, run_id: str) -> list[ClientView]:
        """The clients that show ``run_id`` (live or its recording), newest first."""
        with self.lock:
            return [c for _, c in sorted(self.clients.items(), reverse=True)
                    if c.selected == run_id and c.mode in ("live", "replay")]

    @contextmanager
    def from_code(self) -> Iterator[None]:
        """GUI values set inside are the code's, not a user's: their callbacks do nothing.
        viser runs the callbacks of a value set in code at once, in the thread that set it, so
        the mark is per thread: a user's change arriving meanwhile (in viser's threads, or a
        test's) is still the user's."""
        before = getattr(self._code, "on", False)
        self._code.on = True
        try:
            yield
        finally:
            self._code.on = before

    def by_user(self, action: Callable[[], object]) -> Callable[[object], None]:
        """An ``on_update`` callback that runs ``action()`` for a user's change only."""
        return lambda _e: None if getattr(self._code, "on", False) else action()

    # ---- what the server tells every browser --------------------------------------------------
    def add_parameters(self, parameters: dict[str, tuple[float, float]]) -> None:
        """The live parameters, once the solver process has said which exist."""
        with self.lock:
            self.parameters = dict(parameters)
            for c in self.clients.values():
                c.add_parameters(self.parameters)

    def set_runs(self, run_ids: list[str]) -> None:
        """The runs each "Run" dropdown offers (newest first)."""
        with self.lock:
            self.run_ids = tuple(run_ids)
            for c in self.clients.values():
                c.set_runs(self.run_ids)

    def set_parameter_value(self, run_id: str, name: str, value: float) -> None:
        """A live parameter of ``run_id`` changed: its slider follows where the run is shown."""
        with self.lock:
            for c in self.clients.values():
                c.set_parameter_value(run_id, name, value)

    def run_status(self, run_id: str, line: str, active: bool,
                   controls: Sequence[str]) -> None:
        """A run's state changed: its line, whether it is active and the commands that act on
        it now (``Run.controls``), where shown."""
        with self.lock:
            if run_id in self.lives:
                self.lives[run_id].ended = not active
            for c in self.clients.values():
                c.run_status(run_id, line, active, controls)

    def new_run(self, run_id: str, faces: np.ndarray, tools: list[dict], line: str,
                parameters: dict[str, float], thinning_limit: float | None = None) -> None:
        """A run is built: its sheet's faces and its tools (meshes sent once), kept live in
        place of the oldest live run that is over (its kept frames go with it: a browser
        showing it switches to its recording), and shown by the clients that have it
        selected."""
        with self.lock:
            self.live_run = run_id
            self.lives[run_id] = Live(np.asarray(faces, np.uint32), list(tools),
                                      thinning_limit=thinning_limit)
            for old in [r for r, v in self.lives.items() if v.ended]:
                if len(self.lives) <= self.live_runs:
                    break
                del self.lives[old]
                for c in self.clients.values():
                    c.left_live(old)
            for c in self.clients.values():
                c.new_run(run_id, line, parameters)

    def show(self, frame: dict, status: str, final: bool = False) -> None:
        """A live frame from the bridge: kept as its run's newest, drawn by every client that
        shows the run live."""
        with self.lock:
            live = self.lives.get(frame.get("run") or "")
            if live is None:
                return  # a frame of an earlier run, pushed late
            live.frame = frame
            grow(live.seen, frame["fields"])
            for c in self.clients.values():
                c.show(frame, status, final=final)

    # ---- what one view shows ------------------------------------------------------------------
    def show_run(self, run_id: str | None, parameters: dict[str, float], active: bool,
                 controls: Sequence[str], line: str, view: str = DEFAULT) -> None:
        """``view``'s clients show ``run_id`` (``line``: its status line; ``active``: whether
        it is active; ``controls``: the commands that act on it now)."""
        for c in self.of_view(view):
            c.show_run(run_id, parameters, active, controls, line)

    def show_preview(self, scene: str, faces: np.ndarray, tools: list[dict], frame: dict,
                     line: str, view: str = DEFAULT) -> None:
        for c in self.of_view(view):
            c.show_preview(scene, faces, tools, frame, line)

    def preview_status(self, line: str, view: str = DEFAULT) -> None:
        for c in self.of_view(view):
            c.status(line)

    def preview_failed(self, line: str, view: str = DEFAULT) -> None:
        """A preview could not be built: its view shows nothing but why (not the geometry of
        what it showed before, under words that would name the scene that failed)."""
        for c in self.of_view(view):
            c.clear(line)

    def stop(self) -> None:
        self.server.stop()

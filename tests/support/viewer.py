"""A browser's viewer without a browser: a websocket client of the viser viewer that names a
view in its path (as the page's iframe does) and reads every message, so the server builds
that client's own GUI and scene (``server.clientview.ClientView``), which tests then drive
through viser's server-side handles."""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator

import msgspec

from tests.support.service import until


def default_view(run: str) -> dict:
    """``/api/view`` of the default view showing ``run``: no scene previewed, its viewer at
    the run's latest step, nothing done by others."""
    return {"view": "default", "run": run, "scene": None, "preview": None,
            "preview_error": None, "preview_edited": None, "step": None, "notices": []}


class Socket:
    """A connected viser client; ``close()`` disconnects it."""

    def __init__(self, port: int, path: str):
        import viser
        from websockets.sync.client import connect

        def open_it():
            try:
                return connect(f"ws://127.0.0.1:{port}{path}", max_size=None,
                               subprotocols=[f"viser-v{viser.__version__}"])
            except OSError:  # the server is not listening yet
                return None

        self.ws = until(open_it, f"the viewer on port {port} never took a connection")
        # viser counts a client as connected from its first camera message, as a browser's
        self.ws.send(msgspec.msgpack.encode({
            "type": "ViewerCameraMessage", "wxyz": (1.0, 0.0, 0.0, 0.0),
            "position": (0.0, -1.0, 0.5), "fov": 1.0, "near": 0.001, "far": 100.0,
            "image_height": 480, "image_width": 640, "look_at": (0.0, 0.0, 0.0),
            "up_direction": (0.0, 0.0, 1.0)}))
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        with contextlib.suppress(Exception):
            while True:
                self.ws.recv()

    def close(self) -> None:
        self.ws.close()


@contextlib.contextmanager
def attached(viewer, view: str | None = None) -> Iterator[object]:
    """The ``ClientView`` of a client connected to ``viewer`` in ``view`` (None: no view in
    its path, the default), once the server has built it and shown the view's run."""
    before = set(viewer.clients)
    sock = Socket(viewer.port, f"/view/{view}" if view else "/")
    try:
        cv = until(lambda: next((c for k, c in list(viewer.clients.items())
                                 if k not in before), None), "the client view was not built")
        yield cv
    finally:
        sock.close()

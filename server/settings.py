"""Service settings: one frozen dataclass, filled from the command line or by tests."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from server.problems import Invalid
from sim.size import DEFAULT_LIMIT

ROOT = Path(__file__).resolve().parent.parent
NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,79}")


def check_name(name: str, what: str = "name") -> str:
    """A file-system-safe name: letters, digits, ``_ . -``; never ``..`` or a path."""
    if not isinstance(name, str) or not NAME.fullmatch(name) or ".." in name:  # fullmatch:
        # ``$`` would let a trailing newline through
        raise Invalid(f"{what} {name!r}: use letters, digits, '_', '-', '.' (no paths)")
    return name


@dataclass(frozen=True)
class Settings:
    scenes_dir: Path = ROOT / "scenes"
    runs_dir: Path = ROOT / "runs"
    viewer: bool = True  # start the viser viewer in the server process
    viewer_host: str = "127.0.0.1"
    viewer_port: int = 8081
    token: str | None = None  # required on every request when set
    max_body: int = 256 * 1024  # bytes; larger request bodies get 413
    frame_queue: int = 4  # frames in flight from worker to bridge; extra frames are dropped
    record_every: int = 10  # steps between sheet meshes in run.rrd (and its first and last)
    push_hz: float = 20.0  # most frames per second pushed to the viewer
    step_delay: float = 0.0  # seconds between steps (lets a tiny scene be watched)
    ack_timeout: float = 1.0  # seconds a parameter change waits for the solver's answer
    stop_timeout: float = 5.0  # seconds shutdown waits for the solver to stop the run
    history_frames: int = 400  # frames of the current run kept for scrubbing; then every k-th
    history_bytes: int = 256 * 2**20  # and at most this many bytes of them (server process)
    default_scene: str = "cup_drawing"  # selected first on the page; the viewer's Play starts it
    # a run whose model would need more memory to build is refused (sim.size: the estimate and
    # why the default is half of this 24 GiB machine)
    max_model_bytes: float = DEFAULT_LIMIT
    extra: dict = field(default_factory=dict)

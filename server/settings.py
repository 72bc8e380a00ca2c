"""Service settings: one frozen dataclass, filled from the command line or by tests."""

from __future__ import annotations

import ipaddress
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

from pydantic import AfterValidator, WithJsonSchema

from server.problems import Invalid
from sim.model.size import DEFAULT_LIMIT

ROOT = Path(__file__).resolve().parent.parent
# A file-system-safe name: starts with a letter or digit, then letters, digits, '_', '-' and
# single dots (never '..', never a path). The same rule is in the API schema (``name_type``).
NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_-]*(?:\.[A-Za-z0-9_-]+)*\.?$"
NAME = re.compile(NAME_PATTERN)
SCENE_NAME_MAX = 80
# /api/scenes/<these> are routes of their own, never a scene
RESERVED_SCENE_NAMES = ("parse", "render", "schema", "validate")
# a run id is its scene's name, then "-<element>-<yyyymmdd-hhmmss>-<4 hex>": room for the
# longest scene name and an element name of up to 26 characters
RUN_ID_MAX = SCENE_NAME_MAX + 48


def check_name(name: str, what: str = "name", max_length: int = SCENE_NAME_MAX,
               reserved: tuple[str, ...] = ()) -> str:
    """``name`` if it follows ``NAME``, is at most ``max_length`` long and not ``reserved``;
    else Invalid (422)."""
    if not isinstance(name, str) or len(name) > max_length or not NAME.fullmatch(name):
        raise Invalid(f"{what} {name!r}: 1 to {max_length} letters, digits, '_', '-' or '.', "
                      "starting with a letter or digit, no '..' (no paths)")
    if name in reserved:
        raise Invalid(f"{what} {name!r} is reserved (not one of {', '.join(reserved)})")
    return name


def check_scene_name(name: str) -> str:
    return check_name(name, "scene name", SCENE_NAME_MAX, RESERVED_SCENE_NAMES)


def check_run_id(name: str) -> str:
    return check_name(name, "run id", RUN_ID_MAX)


def name_type(check: Callable[[str], str], max_length: int,
              reserved: tuple[str, ...] = ()) -> Any:
    """A pydantic type for a ``check_name`` rule: the rule in the JSON schema, ``check``'s
    message on error."""
    schema = {"type": "string", "pattern": NAME_PATTERN, "minLength": 1,
              "maxLength": max_length}
    if reserved:
        schema["not"] = {"enum": list(reserved)}
    return Annotated[str, AfterValidator(check), WithJsonSchema(schema)]


SceneName = name_type(check_scene_name, SCENE_NAME_MAX, RESERVED_SCENE_NAMES)
# in a path: /api/scenes/schema is the concrete route, which OpenAPI matches before the
# templated one, so the template's schema need not (and must not) exclude the reserved names
ScenePath = name_type(check_scene_name, SCENE_NAME_MAX)
RunId = name_type(check_run_id, RUN_ID_MAX)


def loopback(host: str) -> bool:
    """Whether ``host`` is a loopback address or name: reachable from this machine only."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


@dataclass(frozen=True)
class Settings:
    scenes_dir: Path = ROOT / "scenes"
    runs_dir: Path = ROOT / "runs"
    viewer: bool = True  # start the viser viewer in the server process
    viewer_host: str = "127.0.0.1"
    viewer_port: int = 8081
    token: str | None = None  # required on every request when set
    max_body: int = 256 * 1024  # bytes; larger request bodies get 413
    # bytes; a larger upload to /api/files gets 413 (a blank of 10^6 triangles is about 50 MB
    # as binary STL)
    max_upload: int = 64 * 2**20
    body_timeout: float = 30.0  # seconds for a request body to arrive in full; then 408
    frame_queue: int = 4  # frames in flight from worker to bridge; extra frames are dropped
    record_every: int = 10  # steps between sheet meshes in run.rrd (and its first and last)
    push_hz: float = 20.0  # most frames per second pushed to the viewer
    step_delay: float = 0.0  # seconds between steps (lets a tiny scene be watched)
    ack_timeout: float = 1.0  # seconds a parameter change waits for the solver's answer
    stop_timeout: float = 5.0  # seconds shutdown waits for the solver to stop the run
    # seconds a stop waits for the solver to end the step under way (it reads commands
    # between steps); then its process is killed and a new one started, so that a step that
    # does not end (a huge model, a solver stuck) cannot hold a solver for ever
    stop_grace: float = 20.0
    # frames kept for scrubbing of each of the latest runs (one per solver); then every k-th
    history_frames: int = 400
    history_bytes: int = 256 * 2**20  # and at most this many bytes of them in all (server)
    # the scene the page selects first: the cup whose 2 mm answer is nearest the converged one
    # (docs/service.md, "The first scene")
    default_scene: str = "cup_drawing_outline"
    # a run whose model would need more memory to build is refused (sim.model.size: the estimate and
    # why the default is half of this 24 GiB machine)
    max_model_bytes: float = DEFAULT_LIMIT
    # solver processes, each stepping one run (q3t serve --solvers): more runs at once, but
    # each slower when there are more than cores
    solvers: int = 1
    queue_limit: int = 16  # runs that may wait for a solver process; then a start is a 429
    # the Dask scheduler whose workers run the solvers (q3t serve --scheduler); None: local
    # processes
    scheduler: str | None = None
    scheduler_timeout: float = 10.0  # s to reach the scheduler at start-up; then an error
    extra: dict = field(default_factory=dict)

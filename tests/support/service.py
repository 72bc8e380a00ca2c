"""Waiting on the service and its processes: hang guards, never a clock a test races."""

from __future__ import annotations

import contextlib
import os
import random
import socket
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from server.records import ACTIVE
from tests.support.scenes import tiny_toml

# s: how long a test waits for something that must happen - a hang guard, never a clock it
# races (a run of the tiny scene takes a second; on a loaded machine, or compiling the
# kernels on a cold numba cache, a minute)
HANG = 300.0
ENDED = {"finished", "failed", "stopped", "cancelled"}  # the states a run ends in


def until(cond: Callable[[], Any], what: str, timeout: float = HANG) -> Any:
    """Poll ``cond()`` until it is true; fail past ``timeout`` s (a hang guard)."""
    deadline, pause = time.monotonic() + timeout, 0.01
    while not (out := cond()):
        assert time.monotonic() < deadline, what
        time.sleep(pause)
        # s: quick for what is nearly there, then a few polls a second - each poll is a
        # request the server answers on the cores the solver and the browser need
        pause = min(1.5 * pause, 0.2)
    return out


def until_exists(path: str) -> None:
    """Returns once ``path`` exists: a job that holds a process (server.rings') until the test
    lets it go, never longer than HANG (a hang guard)."""
    until(lambda: Path(path).exists(), f"{path} never appeared")


def hold_ring_at(stage: str, gate: str, iteration: int | None = None) -> None:
    """A job for server.rings' process: the next ring it cuts reports ``stage`` (words, as
    the server lists it; at Newton's ``iteration``, if given), then waits until ``gate``
    exists (until_exists) before it goes on. Once: later reports go as they come."""
    import server.rings as child

    reports = child._reports

    class Held:
        def put(self, msg: dict) -> None:
            reports.put(msg)
            newton = msg["newton"] or {}
            if msg["stage"] == stage and (iteration is None or
                                          newton.get("iteration") == iteration):
                child._reports = reports
                until_exists(gate)

    child._reports = Held()


def wait_ready(client, timeout: float = HANG) -> None:
    """Until the solver has said it is ready; failing, say why the solvers were lost (the
    health's ``solver_losses``: the one clue when it happens on a CI machine only)."""
    try:
        until(lambda: client.get("/api/config").json()["ready"], "", timeout)
    except AssertionError:
        health = client.get("/api/health").json()
        raise AssertionError(f"the solver never got ready: "
                             f"{health['worker_restarts']} solvers replaced; the last lost: "
                             f"{health.get('solver_losses')}; their log: "
                             f"{health.get('solver_log')}") from None


def wait_state(client, run_id: str, states: set[str], timeout: float = HANG) -> dict:
    def done():
        st = client.get(f"/api/runs/{run_id}").json()
        return st if st["state"] in states else None

    return until(done, f"run {run_id} never reached {states}", timeout)


def finished_run(client, scene: str = "tiny_cup", **body) -> str:
    """The id of a run of ``scene`` started with ``body`` (the API's start fields) through
    ``client`` (a TestClient, or an httpx.Client on a served URL), once it has finished."""
    run = client.post("/api/runs", json={"scene": scene, **body}).json()["id"]
    st = wait_state(client, run, {"finished", "failed", "stopped", "cancelled"})
    assert st["state"] == "finished", st["reason"]
    return run


def wait_done(client, run_id: str) -> dict:
    """The status once the solver has acted on every command sent for the run."""
    def idle():
        st = client.get(f"/api/runs/{run_id}").json()
        return st if not st["pending"] else None

    return until(idle, f"the solver never acted on the commands for {run_id}")


def wait_step(client, run_id: str, step: int, timeout: float = HANG) -> dict:
    def reached():
        st = client.get(f"/api/runs/{run_id}").json()
        return st if st["step"] >= step or st["state"] not in ACTIVE else None

    return until(reached, f"run {run_id} did not reach step {step}", timeout)


def stop_all(client) -> None:
    """Cancel every queued run and stop every active one (left by a test that failed before),
    and wait until they have ended. ``client``: a TestClient, or an ``httpx.Client`` with a
    ``base_url``."""
    health = client.get("/api/health").json()
    for run in health["queued"] + health["active"]:
        client.post(f"/api/runs/{run}/stop")
    for run in health["queued"] + health["active"]:
        wait_state(client, run, ENDED)


def free_port() -> int:
    """A port free now, for a server the test starts next. Not the kernel's pick (bind to
    0): that comes from the ephemeral range, which every outgoing connection of the suite's
    two processes (Dask's, the browser's, the test clients') also draws from, so another may
    take it before the server binds. Below that range only servers bind."""
    low = _ephemeral_low()
    for _ in range(200 if low > 2048 else 0):
        port = _PORTS.randrange(max(1024, low - 12000), low)
        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:  # in use: another
                continue
            return port
    with socket.socket() as s:  # everything below the range taken: the kernel's pick
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


_PORTS = random.Random(os.getpid())  # the two parts of the suite draw different sequences


def _ephemeral_low() -> int:
    try:
        return int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return 32768  # Linux's default


def no_temp_files(root: Path) -> list[Path]:
    return [p for p in root.rglob("*") if p.name.startswith(".") or ".tmp" in p.name]


def outside_scenes(settings) -> dict:
    """Every file in the test folder outside scenes/ and runs/, with its content and mtime."""
    root = settings.scenes_dir.parent
    keep = (settings.scenes_dir, settings.runs_dir, root / "config", root / "data")
    return {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in root.rglob("*")
            if p.is_file() and not any(p.is_relative_to(k) for k in keep)}


def file_scene(path: str) -> str:
    """tiny, its mesh read from ``path`` (a file mesh takes no rectangle's size nor edge)."""
    text = tiny_toml()
    mesh = text[text.index("[mesh]"):text.index("[shell]")]
    return text.replace(mesh, f"[mesh]\nkind = \"file\"\npath = '{path}'\n\n")


def thickness_scene(path: str) -> str:
    """tiny, its per-vertex thickness read from ``path``."""
    return tiny_toml().replace("thickness = 0.007", f"thickness_file = '{path}'")


def nested(depth: int) -> str:
    return "[" * depth + "]" * depth


def service_settings(tmp: Path, scenes: dict[str, str], settings: dict) -> Any:
    """The service's Settings over ``tmp/scenes`` (written from ``scenes``: name -> TOML) and
    ``tmp/runs``, without the viewer unless ``settings`` say otherwise. The solver answers a
    request between two steps: on a loaded machine that may take longer than the default
    second, never HANG (a hang guard); a stop likewise waits for the step under way
    (``stop_grace``) rather than kill the solver."""
    from server.settings import Settings

    os.environ.setdefault("XDG_CONFIG_HOME", str(tmp / "config"))
    os.environ.setdefault("XDG_DATA_HOME", str(tmp / "data"))
    (tmp / "scenes").mkdir(exist_ok=True)
    for name, text in scenes.items():
        (tmp / "scenes" / f"{name}.toml").write_text(text)
    return Settings(scenes_dir=tmp / "scenes", runs_dir=tmp / "runs",
                    **{"viewer": False, "ack_timeout": HANG, "stop_grace": HANG, **settings})


@contextlib.contextmanager
def in_process(tmp: Path, scenes: dict[str, str], **settings: Any) -> Iterator[tuple]:
    """The service in this process (FastAPI's TestClient, which runs the lifespan) with
    service_settings; yields (client, Settings) once the solver is ready."""
    from fastapi.testclient import TestClient

    from server.app import create_app

    config = service_settings(tmp, scenes, settings)
    with TestClient(create_app(config)) as client:
        wait_ready(client)
        yield client, config


@contextlib.contextmanager
def on_uvicorn(app: Any, **config: Any) -> Iterator[str]:
    """``app`` on a real uvicorn server in a thread, lifespan and all: yields its base URL."""
    import uvicorn

    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning", **config))
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    deadline = time.monotonic() + 120  # the lifespan starts the solver process
    while not server.started:
        assert thread.is_alive() and time.monotonic() < deadline, "the server did not start"
        time.sleep(0.02)
    try:
        yield f"http://127.0.0.1:{sock.getsockname()[1]}"
    finally:
        server.should_exit = True
        thread.join(60)
        sock.close()


@contextlib.contextmanager
def in_thread(tmp: Path, scenes: dict[str, str], **settings: Any) -> Iterator[tuple]:
    """The service in this process with service_settings, on uvicorn in a thread: a browser talks
    to it over HTTP while the test reaches into its app (``app.state``: the process that cuts
    rings, to hold one at a stage). Yields (url, app) once the solver is ready."""
    import httpx

    from server.app import create_app

    app = create_app(service_settings(tmp, scenes, settings))
    with on_uvicorn(app) as url:
        until(lambda: httpx.get(f"{url}/api/config").json()["ready"], "solver never ready")
        yield url, app


def stuck_worker(*args: Any, **kwargs: Any) -> None:
    """``server.worker.worker_main`` whose steps never end, as a step stuck in the solver: a
    solver process's entry point for a service under test (``create_app(worker_target=...)``)."""
    from server.worker import worker_main
    from sim.stepping.simulation import Simulation

    def stuck(self: Simulation) -> None:
        while True:
            time.sleep(1.0)

    Simulation.step = stuck
    worker_main(*args, **kwargs)

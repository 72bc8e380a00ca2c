"""``q3t bench-service``: the viewer path, the API under load and the start-up, measured (not
tested). Every figure goes through the real pieces, with a websocket client connected to the
viser viewer (so viser encodes and sends every update, as to a browser):

- delivery: a frame generator in the solver's place (same process, queues, frame format and
  recording as ``server.worker``) makes 40k-vertex frames faster than the viewer takes them;
  the bridge pushes to viser. Reports frames made, dropped (queue full), received, pushed per
  second, at the service's push cap (20/s) and uncapped (the path's capacity), and the status
  latency over HTTP meanwhile;
- status latency (p50/p99 over HTTP) while ``q3t serve`` (viewer and recording on) builds and
  steps the cup blank at ~40k display vertices;
- start-up of ``q3t serve`` to a ready page and solver, with an empty and a warm numba cache,
  and the first frame of a small run after each (numba compiles on first use).
"""

from __future__ import annotations

import argparse
import functools
import multiprocessing as mp
import os
import queue
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path

import numpy as np

from server.settings import ROOT, Settings
from server.worker import Channel
from sim.frames import results
from sim.stamp import Stamp, add_results_option, write_results

CUP_40K = {"mesh.edge_length": 0.00038, "stepping.steps": 50}  # 39,686 display vertices
PARAMETERS = {"load_scale": (0.0, 100.0)}


def _grid(n: int) -> tuple[np.ndarray, np.ndarray]:
    """A square grid of about n vertices: positions (float32) and faces."""
    m = int(np.sqrt(n))
    i, j = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
    V = np.column_stack([i.ravel(), j.ravel(), np.zeros(m * m)]).astype(np.float32) / m
    a = (i[:-1, :-1] * m + j[:-1, :-1]).ravel()
    F = np.concatenate([np.column_stack([a, a + m, a + 1]), np.column_stack([a + 1, a + m,
                                                                             a + m + 1])])
    return V, F.astype(np.uint32)


class _Synthetic:
    """The frame generator's one run: a rippling square sheet, its records and recording."""

    def __init__(self, events: Channel, frames: Channel, record_every: int, n_vertices: int,
                 rate: float):
        self.events, self.frames = events, frames
        self.record_every, self.rate = record_every, rate
        self.V, self.F = _grid(n_vertices)
        self.run: str | None = None
        self.rec = None
        self.step = self.produced = self.dropped = 0
        self.t_next = time.perf_counter()

    def emit(self, kind: str, **kw: object) -> None:
        self.events.put({"kind": kind, "run": self.run, **kw})

    def frame(self, k: int) -> dict:
        V = self.V
        W = V.copy()
        W[:, 2] = 0.01 * np.sin(k / 10 + V[:, 0] * 6)
        h = (1.0 - 0.1 * V[:, 0] * np.sin(k / 20)).astype(np.float32)
        return {"kind": "frame", "run": self.run, "step": k, "time": 0.01 * k, "positions": W,
                "fields": {"thickness_mm": h, "thinning_pct": 100 * (1 - h),
                           "von_mises_MPa": 100 * h, "eq_plastic_strain_pct": 0 * h},
                "tools": {}, "probes": {"tip": float(W[0, 2])}, "iterations": 1,
                "residual": 1e-9}

    def command(self, msg: dict) -> None:
        """``start`` and ``stop`` as the solver does them (other commands are only replied
        to)."""
        from server.recording import Recorder

        if msg["cmd"] == "start":
            self.run, self.step, self.produced, self.dropped = msg["run"], 0, 0, 0
            self.rec = Recorder(Path(msg["out"]) / "run.rrd", self.run)
            self.emit("state", state="building")
            self.emit("meta", faces=self.F, n_steps=10**6, counts={}, element="synthetic",
                      probes=["tip"], tools=[], timing={})
            self.rec.meta(self.F)
            self.events.put(self.frame(0))
            self.emit("state", state="running")
        elif msg["cmd"] == "stop" and self.run:
            self.rec.close()
            self.emit("state", state="stopped", reason=msg.get("reason") or "stopped",
                      frames={"produced": self.produced, "dropped": self.dropped})
            self.run = None
        self.events.put({"kind": "reply", "id": msg.get("id"), "ok": True, "run": self.run,
                         "result": None})

    def tick(self) -> None:
        """The next frame, ``rate`` a second: its record, its recording, the bounded queue."""
        now = time.perf_counter()
        if now < self.t_next:
            time.sleep(self.t_next - now)
        self.t_next = max(self.t_next + 1.0 / self.rate, time.perf_counter() - 1.0 / self.rate)
        self.step += 1
        f = self.frame(self.step)
        self.produced += 1
        record = {"step": self.step, "time": f["time"], "probes": f["probes"], "iterations": 1,
                  "residual": 1e-9, "energy": 0.0, "cutbacks": 0}
        self.emit("step", record=record,
                  frames={"produced": self.produced, "dropped": self.dropped})
        self.rec.step(record)
        self.rec.frame(f, mesh=self.step % self.record_every == 0)
        try:
            self.frames.put_nowait(f)
        except queue.Full:
            self.dropped += 1


def frame_generator(commands: Channel, events: Channel, frames: Channel, record_every: int,
                    step_delay: float, n_vertices: int = 40_000, rate: float = 100.0) -> None:
    """Stands in for ``worker.worker_main``: on ``start`` it makes ``rate`` frames a second of
    an ``n_vertices`` sheet (positions and four fields, as the solver sends them), puts them on
    the bounded queue (dropped when full), sends step records and writes the recording like
    the solver process does; until ``stop``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    gen = _Synthetic(events, frames, record_every, n_vertices, rate)
    events.put({"kind": "ready", "run": None, "parameters": PARAMETERS})
    while True:
        try:
            msg = commands.get_nowait() if gen.run else commands.get(timeout=0.2)
        except queue.Empty:
            msg = None
        if msg is not None:
            if msg["cmd"] == "shutdown":
                break
            gen.command(msg)
        elif gen.run is not None:
            gen.tick()
    events.close()
    frames.close()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class ViewerClient:
    """A websocket client of the viser viewer that reads (and discards) every message."""

    def __init__(self, port: int):
        import viser
        from websockets.sync.client import connect

        self.messages = self.bytes = 0
        deadline = time.time() + 30
        while True:
            try:
                self.ws = connect(f"ws://127.0.0.1:{port}", max_size=None,
                                  subprotocols=[f"viser-v{viser.__version__}"])
                break
            except OSError:
                if time.time() > deadline:
                    raise
                time.sleep(0.2)
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self) -> None:
        try:
            while True:
                m = self.ws.recv()
                self.messages += 1
                self.bytes += len(m)
        except Exception:
            return

    def close(self) -> None:
        self.ws.close()


def _wait_http(url: str, cond: Callable[[dict], bool], timeout: float,
               proc: subprocess.Popen | None = None) -> float:
    """Seconds until ``cond(response json)`` holds for GET url."""
    import httpx

    t0 = time.perf_counter()
    while True:
        try:
            r = httpx.get(url, timeout=2)
            if r.status_code == 200 and cond(r.json()):
                return time.perf_counter() - t0
        except (httpx.HTTPError, ValueError):
            pass
        if time.perf_counter() - t0 > timeout or (proc is not None and proc.poll() is not None):
            raise RuntimeError(f"{url} not ready after {time.perf_counter() - t0:.0f} s")
        time.sleep(0.05)


def _latency(url: str, seconds: float, every: float = 0.01) -> np.ndarray:
    """Status request latencies (ms) for ``seconds``, one request every ``every`` s."""
    import httpx

    lat = []
    with httpx.Client() as c:
        t_end = time.perf_counter() + seconds
        while time.perf_counter() < t_end:
            t0 = time.perf_counter()
            c.get(url).raise_for_status()
            lat.append(time.perf_counter() - t0)
            time.sleep(every)
    return 1e3 * np.array(lat)


def cpu_pressure() -> float | None:
    """Linux PSI: % of the last 60 s in which runnable tasks waited for a CPU (other jobs on a
    shared machine show up here), or None where not available."""
    try:
        line = Path("/proc/pressure/cpu").read_text().splitlines()[0]
        return float(dict(kv.split("=") for kv in line.split()[1:])["avg60"])
    except (OSError, ValueError, KeyError, IndexError):
        return None


def _pcts(lat: np.ndarray) -> dict:
    return {"requests": len(lat), "p50_ms": float(np.percentile(lat, 50)),
            "p99_ms": float(np.percentile(lat, 99)), "max_ms": float(lat.max()),
            "cpu_pressure_avg60_pct": cpu_pressure()}


def _serve_app(settings: Settings, port: int, n_vertices: int, rate: float) -> None:
    """Child process: uvicorn with the service app, the frame generator as its solver."""
    import uvicorn

    from server.app import create_app

    target = functools.partial(frame_generator, n_vertices=n_vertices, rate=rate)
    uvicorn.run(create_app(settings, worker_target=target), host="127.0.0.1", port=port,
                log_level="warning")


def delivery(n_vertices: int, seconds: float, push_hz: float, rate: float) -> dict:
    """Frames through the real bridge and viewer, from a generator faster than the viewer."""
    import httpx

    from server.settings import Settings

    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "scenes").mkdir()
        (Path(tmp) / "scenes" / "synthetic.toml").write_text(
            (ROOT / "scenes" / "cantilever.toml").read_text())
        port, vport = _free_port(), _free_port()
        settings = Settings(scenes_dir=Path(tmp) / "scenes", runs_dir=Path(tmp) / "runs",
                            viewer_port=vport, push_hz=push_hz)
        proc = mp.get_context("spawn").Process(target=_serve_app,  # it spawns the generator
                                               args=(settings, port, n_vertices, rate))
        proc.start()
        url = f"http://127.0.0.1:{port}"
        try:
            _wait_http(url + "/api/config", lambda j: j["ready"], 60)
            client = ViewerClient(vport)
            run = httpx.post(url + "/api/runs", json={"scene": "synthetic"}).json()["id"]
            _wait_http(f"{url}/api/runs/{run}", lambda j: j["frames"].get("pushed", 0) > 0, 30)
            time.sleep(1.0)  # settle
            a = httpx.get(f"{url}/api/runs/{run}").json()["frames"]
            m0, b0, t0 = client.messages, client.bytes, time.perf_counter()
            lat = _latency(f"{url}/api/runs/{run}", seconds)
            b = httpx.get(f"{url}/api/runs/{run}").json()["frames"]
            dt = time.perf_counter() - t0
            msgs, mb = client.messages - m0, (client.bytes - b0) / 1e6
            httpx.post(f"{url}/api/runs/{run}/stop")
            client.close()
        finally:
            proc.terminate()
            proc.join(10)
    per_s = {k: (b.get(k, 0) - a.get(k, 0)) / dt for k in ("produced", "dropped", "received",
                                                           "pushed")}
    return {"vertices": int(np.sqrt(n_vertices)) ** 2, "push_hz_cap": push_hz, "seconds": dt,
            "per_s": per_s, "viewer_messages_per_s": msgs / dt, "viewer_MB_per_s": mb / dt,
            "status": _pcts(lat)}


def _serve(tmp: Path, port: int, vport: int, env: dict) -> subprocess.Popen:
    log = open(tmp / f"serve-{port}.log", "wb")  # noqa: SIM115 - the child holds it
    proc = subprocess.Popen(
        [sys.executable, "-m", "sim.apps", "serve", "cantilever", "--port", str(port),
         "--viewer-port", str(vport), "--scenes-dir", str(tmp / "scenes"),
         "--runs-dir", str(tmp / "runs")], stdout=log, stderr=subprocess.STDOUT,
        env=env, start_new_session=True)
    log.close()
    return proc


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)


def start_and_latency(seconds: float, tmp: Path, cold: bool = True) -> dict:
    """``q3t serve`` started with an empty (unless not ``cold``), then a warm numba cache;
    then, on the warm server, status latency while it builds and steps the cup blank at ~40k
    display vertices."""
    import httpx

    (tmp / "scenes").mkdir()
    for name in ("cantilever", "cup_blank"):
        shutil.copy(ROOT / "scenes" / f"{name}.toml", tmp / "scenes")
    # cold: a numba cache of its own, empty; warm only: the one this process uses (the served
    # processes compile nothing it has compiled)
    cache = {"NUMBA_CACHE_DIR": str(tmp / "numba-cache")} if cold else {}
    env = {**os.environ, **cache, "PYTHONPATH": str(ROOT), "XDG_CONFIG_HOME": str(tmp / "cfg"),
           "XDG_DATA_HOME": str(tmp / "data")}
    # the warm start after a cold one finds every kernel; alone (--warm-only) it finds what
    # this process's cache holds, which on a fresh checkout may be nothing: count what it
    # compiled, so that its row says so
    kernels = (cache or os.environ).get("NUMBA_CACHE_DIR")
    out = {"cold": None}
    for label in ("cold", "warm") if cold else ("warm",):
        before = _cached_kernels(kernels)
        port, vport = _free_port(), _free_port()
        url = f"http://127.0.0.1:{port}"
        t0 = time.perf_counter()
        proc = _serve(tmp, port, vport, env)
        try:
            page = _wait_http(url + "/api/health", lambda j: j["ok"], 120, proc)
            httpx.get(url + "/").raise_for_status()
            ready = time.perf_counter() - t0
            _wait_http(url + "/api/config", lambda j: j["ready"], 120, proc)
            solver = time.perf_counter() - t0
            client = ViewerClient(vport)
            run = httpx.post(url + "/api/runs", json={"scene": "cantilever", "overrides": {
                "mesh.edge_length": 0.035}}).json()["id"]
            _wait_http(f"{url}/api/runs/{run}", lambda j: j["state"] == "finished", 300, proc)
            timing = httpx.get(f"{url}/api/runs/{run}").json()["timing"]
            out[label] = {"page_s": ready, "page_health_s": page, "solver_ready_s": solver,
                          "first_frame_s": timing.get("first_frame_s"),
                          "first_step_s": timing.get("first_step_s")}
            if label == "warm":
                big = httpx.post(url + "/api/runs", json={"scene": "cup_blank",
                                                           "overrides": CUP_40K}).json()["id"]
                lat = _latency(f"{url}/api/runs/{big}", seconds)
                st = httpx.get(f"{url}/api/runs/{big}").json()
                out["solver_40k"] = {**_pcts(lat), "scene": "cup_blank", "overrides": CUP_40K,
                                     "state": st["state"], "step_reached": st["step"],
                                     "timing": st["timing"], "frames": st["frames"],
                                     "viewer_MB": client.bytes / 1e6}
                httpx.post(f"{url}/api/runs/{big}/stop")
            client.close()
        finally:
            _stop(proc)
        out[f"{label}_compiled"] = _cached_kernels(kernels) - before
    return out


def _ms(st: dict) -> str:
    return (f"p50 {st['p50_ms']:.1f} ms, p99 {st['p99_ms']:.1f} ms, max {st['max_ms']:.0f} ms "
            f"over {st['requests']} requests")


def _pressure(st: dict) -> str:
    p = st["cpu_pressure_avg60_pct"]
    return "" if p is None else f"{p:.0f} %"


def _cached_kernels(cache: str | None) -> int:
    """How many compiled kernels (numba's index files) ``cache`` holds."""
    return sum(1 for _ in Path(cache).rglob("*.nbi")) if cache and Path(cache).is_dir() else 0


def _start(c: dict | None) -> str:
    if c is None:
        return "not measured (--warm-only)"
    step = c["first_step_s"]
    return (f"{c['page_s']:.1f} s (solver ready {c['solver_ready_s']:.1f} s; a small run's "
            f"first frame {c['first_frame_s']:.1f} s after it was started, first step "
            + (f"{step:.1f} s)" if step is not None else "-)"))


def _warm_label(compiled: int | None) -> str:
    """The warm start's row: warm unless it compiled kernels the cache did not hold."""
    if not compiled:
        return "start-up to a ready page, warm numba cache"
    return (f"start-up to a ready page, numba cache as found ({compiled} kernels compiled "
            "during it)")


def service_md(out: dict, rate: float) -> str:
    """The measurements as one markdown table, with the targets of docs/performance.md."""
    capped, free = out["delivery"]
    s, b = out["start"], out["start"]["solver_40k"]
    sheet = f"generator at {rate:g} frames/s of a {capped['vertices']:,}-vertex sheet"
    rows = [
        (f"pushes to the viewer at the service's cap ({sheet})",
         f"{capped['per_s']['pushed']:.1f} /s ({capped['viewer_MB_per_s']:.1f} MB/s to the "
         f"client), {capped['per_s']['dropped']:.0f} /s dropped", ">= 20 /s",
         _pressure(capped["status"])),
        ("pushes, uncapped (the path's capacity)", f"{free['per_s']['pushed']:.1f} /s", "",
         _pressure(free["status"])),
        ("status requests while frames stream (capped)", _ms(capped["status"]), "",
         _pressure(capped["status"])),
        (f"status requests while `q3t serve` builds and steps `cup_blank` at edge "
         f"{1e3 * CUP_40K['mesh.edge_length']:g} mm, about 40k display vertices (viewer and "
         f"recording on; reached step {b['step_reached']}, {b['state']})", _ms(b),
         "p99 < 50 ms", _pressure(b)),
        (_warm_label(s.get("warm_compiled")), _start(s["warm"]), "10 s", ""),
        ("start-up to a ready page, empty numba cache", _start(s["cold"]), "10 s", ""),
    ]
    lines = ["| measurement | result | target | CPU pressure (60 s) |", "|---|---|---|---|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return ("Through the real bridge and viewer, with a websocket client reading everything "
            "viser sends. CPU pressure: the share of the last minute in which runnable tasks "
            "waited for a CPU (Linux PSI), what other jobs on the machine take.\n\n"
            + "\n".join(lines) + "\n")


def run(args: argparse.Namespace) -> int:
    stamp = Stamp.begin(args.command)
    out = {"stamp": asdict(stamp)}
    with tempfile.TemporaryDirectory() as tmp:
        out["start"] = start_and_latency(args.seconds_solver, Path(tmp), not args.warm_only)
    out["delivery"] = [delivery(args.vertices, args.seconds, hz, args.rate)
                       for hz in (20.0, 1000.0)]
    md = service_md(out, args.rate)
    print(md)
    path = Path(args.out)
    path.mkdir(parents=True, exist_ok=True)
    (path / "bench_service.json").write_text(results.dumps(out, nulls=True, indent=1))
    if args.results:
        write_results(args.results, "The service (`q3t bench-service`)", md, stamp)
        print(f"wrote {args.results}")
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    b = sub.add_parser("bench-service", help="viewer frame rate, API latency, start-up time")
    b.add_argument("--vertices", type=int, default=40_000)
    b.add_argument("--rate", type=float, default=100.0,
                   help="frames/s the generator makes (faster than the viewer takes them)")
    b.add_argument("--seconds", type=float, default=15.0, help="per delivery measurement")
    b.add_argument("--seconds-solver", type=float, default=60.0,
                   help="status requests while the solver runs the 40k-vertex scene")
    b.add_argument("--warm-only", action="store_true",
                   help="skip the start with an empty numba cache (it compiles the solver's "
                        "kernels first: minutes)")
    b.add_argument("--out", default="runs/bench")
    add_results_option(b, "service.md")
    b.set_defaults(func=run)

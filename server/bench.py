"""``q3t bench-service``: the viewer path and the API under load, measured (not tested).

- frames/s of position updates of a 40k-vertex sheet pushed to viser (server side), and the
  cost of a full per-vertex-coloured push;
- latency (p50/p99) of run-status requests while the solver worker steps a scene.
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import numpy as np


def _grid(n: int) -> tuple[np.ndarray, np.ndarray]:
    """A square grid of about n vertices: positions (float32) and faces."""
    m = int(np.sqrt(n))
    i, j = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
    V = np.column_stack([i.ravel(), j.ravel(), np.zeros(m * m)]).astype(np.float32) / m
    a = (i[:-1, :-1] * m + j[:-1, :-1]).ravel()
    F = np.concatenate([np.column_stack([a, a + m, a + 1]), np.column_stack([a + 1, a + m,
                                                                             a + m + 1])])
    return V, F.astype(np.int32)


def viewer_path(n_vertices: int = 40_000, frames: int = 200) -> dict:
    import trimesh
    import viser

    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        V, F = _grid(n_vertices)
        handle = server.scene.add_mesh_simple("/sheet", V, F)
        t = []
        for k in range(frames):
            W = V.copy()
            W[:, 2] = 0.01 * np.sin(k / 10 + V[:, 0] * 6)
            t0 = time.perf_counter()
            with server.atomic():
                handle.vertices = W
            t.append(time.perf_counter() - t0)
        colours = (np.random.default_rng(0).random((len(V), 4)) * 255).astype(np.uint8)
        c = []
        for _ in range(10):
            mesh = trimesh.Trimesh(V, F, vertex_colors=colours, process=False)
            t0 = time.perf_counter()
            server.scene.add_mesh_trimesh("/sheet_coloured", mesh)
            c.append(time.perf_counter() - t0)
    finally:
        server.stop()
    med = float(np.median(t))
    return {"vertices": len(V), "position_push_ms": 1e3 * med, "frames_per_s": 1.0 / med,
            "coloured_push_ms": 1e3 * float(np.median(c))}


def status_latency(requests: int = 300, scene: str = "cantilever") -> dict:
    from fastapi.testclient import TestClient

    from server.app import create_app
    from server.settings import ROOT, Settings

    with tempfile.TemporaryDirectory() as tmp:
        settings = Settings(scenes_dir=ROOT / "scenes", runs_dir=Path(tmp), viewer=False)
        with TestClient(create_app(settings)) as c:
            run = c.post("/api/runs", json={"scene": scene}).json()["id"]
            lat = []
            t_end = time.time() + 120
            while len(lat) < requests and time.time() < t_end:
                t0 = time.perf_counter()
                c.get(f"/api/runs/{run}")
                lat.append(time.perf_counter() - t0)
                time.sleep(0.01)
            state = c.get(f"/api/runs/{run}").json()
            c.post(f"/api/runs/{run}/stop")
    lat = np.array(lat) * 1e3
    return {"requests": len(lat), "p50_ms": float(np.percentile(lat, 50)),
            "p99_ms": float(np.percentile(lat, 99)), "solver_step_reached": state.get("step")}


def run(args) -> int:
    out = {"date": time.strftime("%Y-%m-%d"), "viewer": viewer_path(args.vertices),
           "status": status_latency(args.requests, args.scene)}
    v, s = out["viewer"], out["status"]
    print(f"viewer: {v['vertices']} vertices, position push {v['position_push_ms']:.2f} ms "
          f"({v['frames_per_s']:.0f} frames/s server side), coloured push "
          f"{v['coloured_push_ms']:.1f} ms")
    print(f"status while solving {args.scene}: p50 {s['p50_ms']:.1f} ms, p99 {s['p99_ms']:.1f} "
          f"ms over {s['requests']} requests (solver reached step {s['solver_step_reached']})")
    path = Path(args.out)
    path.mkdir(parents=True, exist_ok=True)
    (path / "bench_service.json").write_text(json.dumps(out, indent=1))
    return 0


def add_parser(sub) -> None:
    b = sub.add_parser("bench-service", help="viewer frame rate and API latency under load")
    b.add_argument("--vertices", type=int, default=40_000)
    b.add_argument("--requests", type=int, default=300)
    b.add_argument("--scene", default="cantilever")
    b.add_argument("--out", default="runs/bench")
    b.set_defaults(func=run)

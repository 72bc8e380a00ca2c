"""``q3t serve`` (the preview service) and ``q3t play`` (open a run's recording)."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from types import FrameType

from server.settings import ROOT, Settings, loopback

EXPOSED_VIEWER = ("q3t: warning: --expose-viewer: the viser viewer on {host}:{port} has no "
                  "token check. Anyone who can reach that port can watch every run AND use its "
                  "controls: Pause, Resume, Step and Stop (which stop runs), the run selection "
                  "and the live-parameter sliders. Expose it only on a network you trust.")


def serve_settings(args: argparse.Namespace, token: str | None) -> Settings:
    """Settings of ``q3t serve``. viser has no token check of its own: it stays on loopback
    unless --expose-viewer asks otherwise, with a warning that its controls are open too."""
    viewer_host = args.host if args.expose_viewer else "127.0.0.1"
    if args.expose_viewer and not loopback(args.host):
        print(EXPOSED_VIEWER.format(host=args.host, port=args.viewer_port), file=sys.stderr)
    if args.record_every < 1:
        raise SystemExit("q3t: --record-every must be at least 1")
    if not 0 < args.max_memory < float("inf"):
        raise SystemExit("q3t: --max-memory must be a positive size (GiB)")
    if not 0 < args.max_upload < 2**20:
        raise SystemExit("q3t: --max-upload must be a positive size (MiB), below a TiB")
    return Settings(scenes_dir=Path(args.scenes_dir), runs_dir=Path(args.runs_dir),
                    token=token, viewer=not args.no_viewer, viewer_host=viewer_host,
                    viewer_port=args.viewer_port, step_delay=args.step_delay,
                    record_every=args.record_every, default_scene=args.scene,
                    max_model_bytes=args.max_memory * 2**30,
                    max_upload=int(args.max_upload * 2**20), solvers=args.solvers,
                    queue_limit=args.queue, scheduler=args.scheduler,
                    scheduler_timeout=args.scheduler_timeout)


def at_least(least: int) -> Callable[[str], int]:
    """An argparse type: a whole number of at least ``least`` (else exit 2 naming the
    option)."""
    def count(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
        if value < least:
            raise argparse.ArgumentTypeError(f"must be at least {least}, not {value}")
        return value
    return count


def _scheduler_answers(settings: Settings) -> bool:
    """Whether the Dask scheduler of ``--scheduler`` answers and its workers can run the solver;
    if not, says why (naming the address) before any server starts."""
    from server.cluster import SchedulerError, connect

    print(f"q3t: connecting to the Dask scheduler {settings.scheduler} ...", file=sys.stderr,
          flush=True)
    try:
        client = connect(settings.scheduler, settings.scheduler_timeout)
    except SchedulerError as exc:
        print(f"q3t: {exc}", file=sys.stderr)
        return False
    workers = len(client.scheduler_info(n_workers=-1)["workers"])
    client.close()
    if not workers:
        print(f"q3t: warning: the Dask cluster at {settings.scheduler} has no worker yet: runs "
              "wait in the queue until one joins", file=sys.stderr)
    return True


def seconds(text: str) -> float:
    """An argparse type: a positive, finite number of seconds (else exit 2 naming the
    option)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not 0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"must be a positive number of seconds, not {text}")
    return value


def _stop_as_exit(signum: int, frame: FrameType | None) -> None:
    raise SystemExit(0)


def cmd_serve(args: argparse.Namespace) -> int:
    import signal

    import uvicorn

    from server.app import create_app

    token = args.token or os.environ.get("Q3T_TOKEN")
    if not loopback(args.host) and not token:
        print(f"q3t: refusing to serve on {args.host} without a token (--token or Q3T_TOKEN)",
              file=sys.stderr)
        return 2
    if token is not None and not (token.isascii() and token.isprintable() and token.strip()):
        print("q3t: the token must be printable ASCII (it travels in URLs and cookies)",
              file=sys.stderr)
        return 2
    scenes = Path(args.scenes_dir)
    if not (scenes / f"{args.scene}.toml").is_file():
        print(f"q3t: no scene {args.scene!r} in {scenes}", file=sys.stderr)
        return 2
    settings = serve_settings(args, token)
    if settings.scheduler and not _scheduler_answers(settings):
        return 2
    query = f"?token={token}" if token else ""
    print(f"q3t: open http://{args.host}:{args.port}/{query}  (API docs at /docs)",
          file=sys.stderr, flush=True)
    # uvicorn shuts the app down on SIGTERM, then raises the signal again with the handler it
    # found: by default that kills the process before Python's exit handlers run, among them
    # multiprocessing's, which release the solver queues' semaphores ("leaked semaphore
    # objects" at every shutdown). Ended this way, SIGTERM is a clean exit like Ctrl-C.
    signal.signal(signal.SIGTERM, _stop_as_exit)
    # a connection left open by a client is closed after timeout_keep_alive; a request body
    # that does not arrive is answered 408 after settings.body_timeout; at shutdown requests
    # still in flight get timeout_graceful_shutdown
    uvicorn.run(create_app(settings), host=args.host, port=args.port, log_level="warning",
                timeout_keep_alive=5, timeout_graceful_shutdown=5)
    return 0


def play_command(path: Path, web: bool, port: int) -> list[str]:
    from server.recording import rerun_cli

    if web:
        return [rerun_cli(), "--serve-web", "--bind", "127.0.0.1", "--web-viewer-port", str(port),
                "--port", str(port + 1), str(path)]
    return [rerun_cli(), str(path)]


def cmd_play(args: argparse.Namespace) -> int:
    path = Path(args.run)
    if path.is_dir():
        path = path / "run.rrd"
    elif not path.exists():
        path = Path(args.runs_dir) / args.run / "run.rrd"
    if not path.is_file():
        print(f"q3t: no recording at {path}", file=sys.stderr)
        return 2
    if args.viser:
        from server import replay

        rep = replay.load(path)
        print(f"q3t: {len(rep.steps)} recorded frames, tools {sorted(rep.tools)}; viser viewer "
              f"at http://127.0.0.1:{args.port} (Ctrl-C ends)", file=sys.stderr, flush=True)
        replay.serve(rep, "127.0.0.1", args.port, title=path.parent.name)
        return 0
    cmd = play_command(path, args.web, args.port)
    if args.web:
        print(f"q3t: rerun web viewer at http://127.0.0.1:{args.port}", file=sys.stderr)
    return subprocess.call(cmd)


def add_parser(sub: argparse._SubParsersAction) -> None:
    from server import bench

    bench.add_parser(sub)
    s = sub.add_parser("serve", help="start the browser preview service")
    s.add_argument("scene", nargs="?", default=Settings.default_scene,
                   help="default scene name (selected first on the page)")
    s.add_argument("--host", default="127.0.0.1")
    s.add_argument("--port", type=int, default=8080)
    s.add_argument("--viewer-port", type=int, default=8081, help="viser viewer port")
    s.add_argument("--token", help="access token (required unless bound to loopback)")
    s.add_argument("--scenes-dir", default=str(ROOT / "scenes"))
    s.add_argument("--runs-dir", default="runs")
    s.add_argument("--step-delay", type=float, default=0.0,
                   help="seconds between solver steps (to watch tiny scenes)")
    s.add_argument("--record-every", type=int, default=Settings.record_every, metavar="N",
                   help="steps between sheet meshes in each run's run.rrd (scalars are "
                        "recorded every step; the first and last step always)")
    s.add_argument("--max-memory", type=float, default=Settings.max_model_bytes / 2**30,
                   metavar="GIB", help="refuse a run whose model would need more memory to "
                   "build (GiB; default %(default)g: half of a 24 GiB machine)")
    s.add_argument("--solvers", type=at_least(1), default=Settings.solvers, metavar="N",
                   help="solver processes, each stepping one run; further runs wait in the "
                        "queue (default %(default)s). Each solver's steps use a core or "
                        "more: more solvers than cores make every run slower (on a 2-core "
                        "machine keep 1)")
    s.add_argument("--queue", type=at_least(0), default=Settings.queue_limit, metavar="N",
                   help="runs that may wait for a solver process; a start past them is "
                        "refused (HTTP 429; default %(default)s)")
    s.add_argument("--scheduler", metavar="ADDRESS",
                   help="run the solvers on the workers of this Dask cluster (its scheduler's "
                        "address, e.g. tcp://10.0.0.5:8786) instead of local processes; "
                        "--solvers N of them at once. The workers need q3t-forming installed, "
                        "the same version; no shared file system (each run's files come back "
                        "to --runs-dir). Not reachable within --scheduler-timeout: exit 2")
    s.add_argument("--scheduler-timeout", type=seconds, default=Settings.scheduler_timeout,
                   metavar="S", help="seconds to reach the --scheduler at start-up "
                                     "(default %(default)g)")
    s.add_argument("--max-upload", type=float, default=Settings.max_upload / 2**20,
                   metavar="MIB", help="the largest file /api/files takes (a blank mesh or a "
                   "thickness file; MiB, default %(default)g); larger uploads get 413")
    s.add_argument("--no-viewer", action="store_true", help="no viser viewer")
    s.add_argument("--expose-viewer", action="store_true",
                   help="bind the viser viewer to --host too. It has no token check: anyone "
                        "who reaches it can use its Pause/Resume/Step/Stop and parameter "
                        "controls. By default it stays on 127.0.0.1")
    s.set_defaults(func=cmd_serve)
    p = sub.add_parser("play", help="open a run's rerun recording")
    p.add_argument("run", help="run id, run folder or .rrd file")
    p.add_argument("--web", action="store_true", help="serve rerun's web viewer on 127.0.0.1")
    p.add_argument("--viser", action="store_true",
                   help="replay in a viser viewer on 127.0.0.1 (step slider, Play)")
    p.add_argument("--port", type=int, default=9090, help="viewer port (with --web or --viser)")
    p.add_argument("--runs-dir", default="runs")
    p.set_defaults(func=cmd_play)

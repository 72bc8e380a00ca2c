"""The ``q3t`` command: run, bench, serve, play, study, check."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

SCENES = Path(__file__).resolve().parents[2] / "scenes"


def resolve_scene(name: str) -> Path:
    """A TOML path or a scene name in scenes/; SceneError (exit 2) otherwise."""
    from sim.scene import SceneError

    p = Path(name)
    if p.is_file():
        return p
    q = SCENES / f"{name}.toml"
    if q.is_file():
        return q
    raise SceneError(f"no scene {name!r} (not a file, not in {SCENES})")


def parse_sets(items: list[str]) -> dict:
    from sim.scene import SceneError, parse_value

    out = {}
    for it in items:
        if "=" not in it:
            raise SceneError(f"--set needs key.path=value, got {it!r}")
        k, v = it.split("=", 1)
        out[k.strip()] = parse_value(v.strip())
    return out


def _progress(sim, rec) -> None:
    n = sim.n_steps
    bar = "#" * int(30 * rec.step / n)
    probes = " ".join(f"{k}={v:.4g}" for k, v in list(rec.probes.items())[:3])
    print(f"\r[{bar:<30}] step {rec.step}/{n} t={rec.time:.3g} newton={rec.iterations} "
          f"res={rec.residual:.2e} {probes}", end="" if rec.step < n else "\n",
          file=sys.stderr, flush=True)


def cmd_run(args) -> int:
    from sim import results, size
    from sim.scene import SceneError, load_scene
    from sim.simulation import Simulation

    overrides = parse_sets(args.set)
    if args.element:
        overrides["shell.element"] = args.element
    if not args.max_memory > 0:
        raise SceneError(f"--max-memory: {args.max_memory:g} GiB is not a positive size")
    scene = load_scene(resolve_scene(args.scene), overrides)  # SceneError: exit 2 (main)
    size.check(scene, args.max_memory * 2**30)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    out = Path(args.out or f"runs/{scene.name}-{scene.shell.element}-{stamp}")
    try:
        sim = Simulation.from_scene(scene)
    except ValueError as exc:  # bad input the build finds (a region selecting no node, ...)
        print(f"q3t: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # a failed run, not bad input: say why, with a result.json
        reason = f"build failed: {type(exc).__name__}: {exc}"
        out.mkdir(parents=True, exist_ok=True)
        results.write(out / "result.json", results.interrupted(scene.name, scene.shell.element,
                                                           reason))
        print(f"q3t: FAILED: {reason}\nwrote {out}/result.json", file=sys.stderr)
        return 1
    c = sim.result()["counts"]
    print(f"{scene.name}: {scene.shell.element}, {c['elements']} elements, {c['dofs']} DoFs, "
          f"solver {sim.model.built['linear_solver']}", file=sys.stderr)
    ok = sim.run(progress=None if args.quiet else _progress)
    sim.write(out)
    if not ok:
        print(f"\nq3t: FAILED: {sim.failure['reason']} at step {sim.failure['step']}",
              file=sys.stderr)
    print(f"wrote {out}/result.json ({sim.wall:.2f} s)", file=sys.stderr)
    return 0 if ok else 1


def main(argv: list[str] | None = None) -> int:
    from sim.size import DEFAULT_LIMIT

    ap = argparse.ArgumentParser(prog="q3t", description=__doc__)
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="run a scene headless and write result.json")
    r.add_argument("scene", help="scene name in scenes/ or a TOML path")
    r.add_argument("--element", help="override shell.element (linear, q3t, quadratic, quartic)")
    r.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scene value, e.g. material.nu=0.3 (repeatable)")
    r.add_argument("--out", help="output folder (default runs/<scene>-<element>-<time>)")
    r.add_argument("--quiet", action="store_true")
    r.add_argument("--max-memory", type=float, default=DEFAULT_LIMIT / 2**30, metavar="GIB",
                   help="refuse a scene whose model would need more memory to build (GiB; "
                        "default %(default)g: half of a 24 GiB machine)")
    r.set_defaults(func=cmd_run)
    from sim.apps import bench, check, study, sweep

    bench.add_parser(sub)
    for mod in (study, sweep, check):  # matplotlib and dask are imported only when run
        mod.add_parser(sub)
    try:  # the service commands exist only where the service stack is installed
        from server import cli as server_cli
    except ImportError:
        server_cli = None
    if server_cli is not None:
        server_cli.add_parser(sub)
    args = ap.parse_args(argv)
    from sim.scene import SceneError

    try:
        return args.func(args)
    except SceneError as exc:  # bad input, whichever command read it: exit 2 like argparse
        print(f"q3t: {exc}", file=sys.stderr)
        return 2

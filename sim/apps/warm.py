"""``q3t warm``: compile the solver's kernels into numba's cache now.

numba compiles a kernel on its first call and caches it per source of the solver
(sim.numba_cache_dir), so the first run after a checkout, an edit of sim/ or on a new machine
waits minutes for it, in whichever process comes first. ``q3t warm`` does that work up front,
by exercising each family of kernels once on a coarse shipped scene. ``--part I/N`` does the
I-th of N shares, so that N processes side by side compile N different sets instead of each
compiling the same kernels at once (numba holds no lock: two processes that miss the cache
both compile); the test suite starts that way (tests/split.py). On a warm cache it takes a
few seconds: every kernel loads from the cache.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from sim.apps.common import OK

if TYPE_CHECKING:
    from sim.scene.load import Scene

SCENES = Path(__file__).resolve().parents[2] / "scenes"
# coarse: what is compiled does not depend on the mesh, and the solve should take a second
COARSE = {"mesh.edge_length": 0.006}


def _assumed_strain() -> None:
    """The assumed-strain element loop (q3t_ans, the forming scenes' element) under the
    isotropic laws and Hill48 (one kernel: every material is a branch of it), the plastic
    commit and stress kernels, tool contact with friction (the stack machine that evaluates
    every tool shape) and assembly: two steps of the cup and a frame, then Hill48 past the
    yield point; then the tools' entry points the viewer's display meshes and the probes
    use."""
    from sim.model.build import build_model
    from sim.scene.load import load_scene
    from sim.tools.evaluate import sdf_distance, sdf_eval
    from sim.tools.shapes import tool_program
    from sim.tools.surface import tool_mesh

    scene = _steps("q3t_ans", 2)
    prog = tool_program(scene.tools[0].shape)
    tool_mesh(prog, method="implicit", resolution=8)
    sdf_eval(prog, np.zeros((1, 3)))
    sdf_distance(prog, np.zeros((1, 3)))
    m = build_model(load_scene(SCENES / "cup_drawing_aa5754.toml",
                               {**COARSE, "shell.element": "q3t_ans"}))
    term, rest = m.elasticity, m.shell.rest
    x = rest * [1.05, 1.0, 1.0]  # 5 % stretch: past the yield strain
    term.commit(x)
    term.add_gradient_hessian(x, np.zeros_like(x), np.zeros(m.pattern.nnz))
    term.von_mises(x)
    term.volume_ratios(x)


def _standard() -> None:
    """The element loop of the linear, Q3T and quadratic prisms (one kernel for the three),
    which the paper's scenes and most tests' small scenes use: a step of the cup with Q3T
    and a frame (its contact kernels again: the other share compiles them at the same
    time)."""
    _steps("q3t", 1)


def _steps(element: str, steps: int) -> Scene:
    """The coarse cup with ``element``: ``steps`` steps and a frame; its scene."""
    from sim.scene.load import load_scene
    from sim.stepping.simulation import Simulation

    scene = load_scene(SCENES / "cup_drawing.toml", {**COARSE, "shell.element": element})
    sim = Simulation.from_scene(scene)
    for _ in range(steps):
        sim.step()
    sim.frame()
    return scene


# name -> what it compiles; the shares are about equal in compile time (the assumed-strain
# kernel's compile is the longer, the standard one's the other share's whole)
TASKS: dict[str, Callable[[], None]] = {"assumed_strain": _assumed_strain,
                                        "standard": _standard}


def share(part: int, parts: int) -> list[str]:
    """The tasks of share ``part`` (1-based) of ``parts``: every ``parts``-th, from ``part``."""
    return list(TASKS)[part - 1::parts]


def parse_part(text: str) -> tuple[int, int]:
    """``I/N`` with 1 <= I <= N (argparse names the option and exits 2 otherwise)."""
    try:
        i, n = (int(v) for v in text.split("/"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not I/N (e.g. 1/2)") from None
    if not 1 <= i <= n:
        raise argparse.ArgumentTypeError(f"{text!r} needs 1 <= I <= N")
    return i, n


def run(args: argparse.Namespace) -> int:
    part, parts = args.part
    names = share(part, parts)
    if not names:
        print(f"q3t warm: share {part}/{parts} has no task (there are {len(TASKS)})")
    for name in names:
        t0 = time.perf_counter()
        TASKS[name]()
        print(f"q3t warm: {name} kernels ready in {time.perf_counter() - t0:.1f} s", flush=True)
    return OK


def add_parser(sub: argparse._SubParsersAction) -> None:
    w = sub.add_parser("warm", help="compile the solver's kernels into numba's cache now")
    w.add_argument("--part", type=parse_part, default=(1, 1), metavar="I/N",
                   help="I/N: the I-th of N shares, for N processes side by side (default 1/1)")
    w.set_defaults(func=run)

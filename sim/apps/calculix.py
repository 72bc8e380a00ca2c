"""CalculiX (``ccx``, Debian's ``calculix-ccx``) as an independent check of a static scene: our
mesh written as a CalculiX input deck (linear prisms as C3D6, quadratic ones as C3D15), ccx run
on it, and its iteration counts (``.sta``, ``.cvg``), wall time and displacements (``.dat``)
read back. ``q3t bench --cases calculix`` (sim.apps.bench_calculix) puts them beside ours.

What the deck keeps and changes:
- The same nodes and elements. C3D6 is our linear prism (its 1 x 2 rule is ours); C3D15 is our
  18-node quadratic prism without the three nodes at the centres of its side faces (serendipity,
  3 x 3 points against our 7 x 3). Q3T has no CalculiX counterpart.
- The material: ``*HYPERELASTIC, NEO HOOKE`` with C10 = mu / 2, D1 = 2 / K. It is
  C10 (I1bar - 3) + (J - 1)^2 / D1 where ours is mu/2 (I1 - 3) - mu ln J + lam/2 ln^2 J: the same
  mu and K at small strain, different at second order in the strain (``*ELASTIC`` with NLGEOM,
  St. Venant-Kirchhoff, is the other choice: ``material="elastic"``).
- The load: ``*DLOAD, GRAV`` (ccx integrates its own consistent nodal forces), ramped linearly
  over the run as ours in static stepping: one ``*STEP`` per scene step, one increment each
  (``*STATIC, DIRECT``), so an increment of CalculiX is a step of ours.
- Units: lengths in ``LENGTH`` m, stresses in Pa, so forces in ``FORCE`` = LENGTH^2 N. ccx
  sets the largest residual force to zero below 1e-6 force units (nonlingeo.c, "stress-less
  temperature calculations"): in newtons that floor is far above a 1e-8 relative residual of a
  sheet weighing newtons, and no tolerance could be matched. Stresses stay in Pa because ccx
  also replaces a NEO HOOKE D1 below 1e-10 by its own default (hyperelastics.f), which it
  would do to this sheet's D1 = 1.2e-10 /Pa in any smaller stress unit.

Convergence (the CalculiX manual, "Convergence criteria"; checkconvergence.c): an iteration of
ccx converges when the largest residual force component r_max <= R_n q (q: the "average force",
or the user's q_u) and, besides, the largest correction is small against the increment's
largest displacement (C_n) or one of its alternatives, among them r_max <= R_l q. Ours: the
residual's 2-norm <= rtol times the applied forces' 2-norm. ``CONTROLS``:
- ``default``: no ``*CONTROLS`` (R_n = 0.005 of a time-averaged mean nodal force, C_n = 0.01).
- ``matched``: q_u = our force level (the 2-norm of our nodal loads at the step's load), R_n =
  R_p = R_l = the scene's ``solver.rtol``, so only the residual decides, with our number, in the
  max-norm: ours implies it (|r|_max <= |r|_2).
- ``strict``: R_n = R_p = R_l = rtol / sqrt(free DoFs): it implies ours (|r|_2 <= sqrt(n)
  |r|_max). Ours lies between the two.
Both codes stall at a round-off floor above a 1e-8 relative residual on a thin sheet (ccx's
largest residual at about 1e-8 of the force level, ours at its measured floor), so a matched
comparison runs at a tolerance both can reach (sim.apps.bench_calculix).
"""

from __future__ import annotations

import math
import os
import re
import resource
import shutil
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from sim.elements.base import line_lagrange

if TYPE_CHECKING:
    from sim.model.build import Model

PROGRAM = "ccx"
LENGTH = 1e-4  # m: the deck's length unit (stresses in Pa, time in s)
FORCE = LENGTH ** 2  # N: its force unit
D1_MIN = 1e-10  # below it ccx takes its own NEO HOOKE D1 (hyperelastics.f)
CONTROLS = ("default", "matched", "strict")
MATERIALS = ("neo_hooke", "elastic")
# ccx reads a number field of at most 20 characters and silently misreads a longer one
# (2.4000000000000004e-09 became another D1): 13 significant digits fit with sign and exponent
FMT = ".13g"


class CalculixError(RuntimeError):
    """ccx failed or its output is not what the deck asked for; the message says which."""


def program() -> str | None:
    """The ccx executable on PATH, None when CalculiX is not installed."""
    return shutil.which(PROGRAM)


def _num(v: float) -> str:
    return format(float(v), FMT)


@dataclass(frozen=True)
class Deck:
    """An input deck and what it holds, for the checks and the bench."""

    text: str
    element: str  # C3D6 or C3D15
    nodes: int
    elements: int
    dofs: int
    free_dofs: int
    steps: int
    tip_nodes: list[int]  # ccx node ids of the tip probe's vertex column, bottom to top
    tip_weights: list[float]  # their weights at the mid-surface (w = 0)
    tip_component: int  # 0, 1, 2 = x, y, z
    force_levels: list[float]  # our nodal loads' 2-norm at each step's load (N)


def _connectivity(model: Model) -> tuple[str, np.ndarray]:
    """The CalculiX element type and our node ids in its order (0-based). Ours are layer-major,
    each layer the triangle's vertices then its edge nodes (0-1, 1-2, 2-0): C3D6 is the bottom
    then the top vertices; C3D15 the bottom and top vertices, the bottom and top edge nodes, then
    the mid-layer vertices (the mid-layer edge nodes, at face centres, have no place in it)."""
    sh = model.shell
    el = sh.element
    n = el.n_tri
    layer = [sh.conn[:, k * n:(k + 1) * n] for k in range(el.n_layers)]
    if (el.p, el.q) == (1, 1):
        return "C3D6", np.hstack([layer[0], layer[1]])
    if (el.p, el.q) == (2, 2):
        return "C3D15", np.hstack([layer[0][:, :3], layer[2][:, :3], layer[0][:, 3:6],
                                   layer[2][:, 3:6], layer[1][:, :3]])
    raise ValueError(f"element {el.name!r} has no CalculiX counterpart (C3D6: linear, C3D15: "
                     "quadratic)")


def _check_scene(model: Model) -> None:
    """ValueError unless the scene is what the deck writes: static, gravity only, supports that
    hold still, no tools."""
    sc = model.scene
    if sc.stepping.kind != "static":
        raise ValueError("stepping.kind: the CalculiX deck is written for static stepping")
    if sc.tools:
        raise ValueError("tools: the CalculiX deck has no contact")
    if any(ld.kind != "gravity" for ld in sc.loads) or not sc.loads:
        raise ValueError("loads: the CalculiX deck carries gravity loads only")
    if sc.material.model != "neo_hookean":
        raise ValueError("material.model: the CalculiX deck maps neo_hookean only")
    if model.driven:
        raise ValueError("bcs: the CalculiX deck holds supports still (no prescribed motion)")
    if sc.stepping.release:
        raise ValueError("stepping.release: the CalculiX deck has no springback step")


def _tip(model: Model) -> tuple[int, np.ndarray, int]:
    """The vertex, mid-surface weights and component of the scene's first displacement probe,
    found as sim.frames.probes finds it (the nearest mesh vertex)."""
    sh = model.shell
    probe = next((p for p in model.scene.probes if p.kind == "displacement"), None)
    if probe is None:
        raise ValueError("probes: the CalculiX comparison needs a displacement probe")
    v = int(np.argmin(np.linalg.norm(sh.mesh.vertices - np.array(probe.point), axis=1)))
    weights, _ = line_lagrange(sh.element.q, np.zeros(1))
    return v, weights[0], "xyz".index(probe.component)


def _controls(setting: str, rtol: float, level: float, free: int) -> list[str]:
    if setting == "default":
        return []
    r = rtol if setting == "matched" else rtol / math.sqrt(free)
    # R_n, C_n, q_0, q_u, R_p, eps, C_eps, R_l: R_l = R_n makes the residual alone decide
    return ["*CONTROLS, PARAMETERS=FIELD",
            ",".join([_num(r), "0.01", "", _num(level / FORCE), _num(r), "1e-5", "1e-3",
                      _num(r)])]


def write_deck(model: Model, setting: str = "matched", material: str = "neo_hooke") -> Deck:
    """The scene of ``model`` (a built sim.model.build.Model) as a CalculiX input deck, with
    the convergence controls ``setting`` (``CONTROLS``). ValueError naming the field when the
    scene is not one the deck can carry."""
    if setting not in CONTROLS:
        raise ValueError(f"setting: unknown {setting!r}; known: {', '.join(CONTROLS)}")
    if material not in MATERIALS:
        raise ValueError(f"material: unknown {material!r}; known: {', '.join(MATERIALS)}")
    _check_scene(model)
    kind, conn = _connectivity(model)
    sc, sh = model.scene, model.shell
    used = np.unique(conn)
    X = model.x0[:sh.n_nodes]
    fixed = model.fixed[:sh.n_nodes]
    n_free = int((~fixed[used]).sum())
    lines = ["** written by q3t (sim.apps.calculix) from scene " + sc.name,
             f"** units: length {_num(LENGTH)} m, stress Pa, force {_num(FORCE)} N, time s",
             "*NODE, NSET=Nall"]
    lines += [f"{i + 1}, " + ", ".join(_num(c / LENGTH) for c in X[i]) for i in used]
    lines.append(f"*ELEMENT, TYPE={kind}, ELSET=Eall")
    lines += [f"{e + 1}, " + ", ".join(str(i + 1) for i in row) for e, row in enumerate(conn)]
    lines.append("*BOUNDARY")
    lines += [f"{i + 1}, {c + 1}, {c + 1}" for i in used for c in range(3) if fixed[i, c]]
    m = sc.material
    mu, K = m.E / (2 * (1 + m.nu)), m.E / (3 * (1 - 2 * m.nu))
    lines += ["*MATERIAL, NAME=SHEET"]
    if material == "neo_hooke":
        if 2 / K < D1_MIN:
            raise ValueError(f"material: D1 = 2/K = {2 / K:.3g} /Pa is below ccx's {D1_MIN:g}, "
                             "which it would replace by its own default")
        lines += ["*HYPERELASTIC, NEO HOOKE", f"{_num(mu / 2)}, {_num(2 / K)}"]
    else:
        lines += ["*ELASTIC", f"{_num(m.E)}, {_num(m.nu)}"]
    # the mass unit is FORCE s^2 / LENGTH = LENGTH kg
    lines += ["*DENSITY", _num(m.density * LENGTH ** 2),
              "*SOLID SECTION, ELSET=Eall, MATERIAL=SHEET"]
    v, weights, comp = _tip(model)
    tip = [k * sh.n_plane + v + 1 for k in range(sh.element.n_layers)]
    lines += ["*NSET, NSET=TIP", ", ".join(map(str, tip))]
    g = np.sum([np.asarray(ld.vector, float) for ld in sc.loads], axis=0)
    mag = float(np.linalg.norm(g))
    steps = sc.stepping.steps
    full = float(np.linalg.norm(model.external.f)) if model.external is not None else 0.0
    levels = [full * k / steps for k in range(1, steps + 1)]
    for k in range(1, steps + 1):
        lines += ["*STEP, NLGEOM, INC=1000", "*STATIC, DIRECT", "1., 1."]
        lines += _controls(setting, sc.solver.rtol, levels[k - 1], n_free)
        lines += ["*DLOAD", "Eall, GRAV, " + ", ".join(_num(c) for c in
                                                       (mag / LENGTH * k / steps, *(g / mag)))]
        lines += ["*NODE PRINT, NSET=TIP", "U", "*END STEP"]
    return Deck("\n".join(lines) + "\n", kind, len(used), len(conn), 3 * len(used), n_free,
                steps, tip, [float(w) for w in weights], comp, levels)


# ---- reading ccx's output ----

@dataclass(frozen=True)
class Increment:
    """A converged increment of ``.sta``: its step, increment, attempt and iterations."""

    step: int
    increment: int
    attempt: str  # "1"; a cut-back increment carries more (and a "U" for unconverged tries)
    iterations: int


@dataclass(frozen=True)
class Iteration:
    """One row of ``.cvg``: the largest residual force over the average force and the largest
    correction over the increment's largest displacement, both in %."""

    step: int
    increment: int
    attempt: int
    iteration: int
    residual_pct: float
    correction_pct: float


_INT = r"\s+(\d+)"
_NUM = r"\s+([-+0-9.Ee]+)"
_STA = re.compile(r"^\s*(\d+)" + _INT + r"\s+(\d+U?)" + _INT + _NUM * 3 + r"\s*$")
_CVG = re.compile(r"^\s*(\d+)" + _INT * 4 + _NUM * 4 + r"\s*$")


def parse_sta(text: str) -> list[Increment]:
    """The increments of a ``.sta`` file, in order; ValueError when it holds none."""
    out = [Increment(int(m[1]), int(m[2]), m[3], int(m[4]))
           for m in map(_STA.match, text.splitlines()) if m]
    if not out:
        raise ValueError("no increment in the .sta file")
    return out


def parse_cvg(text: str) -> list[Iteration]:
    """The iterations of a ``.cvg`` file, in order; ValueError when it holds none."""
    out = [Iteration(int(m[1]), int(m[2]), int(m[3]), int(m[4]), float(m[6]), float(m[7]))
           for m in map(_CVG.match, text.splitlines()) if m]
    if not out:
        raise ValueError("no iteration in the .cvg file")
    return out


_DAT_HEAD = re.compile(r"displacements \(vx,vy,vz\) for set (\S+) and time\s+(\S+)")


def parse_dat_displacements(text: str) -> list[tuple[float, dict[int, np.ndarray]]]:
    """The ``*NODE PRINT ... U`` blocks of a ``.dat`` file: (time, {node: (ux, uy, uz)})."""
    blocks: list[tuple[float, dict[int, np.ndarray]]] = []
    for line in text.splitlines():
        head = _DAT_HEAD.search(line)
        if head:
            blocks.append((float(head[2]), {}))
            continue
        parts = line.split()
        if blocks and len(parts) == 4 and parts[0].isdigit():
            blocks[-1][1][int(parts[0])] = np.array([float(p) for p in parts[1:]])
    return blocks


def threads_used(log: str) -> int:
    """The most threads ccx says it used (``Using up to N cpu(s)``), 1 when it says nothing."""
    return max((int(n) for n in re.findall(r"Using up to (\d+) cpu", log)), default=1)


# ---- running it ----

@dataclass
class CcxRun:
    """One ccx run of a deck: wall and CPU time of the process, iterations, the probe."""

    wall: float
    cpu: float  # user + system seconds of ccx's threads (less moved by a loaded machine)
    iterations: int
    per_step: list[int]
    attempts: int  # increments tried, cut-backs included (the scene's steps when none)
    tip: list[float]  # the probe's displacement at the end of each step (m)
    threads: int
    residuals: list[Iteration] = field(default_factory=list)


def run_deck(deck: Deck, folder: Path, ccx: str, threads: int | None = None,
             timeout: float = 3600.0) -> CcxRun:
    """Write ``deck`` to ``folder/job.inp``, run ``ccx -i job`` there and read its output;
    CalculixError with ccx's last words when it fails."""
    folder.mkdir(parents=True, exist_ok=True)
    for old in folder.glob("job.*"):
        old.unlink()
    (folder / "job.inp").write_text(deck.text)
    env = {**os.environ, "OMP_NUM_THREADS": str(threads or os.cpu_count() or 1)}
    t, before = time.perf_counter(), _children_cpu()
    try:
        p = subprocess.run([ccx, "-i", "job"], cwd=folder, capture_output=True, text=True,
                           env=env, timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        raise CalculixError(f"ccx took over {timeout:.0f} s on {folder / 'job.inp'}") from None
    wall, cpu = time.perf_counter() - t, _children_cpu() - before
    (folder / "ccx.log").write_text(p.stdout + p.stderr)
    return read_run(folder, deck, wall, p.returncode, p.stdout + p.stderr, cpu)


def _children_cpu() -> float:
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def _last_words(log: str) -> str:
    errors = [ln.strip() for ln in log.splitlines() if "ERROR" in ln]
    return "; ".join(errors[-3:]) or " ".join(log.split()[-30:])


def read_run(folder: Path, deck: Deck, wall: float, returncode: int, log: str,
             cpu: float = float("nan")) -> CcxRun:
    """What a finished ccx run in ``folder`` did; CalculixError unless it ended every step."""
    sta = folder / "job.sta"
    try:
        incs = parse_sta(sta.read_text()) if sta.is_file() else []
    except ValueError:
        incs = []
    done = [i for i in incs if not i.attempt.endswith("U")]
    if returncode != 0 or "Job finished" not in log or len({i.step for i in done}) < deck.steps:
        raise CalculixError(f"ccx did not finish the {deck.steps} steps (exit {returncode}, "
                            f"{len(done)} increments converged): {_last_words(log)}")
    per_step = [sum(i.iterations for i in incs if i.step == s) for s in range(1, deck.steps + 1)]
    cvg = folder / "job.cvg"
    blocks = parse_dat_displacements((folder / "job.dat").read_text())
    if len(blocks) < deck.steps:
        raise CalculixError(f"job.dat holds {len(blocks)} displacement blocks, "
                            f"expected {deck.steps}")
    tip = [LENGTH * float(sum(w * b[n][deck.tip_component]
                     for w, n in zip(deck.tip_weights, deck.tip_nodes, strict=True)))
           for _, b in blocks[-deck.steps:]]
    return CcxRun(wall, cpu, sum(per_step), per_step, len(incs), tip, threads_used(log),
                  parse_cvg(cvg.read_text()) if cvg.is_file() else [])

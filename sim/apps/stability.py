"""Stability of an equilibrium: the lowest eigenvalues of the stiffness (the exact Hessian of the
total energy with the held DoFs removed), followed along a static load path.

An equilibrium is stable while the stiffness is positive definite; where its lowest eigenvalue
crosses zero the path bifurcates (a plate in tension that wrinkles, a column that buckles), and
the eigenvector there is the shape it buckles into. A perfect model has no reason to leave the
fundamental path (a flat plate pulled in its plane has no out-of-plane force), so past the
crossing Newton keeps the unstable flat state; ``follow`` can then push the state along the
unstable mode, as one seeds an eigenmode imperfection, and the next step finds the buckled
branch.

Lives in sim/apps, with the commands: it uses the solver (Problem, Simulation) and adds nothing
the kernels reach, so editing it does not void numba's cache (sim.numba_cache_dir).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from sim.frames.fields import mid_surface
from sim.solve.problem import Problem

if TYPE_CHECKING:
    from sim.geometry.trimesh import TriMesh
    from sim.stepping.simulation import Simulation, StepRecord


def free_hessian(problem: Problem, x: np.ndarray) -> tuple[sp.csc_matrix, np.ndarray]:
    """The exact Hessian of the total energy at x (no PSD projection: a projected tangent is
    positive by construction and would hide the instability) restricted to the free DoFs, and
    the flat indices of those DoFs."""
    data = problem.evaluate(x, exact=True)[3]
    free = np.flatnonzero(~problem.fixed.ravel())
    K = problem.pattern.matrix(data).tocsc()
    return K[free][:, free].tocsc(), free


@dataclass
class Spectrum:
    """The lowest eigenvalues ``values`` (ascending), their ``vectors`` (free DoFs, unit
    2-norm, columns), ``negative``: how many eigenvalues of the whole matrix are below zero (its
    inertia), and ``shift``: where the Lanczos iteration was shifted to; ``zero``: the
    threshold of that count (s0 of :func:`lowest_eigenvalues`)."""

    values: np.ndarray
    vectors: np.ndarray
    negative: int
    shift: float
    # s0: an eigenvalue below it is negative, counted in ``negative``; a numerical threshold
    # (1e-13 of the mean diagonal, lowest_eigenvalues), not one set by the physics
    zero: float = 0.0


def _factor(K: sp.csc_matrix, shift: float) -> spla.SuperLU | None:
    """SuperLU of K - shift I with a symmetric ordering and diagonal pivots only, so that it is
    K - shift I = L D L^T up to scaling and the signs of U's diagonal are the signs of D; None
    when a pivot is zero (the shift sits on an eigenvalue)."""
    A = (K - shift * sp.identity(K.shape[0], format="csc")).tocsc()
    try:
        lu = spla.splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                       options=dict(SymmetricMode=True))
    except RuntimeError:
        return None
    d = lu.U.diagonal()
    # SuperLU takes an off-diagonal pivot where a diagonal one is exactly zero, and then the
    # signs of U's diagonal are no inertia: only a factor with the rows in the columns' order
    # counts
    if not np.array_equal(lu.perm_r, lu.perm_c):
        return None
    return lu if np.all(np.isfinite(d)) and np.all(d != 0) else None


def _below(lu: spla.SuperLU) -> int:
    """How many eigenvalues lie below the shift of ``lu``: the negative pivots (Sylvester's law
    of inertia)."""
    return int(np.sum(lu.U.diagonal() < 0))


def lowest_eigenvalues(K: sp.spmatrix, k: int = 3) -> Spectrum:
    """The ``k`` algebraically lowest eigenpairs of the symmetric K and its inertia.

    Shift-invert Lanczos (ARPACK) finds the eigenvalues nearest a shift s, fast; the lowest ones
    are those nearest s once no eigenvalue lies below s, which the inertia of K - s I says.
    s starts as a tiny negative number, 1e-13 of the mean diagonal (K itself is singular exactly
    at a bifurcation; a thin sheet's lowest eigenvalues are 1e-9 of its diagonal, so 1e-10 hid
    some), and while eigenvalues lie below it goes ten times further down: a few factorisations
    past a bifurcation, one before it. ``negative`` counts K's eigenvalues below the first
    shift that factors with diagonal pivots (s0, a hair below zero): the unstable modes."""
    n = K.shape[0]
    if not 1 <= k < n:
        raise ValueError(f"k = {k}: need 1 <= k < {n} (the free DoFs)")
    K = sp.csc_matrix(K)
    scale = float(np.abs(K.diagonal()).mean())
    shift, negative, lu = -1e-13 * scale, None, None
    for _ in range(40):
        lu = _factor(K, shift)
        if lu is not None:
            below = _below(lu)
            if negative is None:
                negative, s0 = below, shift
            if below == 0:
                break
        shift *= 10  # a pivot was zero, or eigenvalues lie below: further down
    else:
        raise RuntimeError(f"no shift down to {shift:.3g} has K - s I positive definite")
    op = spla.LinearOperator((n, n), matvec=lu.solve, dtype=float)
    # a seeded random start: ARPACK's own would make the result differ from run to run in its
    # last bits, and a uniform one is orthogonal to every mode a symmetric mesh turns
    # antisymmetric, which Lanczos then never finds
    v0 = np.random.default_rng(0).standard_normal(n)
    vals, vecs = spla.eigsh(K, k=k, sigma=shift, which="LM", OPinv=op, v0=v0, tol=1e-10)
    order = np.argsort(vals)
    vals, vecs = vals[order], vecs[:, order]
    if negative < k and int(np.sum(vals < s0)) != negative:
        raise RuntimeError(f"Lanczos found {int(np.sum(vals < s0))} eigenvalues below "
                           f"{s0:.3g} where the inertia counts {negative}: it missed some")
    return Spectrum(vals, vecs, negative, shift, s0)


# a field whose overlap with the unstable modes is under this share of its norm misses them
# (round-off: every one of them in another symmetry class than the field)
MISSES = 1e-6


def corner_lift(x0: np.ndarray) -> np.ndarray:
    """A sheet lifted at one corner ``(n_nodes, 3)``: z = (1 + xi)(1 + eta), with xi, eta the
    rest positions scaled to [-1, 1] over their bounding box, the same at every node of a fibre.
    It holds all four symmetry classes of a rectangle (1, xi, eta, xi eta), and on a uniform
    mesh its overlap with a smooth mode approximates an integral (a sum over nodes, not
    weighted by their areas), so elements and meshes see nearly the same imperfection."""
    lo, hi = x0.min(axis=0), x0.max(axis=0)
    span = np.where(hi > lo, hi - lo, 1.0)
    xi = 2.0 * (x0 - lo) / span - 1.0
    out = np.zeros_like(x0)
    out[:, 2] = (1.0 + xi[:, 0]) * (1.0 + xi[:, 1])
    return out


def unstable_direction(spec: Spectrum, field: np.ndarray) -> np.ndarray:
    """The unit direction on the free DoFs to kick along: ``field`` (free DoFs) through the
    negative part of the stiffness, K_- field: each unstable mode (its eigenvalue below the
    inertia's threshold ``spec.zero``; ``spec`` holds every one) weighted by how far below it
    lies, as a step of gradient flow grows an imperfection. A function of K, not of the
    vectors Lanczos returned: a pair of nearly equal eigenvalues, whose vectors come in
    whatever basis round-off gives, enters by its span, and the direction moves with K
    continuously, not by a jump where round-off reorders the pair. A stable state's is its
    lowest mode; a field that misses the modes (``MISSES``) leaves the lowest, its largest
    entry positive (a sign that mirror-symmetric entries leave to round-off: in practice an
    in-plane mode, which ``follow`` does not kick along). Only z is lifted: an in-plane
    unstable mode gets no weight."""
    weights = np.maximum(spec.zero - spec.values, 0.0)
    if not weights.any():
        weights = (np.arange(spec.values.size) == 0).astype(float)
    vectors = spec.vectors[:, weights > 0]
    overlap = vectors.T @ field
    if np.linalg.norm(overlap) <= MISSES * np.linalg.norm(field):
        v = spec.vectors[:, 0]
        return v * np.sign(v[np.argmax(np.abs(v))])
    direction = vectors @ (weights[weights > 0] * overlap)
    return direction / np.linalg.norm(direction)


def expand(vector: np.ndarray, free: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """A vector on the free DoFs as an (n_nodes, 3) array, zero on the held ones."""
    out = np.zeros(int(np.prod(shape)))
    out[free] = vector
    return out.reshape(shape)


@dataclass
class PathPoint:
    """One converged step of a followed load path."""

    step: int
    time: float  # scene time (the load factor of static stepping)
    strain: float  # nominal strain of the pulled end (``follow``'s ``end``)
    eigenvalues: list[float]  # the lowest, ascending (N/m)
    negative: int  # eigenvalues below s0, a hair below zero (the inertia; lowest_eigenvalues)
    out_of_plane: float  # share of the unstable direction's squared norm in z: 1 for a wrinkle
    amplitude: float  # height range of the mid-surface (m)
    iterations: int  # Newton iterations of the step
    kicked: bool = False  # the state was pushed along the unstable direction after this step
    modes: int = 1  # eigenpairs the unstable direction is made of (its negative eigenvalues)
    rms: float = 0.0  # root mean square height of the mid-surface over its area (m, rms_height)


def nominal_strain(sim: Simulation, nodes: np.ndarray, direction: np.ndarray) -> float:
    """Mean displacement of ``nodes`` along ``direction`` over the sheet's rest extent along
    it: the engineering strain of a strip pulled at that end."""
    rest = sim.model.shell.rest
    u = (sim.x[nodes] - sim.model.x0[nodes]) @ direction
    extent = np.ptp(rest[: sim.model.shell.n_nodes] @ direction)
    return float(u.mean() / extent)


# a height range under this many thicknesses is the flat sheet: a flat path's round-off
# heights are 1e-8 of the thickness (docs/results/fig4-wrinkling.md), the kick a tenth of it
FLAT = 1e-3
# before the first kick, a step that ends unstable or off the plane is retaken in halves, at most
# this many times: the crossing then lies in a step of 1/8 of a planned one (tool_speed goes
# down to 0.1 of a planned step, sim.stepping.parameters)
HALVINGS = 3
# Newton's cap for the step after a kick. That step leaves an unstable equilibrium for the
# branch down a valley whose stiffness is nearly neutral; it runs on the exact Hessian shifted
# past its negative eigenvalues (NewtonSettings.indefinite), as projected corrections crossed
# it in many short steps (q3t_ans's stretched sheet: 234), and a shorter increment does not
# shorten the valley. A stall still ends it sooner (NewtonSettings.patience)
KICKED_ITERATIONS = 1000
# what a step changes in a Simulation, saved to retake it (``_mark``)
_STEPPING = ("x", "t", "progress", "_stroked", "step_index", "_last_increment", "_last_dt",
             "_force_level")


def history(sim: Simulation) -> str:
    """What makes the state depend on the path, not only on the load (plastic flow, tools'
    contact and friction): a step cannot be retaken there by restoring the state; "" when
    nothing does."""
    plastic = any(getattr(t, "plastic", False) for t in sim.model.terms)
    return "plastic flow" if plastic else "tools" if sim.tools else ""


def _mark(sim: Simulation) -> dict:
    return {k: np.copy(v) if isinstance(v := getattr(sim, k), np.ndarray) else v
            for k in _STEPPING} | {"records": len(sim.records)}


def _back(sim: Simulation, mark: dict) -> None:
    for k in _STEPPING:
        setattr(sim, k, mark[k])
    del sim.records[mark["records"]:]


def _observe(sim: Simulation, nodes: np.ndarray, direction: np.ndarray, k: int, step: int,
             iterations: int) -> tuple[PathPoint, np.ndarray]:
    """The path point of ``sim``'s state and its unstable direction ``(n_nodes, 3)``
    (``unstable_direction`` with the ``corner_lift`` field)."""
    K, free = free_hessian(sim.model.problem, sim.x)
    spec = lowest_eigenvalues(K, k)
    # the unstable direction needs every eigenvalue the inertia counts negative; asked for one
    # more than that, lowest_eigenvalues checks that Lanczos found them all
    if spec.negative >= spec.values.size:
        if spec.negative + 1 >= K.shape[0]:
            raise RuntimeError(f"{spec.negative} negative eigenvalues of {K.shape[0]}: no "
                               "stable mode left to tell the unstable ones by")
        spec = lowest_eigenvalues(K, spec.negative + 1)
    field = corner_lift(sim.model.x0).ravel()[free]
    mode = expand(unstable_direction(spec, field), free, sim.x.shape)
    zshare = float(np.sum(mode[:, 2] ** 2) / np.sum(mode**2))
    z = mid_surface(sim.model, sim.x)[:, 2]
    return PathPoint(step, sim.t, nominal_strain(sim, nodes, direction),
                     spec.values[:k].tolist(), spec.negative, zshare, float(z.max() - z.min()),
                     iterations, modes=max(spec.negative, 1),
                     rms=rms_height(sim.model.shell.mesh, z)), mode


def rms_height(mesh: TriMesh, z: np.ndarray) -> float:
    """sqrt(integral of z^2 over the rest mid-surface / its area), z at its vertices, each
    weighted by a third of its triangles' rest area. Where two wrinkle patterns mix at
    almost no cost (a nearly neutral mode: the symmetric and the antisymmetric one of the
    stretched sheet), Newton may stop anywhere along the mix the residual target allows, and
    the height range with it; the patterns being orthogonal, this measure stays (q3t_ans at
    4 %: two descents after the kick 0.576 and 0.595 mm high, the same RMS to four digits)."""
    V, F = mesh.vertices, mesh.faces
    area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]),
                                axis=1)
    w = np.bincount(F.ravel(), np.repeat(area / 3.0, 3), minlength=len(V))
    return float(np.sqrt(w @ z**2 / w.sum()))


def _wrinkles(point: PathPoint) -> bool:
    """Whether ``point`` is unstable and its unstable direction a wrinkle to kick along:
    mostly out of the plane (an in-plane one, a neck or an edge mode, has no z to scale the
    kick by). Unstable: the inertia counts a negative eigenvalue, one below its threshold a
    hair below zero. A wrinkled branch can be so nearly neutral that its lowest eigenvalue
    lies between that threshold and zero (q3t_ans's stretched sheet: -2.4e-8 N/m, the next
    1.5e-4): its sign there is the converged state's residual as much as the branch's, and
    the direction and sign of a kick along it decided whether the next step converged."""
    return point.negative > 0 and point.out_of_plane > 0.5


def _at_converged(sim: Simulation) -> None:
    """The loads back at the scene time of ``sim``'s state after a failed step: its failed
    sub-step left them at its own time (the Hessian of a follower load depends on them)."""
    from sim.model.curves import load_factor

    m = sim.model
    if m.external is not None:
        m.external.factor = float(load_factor(m.scene.stepping, sim.t)) \
            * sim.parameters["load_scale"]


def _shorter_step(sim: Simulation, iterations: int) -> StepRecord:
    """The converged part of a failed step made a step of its own, ending at ``sim``'s state:
    Simulation._advance commits each converged sub-step, so after a SolverFailure the state is
    the last of them, at ``sim.t``, and only the step's bookkeeping is missing (what _advance
    does after its last sub-step). The failure is cleared; ``iterations``: Newton's, failed
    sub-steps' included, as a step counts them. The next step ends at the next planned one
    (``follow`` realigns)."""
    from sim.frames import probes
    from sim.stepping.simulation import StepRecord

    m = sim.model
    cutbacks = sim.failure["cutbacks"]
    sim.failure = None
    sim.progress = sim.t / sim._dt()
    sim._stroked += 1
    sim.step_index += 1
    g = m.problem.gradient(sim.x)
    g[m.problem.fixed] = 0.0  # the residual Newton measures: the held DoFs' reactions left out
    rec = StepRecord(sim.step_index, sim.t, iterations, float(np.linalg.norm(g)),
                     m.problem.energy(sim.x), cutbacks, probes.evaluate(m, sim.x),
                     sim._tool_reports(), sim._lag_change(sim.x), sim._sheet())
    sim.records.append(rec)
    sim._record_sections()
    return rec


def follow(sim: Simulation, nodes: np.ndarray, direction: np.ndarray, k: int = 3,
           kick: float = 0.0) -> Iterator[PathPoint]:
    """Step ``sim`` (a static Simulation) to its end, yielding at its start (step 0) and after
    each converged step the lowest ``k`` eigenvalues of its stiffness and how far the
    mid-surface left its plane.

    ``kick`` (m, 0: never): each time a converged state is unstable (``_wrinkles``) and
    its unstable direction mostly out of plane, add that direction, scaled so that its largest
    mid-surface |z| is ``kick``, to the state, so the next step starts off the unstable
    equilibrium. The direction is a sheet lifted at one corner (``corner_lift``) through the
    negative part of the stiffness (``unstable_direction``): fixed by the stiffness, not by the
    basis or the signs the eigensolver returned its modes in, so runs are kicked alike and
    every element by the same imperfection, into the modes that crossed zero in the same step
    too. The kick moves the state
    the first time off the flat (fundamental) path, later off a wrinkled state that is itself
    unstable (a secondary bifurcation), which Newton's iterates would otherwise leave or not
    as round-off has it. The kick is small
    against the wrinkle (a tenth of the thickness or less).

    Until the first kick the path is the flat (fundamental) one, and a step that ends with a
    negative eigenvalue of an out-of-plane mode, or off the plane (``FLAT``), is retaken in
    halves from the state before it (``HALVINGS`` times at most; a sim whose state has a
    ``history`` cannot be: ValueError), so the crossing is found on converged flat states and
    the kick made at most 1/8 of a step past it. A long step across the crossing lets
    Newton's iterates, which leave the plane far from equilibrium (the projected Hessian's
    corrections are mirror-symmetric only to round-off), settle on whichever wrinkled branch
    round-off picked; a short one from a flat stable state stays on the plane. A step of 1/8
    that still leaves the plane ends the path failed (``sim.failure``), not on a branch
    round-off chose. After it the steps realign with the planned ones.

    After the first kick, a step that fails after some of its sub-steps converged ends at the
    last of them, a shorter step of the path, when that state is unstable out of plane
    (``_wrinkles``): a further bifurcation inside the step, onto whose unstable
    state Newton, with its projected (positive) Hessian, cannot converge. That state is then
    kicked like any other, and the next step ends at the next planned one. The step after a
    kick may take Newton up to ``KICKED_ITERATIONS`` (each attempt), the others the scene's
    cap; in those others an iterate whose exact Hessian is indefinite makes progress only by
    its residual's fall, not by its energy's (NewtonSettings.descent_is_progress), so an
    attempt that crawls down a negative curvature fails after the scene's ``patience`` (the
    stretched sheet's step across its second instability spent hundreds of iterations in
    attempts that crawled to the cap). A failed step with no unstable state to kick (none
    converged, or a stable one) is retaken from its start with the descent counted as
    progress, as a snap to a far branch needs; the path ends early when that fails too, or
    when the step after a kick fails (the Simulation's ``failure`` says why)."""
    from sim.stepping.simulation import SolverFailure

    if kick and (why := history(sim)):
        raise ValueError(f"a kick retakes steps from a saved state, which {why} makes "
                         "path-dependent")
    direction = np.asarray(direction, float) / np.linalg.norm(direction)
    thickness = float(np.mean(sim.model.shell.thickness))
    kicked, length = False, 1.0  # the step's length in planned steps
    point, mode = _observe(sim, nodes, direction, k, 0, 0)
    while True:
        if kick and _wrinkles(point):
            zmode = mid_surface(sim.model, mode)[:, 2]
            sim.x = sim.x + mode * (kick / np.abs(zmode).max())
            kicked = point.kicked = True
        yield point
        if sim.done:
            return
        flat_path = bool(kick) and not kicked
        # the rest of the planned step (after halved ones), else a whole one
        rest = float(np.ceil(sim.progress - 1e-9) - sim.progress)
        rest = rest if rest > 1e-9 else 1.0
        # a shorter step (the converged part of a failed one) can end nearer a planned step
        # than the least tool_speed: the next one goes on to the planned step after it
        rest += 1.0 if rest < sim.ranges["tool_speed"][0] else 0.0
        length = min(length, rest) if flat_path and rest < 1.0 else rest
        # without a kick a failed step is not retaken (nothing to restore it from): its
        # attempts count a descent as progress from the first
        settings, after_kick, crawl = sim.model.settings, point.kicked, not kick
        while True:
            mark = _mark(sim) if kick else None
            if sim.parameters["tool_speed"] != length:
                sim.set_parameter("tool_speed", length)
            t0, iterations0 = sim.t, sim.timing.iterations
            # a step after a kick descends from the unstable state, and its energy's fall is
            # its progress; any other ends at a stable state, or fails where its projected
            # corrections only go down a negative curvature (``crawl``: retaken allowing it)
            sim.model.settings = (replace(settings, indefinite="shift", max_iterations=max(
                settings.max_iterations, KICKED_ITERATIONS)) if after_kick
                else replace(settings, descent_is_progress=crawl))
            try:
                rec = sim.step()
            except SolverFailure:
                # past the first kick a step can cross a further bifurcation, and Newton (its
                # projected Hessian is positive) cannot settle on the unstable state past it:
                # a converged sub-step that is unstable ends a shorter step, kicked at the top
                if kicked and sim.t > t0:
                    _at_converged(sim)
                    point, mode = _observe(sim, nodes, direction, k, sim.step_index + 1,
                                           sim.timing.iterations - iterations0)
                    if _wrinkles(point):
                        _shorter_step(sim, point.iterations)
                        break
                if after_kick or crawl or mark is None:
                    return
                # no unstable state to kick: the step again from its start, a descent on
                # an indefinite Hessian progress this time (a snap to a far branch)
                _back(sim, mark)
                sim.failure, crawl = None, True
                continue
            finally:
                sim.model.settings = settings
            point, mode = _observe(sim, nodes, direction, k, rec.step, rec.iterations)
            left_plane = point.amplitude > FLAT * thickness
            if not (flat_path and (_wrinkles(point) or left_plane)):
                break
            if length <= 2.0**-HALVINGS:
                if left_plane:
                    sim.end(f"the flat sheet left its plane ({point.amplitude:.3g} m) without "
                            f"a kick in a step of {length:g} planned step: round-off chose "
                            "the branch", stopped=False)
                    return
                break
            _back(sim, mark)
            length, crawl = length / 2, False


def bracket(points: list[PathPoint]) -> tuple[PathPoint, PathPoint] | None:
    """The two steps between which the lowest eigenvalue first goes from positive to
    negative; None if it never does. Its sign, not the inertia's count: the crossing is
    interpolated in it; the count decides only where ``follow`` kicks (``_wrinkles``)."""
    for a, b in zip(points, points[1:], strict=False):
        if a.eigenvalues[0] > 0 >= b.eigenvalues[0]:
            return a, b
    return None


def crossing(points: list[PathPoint]) -> float | None:
    """The nominal strain where the lowest eigenvalue first goes from positive to negative,
    linearly interpolated between the two steps around it (``bracket``); None if it never
    does. Linear in the load is right near the crossing, not from the rest state: a thin
    sheet's lowest eigenvalue first rises with tension, then falls (the bracket says how far
    apart the two steps are)."""
    ab = bracket(points)
    if ab is None:
        return None
    a, b = ab
    la, lb = a.eigenvalues[0], b.eigenvalues[0]
    return a.strain + (b.strain - a.strain) * la / (la - lb)

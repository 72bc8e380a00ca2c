"""Stepping a model through time: static load stepping or implicit Euler, with automatic
cut-back of a failing step, per-step records, and the result written as result.json/final.npz.

Data flows one way: Scene -> Model -> Simulation.step() -> StepRecord / Frame.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from sim.frames import fields, output, probes, results, series, summary
from sim.frames.display import DisplayMesh
from sim.frames.output import Frame
from sim.geometry.rigid import determinate_support
from sim.model.build import Model, build_model
from sim.model.curves import load_factor
from sim.scene.boundary import LoadSpec
from sim.scene.load import Scene
from sim.solve.newton import INVERTED_AT_START, NewtonResult, Timing, minimise
from sim.stepping import parameters
from sim.terms.tool_contact import ToolContact, quaternion_wxyz
from sim.text import figure


class SolverFailure(RuntimeError):
    """A step failed even after the allowed cut-backs; ``report`` holds the numbers."""

    def __init__(self, report: dict):
        self.report = report
        # the residual is the force the step left unbalanced (the energy's gradient, N)
        last = ", ".join(figure(r) for r in report["residuals"][-6:])
        super().__init__(f"step {report['step']} failed at t = {report['t']:.6g} after "
                         f"{report['cutbacks']} cut-backs: {report['reason']}"
                         + (f"; the last residuals {last} N" if last else "")
                         + (f"; {report['hint']}" if report.get("hint") else ""))


# what a step that ran out of cut-backs most often needs, said with its numbers (a review's
# "line search stalled (residual 2.476e+02)" on a sharp-edged punch said nothing to change)
CUTBACK_HINT = ("what usually helps: more steps (stepping.steps) or cut-backs "
                "(stepping.max_cutbacks); rounder tool edges (an edge sharper than the mesh "
                "can wrap); a finer mesh (mesh.edge_length) where the sheet bends")


@dataclass
class StepRecord:
    step: int
    time: float
    iterations: int
    residual: float
    energy: float
    cutbacks: int
    probes: dict[str, float]
    # per tool: force the sheet exerts on it (N), nodes in contact, deepest penetration (m), z
    tools: dict[str, dict] = field(default_factory=dict)
    # friction: how far from the state's own the lagged normal forces are (largest change,
    # relative to the largest force; Newton takes them at every iterate, sim.solve.newton)
    friction_change: float = 0.0
    # the sheet now: its least thickness (m) and largest thinning (a fraction) over the
    # vertices, which a page shows while the run goes (the summary comes at its end)
    sheet: dict[str, float] = field(default_factory=dict)


@dataclass
class Simulation:
    model: Model
    step_index: int = 0
    t: float = 0.0
    records: list[StepRecord] = field(default_factory=list)
    timing: Timing = field(default_factory=Timing)
    wall: float = 0.0
    failure: dict | None = None
    stopped: str | None = None  # why the run ended before its last step, when not a failure

    def end(self, reason: str, stopped: bool = True) -> None:
        """The run ends here, not by the solver: ``stopped`` by a user or the service, or
        failed for ``reason`` (the recording broke); result() then says why."""
        if stopped:
            self.stopped = reason
        elif self.failure is None:
            self.failure = {"step": self.step_index, "t": self.t, "cutbacks": 0,
                            "reason": reason, "iterations": 0, "residuals": []}

    @classmethod
    def from_scene(cls, scene: Scene) -> Simulation:
        return cls(build_model(scene))

    # live parameters (sim.stepping.parameters), applied from the next step on. tool_speed is
    # the rate of the stroke: a step covers that many of the planned steps' scene time (which
    # moves the tools, and the prescribed displacements and load ramp with them), so the
    # planned stroke is kept and done in fewer steps (or more); the run ends where the scene's
    # time does. Static stepping only: there scene time is the stroke, while a dynamic run's
    # time is seconds, whose step is dt.
    PARAMETERS = parameters.RANGES  # the run-wide ones; a run adds its tools' (ranges)

    def __post_init__(self) -> None:
        self.ranges = {**self.PARAMETERS, **parameters.per_tool(self.model.scene.tools)}
        self.parameters = {k: 1.0 for k in self.ranges}
        self.tools = [t for t in self.model.terms if isinstance(t, ToolContact)]
        self._mu0 = {t.tool: t.mu for t in self.tools}
        self.parameter_log: list[dict] = []
        self._last_increment: np.ndarray | None = None
        # the largest force level (N, 2-norm: applied forces, and support reactions where a
        # prescribed motion drives the run) met at a converged state; the floor of Newton's
        # reference in later steps (a slow sub-step's own forces can be tiny)
        self._force_level = 0.0
        self._sections = {sp.name: fields.section_points(self.model, sp)
                          for sp in self.model.scene.sections}
        self.sections: dict[str, list[dict]] = {name: [] for name in self._sections}
        self._last_dt = 1.0
        self.release_support: list[dict] = []  # added for springback (_release_supports)
        self.x = self.model.x0.copy()
        self.display = DisplayMesh.from_shell(self.model.shell)
        self.h0 = fields.thickness(self.model, self.x)
        self.loaded: np.ndarray | None = None  # the state at the end of the stroke (release)
        self.summary = summary.Summary(self.model)
        # the summary's quantities among what the run computes (the model knows no frames)
        self.model.built["outputs"]["summary"] = self.summary.names
        self.progress = 0.0  # planned steps of the stroke covered (tool_speed per step)
        self._stroked = 0  # steps of the stroke made
        self._record_sections()  # the rest state, when a section asks for step 0
        self.series: series.FrameSeries | None = None  # the frames saved (save_frames)
        self.field_ranges: dict[str, tuple[float, float]] = {}  # over its frames (frame())

    @property
    def stroke_steps(self) -> int:
        """Steps of the stroke: those done and those the rest of the planned stroke takes at
        the current tool_speed (the scene's stepping.steps as written)."""
        st = self.model.scene.stepping
        left = (st.steps - self.progress) / self.parameters["tool_speed"]
        return self._stroked + max(0, math.ceil(left - self.STEP_TOL))

    @property
    def n_steps(self) -> int:
        return self.stroke_steps + (1 if self.model.scene.stepping.release else 0)

    @property
    def done(self) -> bool:
        return self.step_index >= self.n_steps or self.failure is not None

    # a stroke within this many planned steps of its end is at its end (round-off of the
    # progress summed over steps)
    STEP_TOL = 1e-9

    def _dt(self) -> float:
        """The scene time of a planned step."""
        st = self.model.scene.stepping
        return st.dt if st.kind == "dynamic" else 1.0 / st.steps

    def _stride(self) -> tuple[float, bool]:
        """How many planned steps the next step covers (tool_speed of them) and whether it
        ends the stroke (the last is cut at the stroke's end)."""
        left = self.model.scene.stepping.steps - self.progress
        speed = self.parameters["tool_speed"]
        return (left, True) if left - speed <= self.STEP_TOL else (speed, False)

    def set_parameter(self, name: str, value: float) -> None:
        """Change a live parameter from the next step on; recorded with that step number."""
        value = parameters.check(name, value, self.ranges)
        if name == "tool_speed" and value != 1.0 and self.model.scene.stepping.kind != "static":
            raise ValueError("tool_speed: the rate of a static run's stroke; this scene steps "
                             "dynamically (its tools move at their velocity in m/s: change "
                             "that in the scene)")
        self.parameters[name] = value
        for t in self.tools:
            t.mu = self._mu0[t.tool] * self._friction_scale(t.tool)
            t.force_scale = self.parameters["holder_force_scale"]
        parameters.log_change(self.parameter_log,
                              {"step": self.step_index + 1, "name": name, "value": value})

    def _friction_scale(self, tool: str) -> float:
        """What a tool's friction coefficient is multiplied by: the run-wide friction_scale
        times the tool's own (a tool without friction has none: 1)."""
        return self.parameters["friction_scale"] * self.parameters.get(
            f"friction_scale.{tool}", 1.0)

    def scaled(self) -> dict[str, list[dict]]:
        """What each live parameter multiplies, as the scene gives it (SI), so a page can
        show the result beside the multiplier (friction 0.1 x 2 = 0.2): per tool its friction
        coefficient, its force (force control) and, if it moves, its planned travel per step
        (tool_speed); per load its magnitude. ``{name: [{"what", "value", "unit"}]}``, and
        ``"also"``: the other parameters the value is multiplied by too (a tool's friction by
        the run-wide and its own multiplier)."""
        sc = self.model.scene
        end = sc.stepping.steps * self._dt()
        return {
            "load_scale": [_load_magnitude(i, ld) for i, ld in enumerate(sc.loads)],
            "tool_speed": [{"what": name, "unit": "m/step", "value": travel}
                           for name, travel in self._travel_per_step(end) if travel > 0],
            **self._scaled_friction(),
            "holder_force_scale": [{"what": t.tool, "unit": "N", "value": t.force}
                                   for t in self.tools if t.vdof is not None],
        }

    def _scaled_friction(self) -> dict[str, list[dict]]:
        """Each tool's friction coefficient, under the run-wide friction_scale and under the
        tool's own (tools without friction have neither)."""
        tools = [(t.tool, f"friction_scale.{t.tool}", self._mu0[t.tool]) for t in self.tools]
        tools = [(tool, own, mu) for tool, own, mu in tools if own in self.ranges]
        return {"friction_scale": [{"what": tool, "unit": "1", "value": mu, "also": [own]}
                                   for tool, own, mu in tools],
                **{own: [{"what": tool, "unit": "1", "value": mu, "also": ["friction_scale"]}]
                   for tool, own, mu in tools}}

    def _travel_per_step(self, end: float) -> list[tuple[str, float]]:
        """Each tool's planned travel (m) per planned step: its offset over the run, divided
        by the steps."""
        steps = self.model.scene.stepping.steps
        return [(t.tool, float(np.linalg.norm(t.path(end)[:3] - t.path(0.0)[:3]
                                              + end * t.velocity)) / steps) for t in self.tools]

    def _attempt(self, t_new: float, dt: float) -> NewtonResult:
        m = self.model
        for term in m.terms:
            term.begin_step(t_new, dt, self.x)
        if m.external is not None:
            scale = self.parameters["load_scale"]
            m.external.factor = float(load_factor(m.scene.stepping, t_new)) * scale
        target = m.dirichlet_positions(t_new)  # each BC's own time curve
        # predictor: continue the last converged increment (quasi-static paths are smooth), so
        # a prescribed motion does not start as a jump concentrated on the boundary elements
        x0 = self.x.copy()
        if self._last_increment is not None:
            x0 += self._last_increment * (dt / self._last_dt)
            # a blank holder that came down onto its stop in the last increment stays on it:
            # continued past the stop, its spring (100x the contact stiffness of all its
            # nodes) started the step at 1e6 times the force level
            for t in self.tools:
                if t.vdof is not None and t.stop is not None:
                    x0[t.vdof, 2] = max(x0[t.vdof, 2], t.stop)
            # a node that settled into a tool's contact layer in the last increment is
            # carried as far again, out of it: with every node so, the sheet starts free, and
            # Newton's first correction is a rigid motion that round-off decides (back onto
            # the tools, or off them). From the last state, which the tools hold, instead
            if self._free(x0) and not self._free(self.x):
                x0 = self.x.copy()
        for t in self.tools:
            t.seat(x0)
        x0[m.fixed] = target[m.fixed]
        # a sub-step that barely moves (after cut-backs, or a slow tool) has its forces from
        # the state it starts in: the run's force level so far is the floor of its reference
        res = minimise(m.problem, x0, m.settings, self._force_level, m.driven)
        if (res.reason == INVERTED_AT_START
                and not np.array_equal(x0[~m.fixed], self.x[~m.fixed])):
            # the predictor inverted an element: from the last state instead (minimise
            # evaluates its start first, so this costs nothing where the prediction is fine)
            x0 = self.x.copy()
            x0[m.fixed] = target[m.fixed]
            res = minimise(m.problem, x0, m.settings, self._force_level, m.driven)
        return res

    # deepest penetration of a tool into the sheet a converged state may have, in sheet
    # thicknesses: the contact stiffness keeps it at 1 % under the largest forming pressure
    # (sim.model), so 10 % is a pressure ten times that, which no sheet metal carries: the
    # tool went through the sheet (an increment too large for the penalty to stop it). Nodes
    # held in every component do not count: a tool pressed into a clamp penetrates it by
    # however far it is driven, whatever the solver does.
    MAX_PENETRATION = 0.1

    def _penetration(self, x: np.ndarray) -> str:
        """The diagnostic when a tool penetrates the sheet beyond the bound, else ''."""
        bound = self.MAX_PENETRATION * float(np.mean(self.model.shell.thickness))
        for t in self._active_tools():
            gap = t.gap(x)
            movable = ~self.model.problem.fixed[t.nodes].all(1)
            d = float(max(0.0, -gap[movable].min())) if movable.any() else 0.0
            if d > bound:
                return (f"penetration beyond bound ({t.tool}: {d:.3e} m, bound {bound:.3e} m "
                        f"= {self.MAX_PENETRATION:g} thickness)")
        return ""

    def _active_tools(self) -> list:
        """The tools whose contact is a term of the problem (a released tool's is not)."""
        terms = set(map(id, self.model.problem.terms))
        return [t for t in self.tools if id(t) in terms]

    def _untouched(self, x: np.ndarray) -> bool:
        """Whether no inertia and no tool hold the sheet at ``x`` in a static problem: no node
        within a tool's contact layer (tools where the step puts them)."""
        m = self.model
        if m.inertia is not None and id(m.inertia) in set(map(id, m.problem.terms)):
            return False
        return not any(float(t.gap(x).min()) < t.delta for t in self._active_tools())

    def _loose(self) -> np.ndarray:
        """The directions (3,) in which no node of the sheet is held."""
        return ~self.model.problem.fixed[:self.model.shell.n_nodes].any(0)

    def _free(self, x: np.ndarray) -> bool:
        """Whether nothing holds the sheet at ``x`` in a static problem: no node held and
        ``_untouched``."""
        return bool(self._loose().all()) and self._untouched(x)

    def _drift(self, before: np.ndarray, x: np.ndarray, dt: float) -> str:
        """The diagnostic when a converged static sub-step leaves the sheet touching no tool,
        free in a direction no node is held in (a sheet held in x and y only is free to go
        up), without inertia, moved along such directions farther than any tool moved in it
        (plus a contact layer), else ''. Such a sheet is a free body: its equilibrium stands
        anywhere, so Newton may carry a sheet that lost its tools off to where nothing
        touches it, and the step would report zero forces as converged."""
        loose = self._loose()
        if not loose.any() or not self._untouched(x):
            return ""
        n = self.model.shell.n_nodes
        tools = self._active_tools()
        # along the directions no node is held in: a held one moves as it is told
        moved = float(np.linalg.norm((x[:n] - before[:n])[:, loose], axis=1).max())
        travel = max((t.travel(self.t, self.t + dt, before[:n]) for t in tools), default=0.0)
        # a free sheet that Newton leaves where it lies (a punch gone up, the blank on the
        # die outside its contact layer) moves by round-off; one carried along by a tool it
        # then left moves by the tool's travel at most, and by a contact layer at its edge
        if moved <= travel + max((t.delta for t in tools), default=0.0):
            return ""
        nearest = min((float(t.gap(x).min()) for t in tools), default=float("inf"))
        return (f"sheet lost every tool: moved {moved:.3e} m in a sub-step in which the tools "
                f"moved at most {travel:.3e} m, the nearest tool {nearest:.3e} m away, and "
                "nothing else holds it")

    # how often the tools' travel may halve a step: a tool moving 4,096 thicknesses in one
    # step is split into 4,096 sub-steps of a Newton solve each; a step needing more (a
    # thickness of micrometres under a millimetre stroke, a tool sped up a millionfold)
    # would run for hours or for ever, and fails at once instead, naming what to change
    MAX_TRAVEL_SPLITS = 12

    def _travel_limit(self, dt: float) -> float:
        """``dt`` halved until no tool moves more than a sheet thickness in it: penalty contact
        sees only where a sub-step ends, so a tool moving farther than that can start the
        iteration deep inside the sheet or pass through it unseen. A SolverFailure when
        ``MAX_TRAVEL_SPLITS`` halvings are not enough."""
        h = float(np.mean(self.model.shell.thickness))
        sheet = self.x[: self.model.shell.n_nodes]
        for _ in range(self.MAX_TRAVEL_SPLITS + 1):
            far = [(t.tool, d) for t in self.tools
                   if (d := t.travel(self.t, self.t + dt, sheet)) > h]
            if not far:
                return dt
            dt /= 2
        tool, d = max(far, key=lambda f: f[1])  # over 2 dt, the last increment tried
        self.failure = {
            "step": self.step_index + 1, "t": self.t, "cutbacks": 0, "iterations": 0,
            "residuals": [],
            "reason": (f"the tools move too far for the sheet's thickness: {tool} moves "
                       f"{d:.3e} m in {2 * dt:.3e} s, {d / h:.3g} times the thickness "
                       f"{h:.3e} m, after {self.MAX_TRAVEL_SPLITS} halvings of the step; "
                       f"penalty contact needs at most one thickness per sub-step: take "
                       f"more steps (stepping.steps), a slower tool or a thicker sheet")}
        raise SolverFailure(self.failure)

    def _lag_change(self, x: np.ndarray) -> float:
        """How far friction's lagged normal forces are from those of the converged state x
        (Newton takes them at every iterate, sim.solve.newton, so this is the last
        correction's effect, or how far off they stayed when it ran out of refreshes): the
        step record's ``friction_change``."""
        return self.model.problem.lag_change(x)

    def _commit(self, res: NewtonResult) -> None:
        """Accept the converged state: every term commits its state (plastic flow) there."""
        self.x = res.x
        for term in self.model.terms:
            term.commit(res.x)
        self._force_level = max(self._force_level, res.ref)

    def _release(self) -> StepRecord:
        """Springback: drop the loads and the released BCs, then solve static equilibrium
        (remaining BCs hold their current positions)."""
        m = self.model
        start = time.perf_counter()
        self.loaded = self.x.copy()
        self.formed = fields.mid_surface(m, self.loaded)  # the shape in the closed tools
        m.problem.set_fixed(self._release_supports())
        released = {t.name for t in m.scene.tools if t.release}
        # springback is a static equilibrium: a dynamic run's inertia goes too (kept, the
        # release would be one more time step of a sheet still moving)
        m.problem.terms = [t for t in m.terms
                           if not (isinstance(t, ToolContact) and t.tool in released)
                           and t is not m.inertia]
        for tool in self.tools:  # the tools that stay hold their last position
            tool.moving = False
        for term in m.terms:
            term.begin_step(self.t, self._dt(), self.x)
        if m.external is not None:
            m.external.factor = 0.0
        res = minimise(m.problem, self.x, m.settings, self._force_level, m.driven)
        self.timing.add(res.timing)
        if not res.converged:
            self.failure = {"step": self.step_index + 1, "t": self.t, "cutbacks": 0,
                            "reason": f"release: {res.reason}", "iterations": res.iterations,
                            "residuals": res.residuals}
            self.wall += time.perf_counter() - start
            raise SolverFailure(self.failure)
        change = self._lag_change(res.x)
        if deep := self._penetration(res.x):
            self.failure = {"step": self.step_index + 1, "t": self.t, "cutbacks": 0,
                            "reason": f"release: {deep}", "iterations": res.iterations,
                            "residuals": res.residuals}
            self.wall += time.perf_counter() - start
            raise SolverFailure(self.failure)
        self._commit(res)
        # what the added supports carry: nothing but the residual, when they are determinate
        g = m.problem.gradient(self.x)
        for s in self.release_support:
            s["force"] = -float(g[s["node"], "xyz".index(s["component"])])
        self.step_index += 1
        rec = StepRecord(self.step_index, self.t, res.iterations, res.residuals[-1],
                         res.energy, 0, probes.evaluate(m, self.x, formed=self.formed),
                         self._tool_reports(), change, self._sheet())
        self.records.append(rec)
        self._record_sections()
        self.wall += time.perf_counter() - start
        return rec

    def _release_supports(self) -> np.ndarray:
        """The DoFs held for springback: the scene's (its BCs less the released ones, plus its
        release-only ones) and one more per rigid-body mode those leave free, on the bottom skin
        (sim.geometry.rigid): the part is then held statically determinately, never by round-off.
        The added supports are kept in ``self.release_support`` for the result."""
        m = self.model
        held = (m.fixed & ~m.released) | m.release_support
        n = m.shell.n_nodes
        added = determinate_support(self.x[:n], held[:n], m.shell.layer_nodes(0))
        for node, c in added:
            held[node, c] = True
        self.release_support = [{"node": node, "component": "xyz"[c],
                                 "position": self.x[node].tolist()} for node, c in added]
        return held

    def step(self) -> StepRecord:
        """The next step (the release stage after the last). Whatever goes wrong in it is a
        SolverFailure naming it (``failure``), so a caller ends the run failed with the reason,
        never dies of it; so is a record holding a number that is not finite."""
        if self.done:
            raise RuntimeError("simulation already finished")
        try:
            if self.progress >= self.model.scene.stepping.steps:
                rec = self._release()
            else:
                rec = self._advance()
        except SolverFailure:
            raise
        except Exception as exc:
            self.failure = {"step": self.step_index + 1, "t": self.t, "cutbacks": 0,
                            "reason": f"{type(exc).__name__}: {exc}", "iterations": 0,
                            "residuals": []}
            raise SolverFailure(self.failure) from exc
        bad = results.finite(asdict(rec))[1]
        if bad:
            self.records.pop()
            self.failure = {"step": rec.step, "t": rec.time, "cutbacks": rec.cutbacks,
                            "reason": f"not finite: {', '.join(bad)}",
                            "iterations": rec.iterations, "residuals": []}
            raise SolverFailure(self.failure)
        self.summary.observe(self)
        self._save_frame(rec)
        return rec

    def save_frames(self, folder: Path, every: int) -> None:
        """Save the state into ``folder`` now, every ``every`` steps and at the end
        (sim.frames.series): the run's time series."""
        self.series = series.FrameSeries(folder, every, self)

    def _save_frame(self, rec: StepRecord) -> None:
        """A frame that cannot be saved fails the run, naming why (as a recording does)."""
        if self.series is None:
            return
        try:
            self.series.observe(self, last=self.done)
        except OSError as exc:
            self.end(f"saving the frame of step {rec.step} failed: {exc}", stopped=False)
            raise SolverFailure(self.failure) from exc

    def _advance(self) -> StepRecord:
        """Advance one nominal step, halving the increment on failure and doubling it back
        after a success; the step fails when the increment would fall below 1 / 2^max_cutbacks
        of the nominal one (a bound on the sub-steps, not on the failures over the step)."""
        start = time.perf_counter()
        stride, last = self._stride()
        nominal = stride * self._dt()
        # from the progress, not by adding increments: the stroke ends exactly at its end
        t_target = (self.model.scene.stepping.steps if last else self.progress + stride) \
            * self._dt()
        # cut-backs count from the increment the tools' travel allows (it may already be a
        # fraction of the nominal one), so a fast punch keeps all of its cut-backs
        dt_min = self._travel_limit(nominal) / 2 ** self.model.scene.stepping.max_cutbacks
        dt, cutbacks, iters = nominal, 0, 0
        while self.t < t_target - 1e-12 * t_target:
            dt = self._travel_limit(min(dt, t_target - self.t))
            res = self._attempt(self.t + dt, dt)
            self.timing.add(res.timing)
            iters += res.iterations
            if res.converged and (bad := self._penetration(res.x)
                                  or self._drift(self.x, res.x, dt)):
                res.converged, res.reason = False, bad
            if not res.converged:
                # a load below the force round-off floor stays below it in any increment
                hopeless = res.reason.startswith("load below force round-off floor")
                if hopeless or dt / 2 < dt_min * (1 - 1e-12):
                    self.failure = {"step": self.step_index + 1, "t": self.t + dt,
                                    "cutbacks": cutbacks, "reason": res.reason,
                                    "iterations": res.iterations, "residuals": res.residuals,
                                    "hint": None if hopeless else CUTBACK_HINT}
                    self.wall += time.perf_counter() - start
                    raise SolverFailure(self.failure)
                cutbacks += 1
                dt /= 2
                continue
            before = self.x
            self._commit(res)
            self._last_increment, self._last_dt = self.x - before, dt
            self.t += dt
            dt = min(2 * dt, nominal)  # grow back after a successful sub-step
        self.t = t_target
        self.progress = self.model.scene.stepping.steps if last else self.progress + stride
        self._stroked += 1
        self.step_index += 1
        rec = StepRecord(self.step_index, self.t, iters, res.residuals[-1], res.energy, cutbacks,
                         probes.evaluate(self.model, self.x), self._tool_reports(),
                         self._lag_change(self.x), self._sheet())
        self.records.append(rec)
        self._record_sections()
        self.wall += time.perf_counter() - start
        return rec

    def _record_sections(self) -> None:
        for sp in self.model.scene.sections:
            if not sp.steps or self.step_index in sp.steps:
                self.sections[sp.name].append(self._section_row(sp))

    def _section_row(self, sp: fields.Ray) -> dict:
        """The section ``sp`` now, with its ray's angle from the x axis (deg: where an
        anisotropic sheet's rolling direction is measured from)."""
        (dx, dy) = sp.direction
        return {"step": self.step_index, "time": self.t,
                **fields.section(self.model, self.x, self._sections[sp.name]),
                "angle_deg": float(np.degrees(np.arctan2(dy, dx)))}

    def recorded_sections(self) -> dict[str, list[dict]]:
        """The sections as recorded, each ending at the last step made: a section that lists
        its steps and missed it (a run stopped early, steps or the tool speed changed since the
        steps were listed) gets that step too, so that its plot ends where the part is."""
        out = {}
        for sp in self.model.scene.sections:
            rows = self.sections[sp.name]
            last = rows and rows[-1]["step"] == self.step_index
            # after a failure the state is partway into the next step: not the last one's
            out[sp.name] = rows if last or not self.records or self.failure is not None else [
                *rows, self._section_row(sp)]
        return out

    def run(self, progress: Callable[[Simulation, StepRecord], None] | None = None) -> bool:
        """Step to the end; returns converged. ``progress(sim, record)`` after each step."""
        while not self.done:
            try:
                rec = self.step()
            except SolverFailure:
                return False
            if progress:
                progress(self, rec)
        return True

    def _sheet(self) -> dict[str, float]:
        h = fields.thickness(self.model, self.x)
        return {"min_thickness": float(h.min()),
                "max_thinning": float(fields.thinning(h, self.h0, self.x).max())}

    def _tool_reports(self) -> dict[str, dict]:
        return {t.tool: t.report(self.x) for t in self._active_tools()}

    def tool_poses(self) -> dict[str, np.ndarray]:
        """Current translation (3,) of every tool."""
        return {t.tool: np.array(t.translation(self.x)) for t in self.tools}

    def tool_rotations(self) -> dict[str, np.ndarray]:
        """Current orientation of every tool as a unit quaternion (w, x, y, z)."""
        return {t.tool: quaternion_wxyz(t.R_now) for t in self.tools}

    def frame(self) -> Frame:
        """The viewer's frame of the current state (sim.frames.output.frame); its fields
        widen the run's ``field_ranges``."""
        f = output.frame(self)
        output.grow(self.field_ranges, f.fields)
        return f

    def result(self) -> dict:
        """What the run did, in numbers JSON carries (sim.frames.output.result)."""
        return output.result(self)

    def write(self, out: Path) -> dict:
        """result.json and final.npz in ``out`` (sim.frames.output.write); the result."""
        return output.write(self, out)


def _load_magnitude(i: int, ld: LoadSpec) -> dict:
    """A load's magnitude, ``{"what", "unit", "value"}``: its ``vector``'s length or its
    ``value``, in the unit its kind's schema gives that field (any load kind)."""
    name = "vector" if hasattr(ld, "vector") else "value"
    unit = type(ld).model_fields[name].json_schema_extra["unit"]
    v = getattr(ld, name)
    return {"what": f"{ld.kind} {i}", "unit": unit,
            "value": float(np.linalg.norm(v)) if name == "vector" else float(v)}

"""The run summary: the numbers an engineer reads of a forming run, in result.json's
``summary``. One registry knows the quantities: each declares what the scene must have for it
(a punch, a release stage, a flat blank's edge, a flange) and is computed only where it has
them, so a scene without a punch reports no punch force.

Each entry is ``{"name", "label", "value", "unit", "display": {"value", "unit"}, "at": {...}}``
(plus ``tool`` for a tool's quantity, ``note`` where the definition needs saying): ``value`` in
SI (N, m; ratios as fractions, unit "1"), ``display`` the same in the unit the page shows (kN,
mm, %). ``at`` says where or when: ``step`` and ``vertex`` (mid-surface vertex id) as plain
numbers, every dimensioned one (``stroke``, ``point``: mid-surface position) as a
``{"value", "unit", "display"}`` of its own.

The quantities, and the state they read (final: the last state of the run, after the release
when there is one; loaded: the end of the stroke):

- ``peak_punch_force``, ``final_punch_force`` (per punch; ``tool``): the force resisting the
  punch's motion, -(F . d), F the force the sheet exerts on the punch and d the unit direction
  of its largest excursion from where it started; the stroke (its travel along d) where it
  peaks; final: at the last step of the stroke. A punch that never moves: |F|.
- ``peak_lateral_punch_force``, ``lateral_punch_force_share`` (per moving punch; ``tool``):
  the side thrust on the punch (an off-centre load on the press), |F - (F . d) d|, its peak
  over the stroke with its step, stroke and angle about the punch axis; that peak as a share
  of the run's peak punch force, with (in ``at``) how many steps exceed ``LATERAL_SHARE`` of
  that peak, the first and the last; a side force within the step's residual (what the
  solve left unbalanced) reads 0, a symmetric punch's round-off not shown as thrust. Where a
  blank holder came down on its stop (distance blocks) during the stroke, also the peak
  before that step (``..._holding``) and from it on (``..._holder_on_stop``), each with its
  share in ``at``: a cup's flange is held, then free.
- ``min_thickness``, ``max_thinning``, ``max_thickening``: over the mid-surface vertices
  (thickness: the fibre length between the skins), final state; a sheet that nowhere thins
  (thickens) reads 0 with the nearest vertex's opposite change in the note. With a thinning
  limit in the material card's forming limits (``flc.max_thinning``), ``max_thinning`` says
  how many vertices reach it (``at.over_limit``) and is flagged ``failure`` when any does.
- ``forming_limit_margin`` (a plastic sheet with a forming limit curve in its material card):
  the smallest distance of an element's major strain below the curve at its minor strain,
  e1*(e2) - e1 in true strain (sim.frames.forming_limits), at the end of the stroke as the
  run's FLD; negative where an element is over the curve. ``at`` holds the element, its
  centre, its strains and how many elements each zone of the diagram holds; ``flag`` is the
  worst zone an element is in when that is marginal or failure (the card and the Runs table
  show it), None for a safe part.
- ``max_draw_in``, ``min_draw_in`` (a flat blank's outer edge): sim.frames.blank.draw_in,
  final state.
- ``part_height`` (punches moving along one direction d): the extent of the mid-surface along
  d, final state.
- ``flange_wrinkle_amplitude`` (a flange: the blank's whole outer edge rests on a die at the
  start): half the peak-to-valley of the edge's heights about its least-squares plane
  (sim.frames.blank.waviness), its largest over the steps of the stroke while the whole edge
  is on the die's face (``Summary.observe``).
- ``springback_max``, ``springback_mean`` (a release stage that ran): the distance of each
  mid-surface vertex of the released part from the loaded shape, after the best-fit rigid
  motion of released onto loaded (the release holds the part statically determinately,
  sim.geometry.rigid: its position is that of the supports chosen, its shape is not).
- ``tool_deviation_max``, ``tool_deviation_mean`` (a release stage that ran, tools in contact
  at the end of the stroke): how far the skin nodes that touched a tool (within its contact
  layer) at the end of the stroke moved away from (or into) it on release: the change of each
  one's distance from the tool between the loaded part and the released one, placed by the
  same best-fit motion, the tool where the stroke left it. A part that does not spring back
  reads 0, however deep the penalty contact let it into the contact layer.
- ``max_rim_height``, ``min_rim_height``, ``earing``, ``rim_harmonic_4``, ``rim_harmonic_6``
  (one punch direction, a flat blank's outer edge drawn through the die: every edge vertex
  moved along the punch's direction by more than two thicknesses): the edge's heights above
  the lowest point along the punch's direction, around the punch axis from the x axis
  (sim.frames.earing), final state; ``earing`` is
  (max - min) / mean and carries the whole ``profile`` (angle, height); the four-fold
  harmonic is a rolled sheet's ears, the six-fold a hexagonal mesh's pattern.
- ``volume_change``: V / V0 - 1 of the sheet's material, final state (sim.frames.fields.volume:
  an assumed-strain element's from its own strain, not its interpolated geometry's).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from sim.frames import blank, earing, forming_limits
from sim.frames.fields import element_strains, mid_surface, thickness, thinning, volume
from sim.frames.punch import punch_history
from sim.frames.units import measure
from sim.scene.shapes import tool_role
from sim.terms.tool_contact import ToolContact
from sim.text import mm, plan_extent
from sim.tools.evaluate import sdf_world_distance

if TYPE_CHECKING:
    from sim.frames.output import Run
    from sim.model.build import Model

# a flat blank: every rest mid-surface vertex within this many thicknesses of one plane
FLAT = 0.5
# an edge resting on a die: within this many thicknesses of the die's surface at the start
RESTS = 0.05
# punches moving along one direction: their directions within a degree of each other
PARALLEL = np.cos(np.radians(1.0))
# side thrust counted against the run's peak punch force: issue 17's bar for an axisymmetric
# cup, whose exact answer is no side thrust at all
LATERAL_SHARE = 0.02
# the thinning limit (of the rest thickness) a material card without one is judged by: 20 %, the
# acceptance limit press shops commonly apply to a drawn part's maximum thinning (beyond it a
# split is near); marginal from half of any limit, so a region halfway there shows early. A
# rule of thumb, not the material's (its forming limit curve is): the summary, the Runs table
# and the 3-D view's bands say the same, and the summary's note says which limit it was
THINNING_LIMIT = 0.20
MARGINAL_SHARE = 0.5
# a force-controlled tool is on its stop within this many sheet thicknesses of it: the stop's
# spring lets it in by F / k_stop, far less; a holder still pressing the flange is well above
ON_STOP = 1e-3


def entry(name: str, label: str, value: float, unit: str, at: dict | None = None,
          **extra: object) -> dict:
    return {"name": name, "label": label, **measure(value, unit), "at": at or {}, **extra}


def at_vertex(v: int, points: np.ndarray) -> dict:
    return {"vertex": int(v), "point": measure(points[v], "m")}


@dataclass
class View:
    """What a quantity reads: the run (``sim``), its final state ``x``, the state at the end
    of the stroke ``loaded`` (None before a release ran), the records of the stroke's steps,
    and the tracker (``summary``: the blank's edge, the tools' starts, the wrinkle history)."""

    sim: Run
    summary: Summary
    x: np.ndarray
    loaded: np.ndarray | None
    stroke: list

    @property
    def model(self) -> Model:
        return self.sim.model

    def mid(self, x: np.ndarray | None = None) -> np.ndarray:
        return mid_surface(self.model, self.x if x is None else x)


@dataclass(frozen=True)
class Quantity:
    value: Callable  # (View) -> list of entries
    # "tools", "punch", "edge", "flange", "release", "flc" (features)
    needs: tuple[str, ...] = ()


QUANTITIES: dict[str, Quantity] = {}


def quantity(name: str, needs: tuple[str, ...] = ()) -> Callable[[Callable], Callable]:
    """Register the decorated ``value(view) -> [entries]`` as ``name``."""
    def register(value: Callable) -> Callable:
        QUANTITIES[name] = Quantity(value, needs)
        return value
    return register


# ---- what the scene has ----------------------------------------------------------------------
def tools_of(model: Model, role: str) -> list[ToolContact]:
    roles = {spec.name: tool_role(spec) for spec in model.scene.tools}
    return [t for t in model.terms if isinstance(t, ToolContact) and roles[t.tool] == role]


def flat_edge(model: Model) -> blank.Edge | None:
    """The outer edge of a flat blank (sim.frames.blank), None for a curved one or no edge."""
    sh = model.shell
    V, F = sh.mesh.vertices, sh.mesh.faces
    if not blank.is_flat(V, F, FLAT * float(sh.thickness.min())):
        return None
    return blank.outer_edge(V, F)


def into_die(model: Model, edge: blank.Edge) -> np.ndarray | None:
    """The unit direction from the blank into the die its whole outer edge rests on at the
    start (every edge vertex has a skin within ``RESTS`` thicknesses of the die's surface): a
    flange. None when no die holds the whole edge."""
    sh, x0 = model.shell, model.x0
    top, bottom = (x0[sh.skin_nodes(s)][edge.vertices] for s in (True, False))
    for die in tools_of(model, "die"):
        d = sdf_world_distance(die.prog, die.R_now, die.translation(x0),
                               np.concatenate([top, bottom])).reshape(2, -1)
        if np.all(d.min(0) <= RESTS * sh.thickness[edge.vertices]):
            towards = np.where((d[1] <= d[0])[:, None], bottom - top, top - bottom).sum(0)
            return towards / np.linalg.norm(towards)
    return None


def features(model: Model) -> tuple[set[str], blank.Edge | None, np.ndarray | None]:
    """What the scene has that a quantity may need, the blank's outer edge and, for a flange,
    the direction into its die."""
    have = {"tools"} if any(isinstance(t, ToolContact) for t in model.terms) else set()
    if model.elasticity.plastic and model.scene.material.flc is not None:
        have.add("flc")
    if tools_of(model, "punch"):
        have.add("punch")
    if model.scene.stepping.release:
        have.add("release")
    edge = flat_edge(model)
    die = None
    if edge is not None:
        have.add("edge")
        die = into_die(model, edge) if "punch" in have else None
        if die is not None:
            have.add("flange")
    return have, edge, die


def applicable(have: set[str]) -> list[str]:
    """The quantities a scene with ``have`` reports."""
    return [name for name, q in QUANTITIES.items() if set(q.needs) <= have]


# ---- the tracker -----------------------------------------------------------------------------
@dataclass
class Summary:
    """Follows a run for its summary: what it needs of the rest state, and of each step of the
    stroke what the final state no longer shows (the flange's wrinkles)."""

    model: Model
    have: set[str] = field(init=False)
    edge: blank.Edge | None = field(init=False)
    into_die: np.ndarray | None = field(init=False)  # a flange's direction into its die
    volume0: float = field(init=False)
    starts: dict[str, np.ndarray] = field(init=False)
    # (step, peak-to-valley) of the edge while it is a flange: on the die's face
    wrinkles: list[tuple[int, float]] = field(default_factory=list)
    flange_left: int | None = None  # the step at which part of the edge left the die's face

    def __post_init__(self) -> None:
        m = self.model
        self.have, self.edge, self.into_die = features(m)
        self.volume0 = volume(m, m.x0)
        self.starts = {t.tool: np.array(t.translation(m.x0)) for t in m.terms
                       if isinstance(t, ToolContact)}

    @property
    def names(self) -> list[str]:
        return applicable(self.have)

    def punch_starts(self) -> dict[str, list[float]]:
        """Each punch's start translation (m): its stroke is its travel from there."""
        return {t.tool: self.starts[t.tool].tolist() for t in tools_of(self.model, "punch")}

    def observe(self, sim: Run) -> None:
        """After each step of the stroke, while the edge is a flange: its waviness. The edge
        has left the die's face (into its opening, around its shoulder) once a vertex has moved
        into the die by half a thickness: the die blocks that motion, wrinkles lift the flange
        off it, so only the shoulder lets the edge go that way; the edge's heights then follow
        the shoulder's shape, not wrinkles."""
        m, v = self.model, self.edge.vertices if self.edge is not None else None
        if "flange" not in self.have or self.flange_left is not None \
                or sim.step_index > sim.stroke_steps:
            return
        P = mid_surface(m, sim.x)[v]
        if np.any((P - m.shell.mesh.vertices[v]) @ self.into_die > 0.5 * m.shell.thickness[v]):
            self.flange_left = sim.step_index
            return
        self.wrinkles.append((sim.step_index, blank.waviness(P)))

    def result(self, sim: Run) -> list[dict]:
        steps = sim.stroke_steps
        released = self.model.scene.stepping.release and sim.step_index > steps
        view = View(sim, self, sim.x, sim.loaded if released else None,
                    [r for r in sim.records if r.step <= steps])
        return [e for name in self.names for e in QUANTITIES[name].value(view)]


# ---- the quantities --------------------------------------------------------------------------
def punches(view: View) -> dict[str, dict]:
    """:func:`punch_history` of every punch that was active in the stroke."""
    out = {}
    for t in tools_of(view.model, "punch"):
        rows = [(r.step, r.tools[t.tool]) for r in view.stroke if t.tool in r.tools]
        if rows:
            out[t.tool] = punch_history(rows, view.summary.starts[t.tool])
    return out


@quantity("punch_force", needs=("punch",))
def _punch_force(view: View) -> list[dict]:
    out = []
    for tool, h in punches(view).items():
        steps, force, stroke = h["steps"], h["force"], h["stroke"]
        missed = _missed(view, tool) if not np.any(np.asarray(force) > 0) else {}
        for name, label, k in (("peak_punch_force", "Peak punch force", int(np.argmax(force))),
                               ("final_punch_force", "Punch force at the end of the stroke",
                                len(force) - 1)):
            at = {"step": int(steps[k])}
            if stroke is not None:
                at["stroke"] = measure(stroke[k], "m")
            out.append(entry(name, label, force[k], "N", at, tool=tool, **missed))
    return out


def _missed(view: View, punch: str) -> dict:
    """The flag and note of a punch that never touched the sheet: a run that ends with no
    force at all is a set-up to look at (a drawn blank beside the punch, in its drawing's own
    coordinates), not a part."""
    start = view.summary.starts[punch]
    return {"flag": "no_contact",
            "note": f"the punch never touched the sheet: is the blank under it? The punch "
                    f"started at (x, y) = ({mm(start[0])}, {mm(start[1])}); the blank lies at "
                    f"{plan_extent(view.model.shell.mesh.vertices)}"}


def holder_on_stop(view: View) -> int | None:
    """The first step of the stroke at which a blank holder rests on its stop (its offset,
    the travel from its start along z, at the stop), None when none came down on one."""
    tol = ON_STOP * float(view.model.shell.thickness.min())
    steps = [r.step for t in tools_of(view.model, "blank_holder") if t.stop is not None
             for r in view.stroke if t.tool in r.tools
             and r.tools[t.tool]["z"] - view.summary.starts[t.tool][2] <= t.stop + tol]
    return min(steps, default=None)


@quantity("lateral_punch_force", needs=("punch",))
def _lateral_punch_force(view: View) -> list[dict]:
    out, rests = [], holder_on_stop(view)
    for tool, h in punches(view).items():
        peak = float(h["force"].max())
        if h["lateral"] is None or peak <= 0.0:  # no stroke, or a punch never pressed
            continue
        steps, side = h["steps"], np.linalg.norm(h["lateral"], axis=1)
        # a converged state balances its forces only to the residual Newton left: a side
        # force within it is not resolved (a symmetric punch's is round-off, 1e-14 of its
        # peak) and reads 0, not as a measurement
        left = np.array([r.residual for r in view.stroke if tool in r.tools])
        resolved = side > left
        shown = np.where(resolved, side, 0.0)
        k = int(np.argmax(shown if resolved.any() else side))
        note = ("the punch's force perpendicular to its stroke (side thrust), the angle about "
                "the punch axis from the x axis (y for a punch along x); share: of the run's "
                "peak punch force")
        if not resolved.any():
            note = (f"no side thrust resolved: at every step within the residual force the "
                    f"solve left (the largest, {side[k]:.3g} N at step {int(steps[k])}, "
                    f"against its residual {left[k]:.3g} N)")
        side = shown

        def at(k: int, h: dict = h, side: np.ndarray = side, peak: float = peak) -> dict:
            out = {"step": int(h["steps"][k]), "stroke": measure(h["stroke"][k], "m")}
            if side[k] > 0.0:  # a force that is not there points nowhere
                out["angle"] = measure(np.degrees(earing.angle_about(h["direction"],
                                                                     h["lateral"][k])), "deg")
            return out | {"share_of_peak": measure(side[k] / peak, "1")}

        over = steps[side > LATERAL_SHARE * peak]
        out += [entry("peak_lateral_punch_force", "Peak lateral punch force", side[k], "N",
                      at(k), tool=tool, note=note),
                entry("lateral_punch_force_share",
                      "Peak lateral punch force / peak punch force", side[k] / peak, "1",
                      {"step": int(steps[k]), "stroke": measure(h["stroke"][k], "m"),
                       f"steps_over_{100 * LATERAL_SHARE:g}_percent": len(over),
                       **({"first_step_over": int(over[0]), "last_step_over": int(over[-1])}
                          if len(over) else {})},
                      tool=tool, note=f"peak lateral punch force over the peak punch force of "
                                      f"the same run; the steps (of {len(steps)}) whose lateral "
                                      f"force is over {100 * LATERAL_SHARE:g} % of that peak")]
        split = steps >= rests if rests is not None else np.zeros(len(steps), bool)
        if split.any() and not split.all():
            for name, label, part in (
                    ("holding", "while the blank holder holds", ~split),
                    ("holder_on_stop", "with the blank holder on its stop", split)):
                j = int(np.flatnonzero(part)[np.argmax(side[part])])
                out.append(entry(f"peak_lateral_punch_force_{name}",
                                 f"Peak lateral punch force {label}", side[j], "N",
                                 at(j) | {"holder_on_stop_from_step": int(rests)}, tool=tool,
                                 note=f"{note}; the holder came down on its stop (distance "
                                      f"blocks) at step {rests}"))
    return out


@quantity("thickness")
def _thickness(view: View) -> list[dict]:
    h, h0, mid = thickness(view.model, view.x), view.sim.h0, view.mid()
    thin, i = thinning(h, h0, view.x), int(np.argmin(h))
    most = _most("max_thinning", "Maximum thinning", thin, mid, ("thinner", "thickening"))
    flc = view.model.scene.material.flc
    carded = flc is not None and flc.max_thinning is not None  # (flc: plastic materials only)
    limit = flc.max_thinning if carded else THINNING_LIMIT
    over = int(np.count_nonzero(thin >= limit))
    near = int(np.count_nonzero(thin >= MARGINAL_SHARE * limit))
    most["at"]["over_limit"] = over
    most["flag"] = "failure" if over else "marginal" if near else None
    whose = (f"the material card's limit {100 * limit:g} %" if carded else
             f"the rule-of-thumb limit {100 * limit:g} % (the material card sets none)")
    most["note"] = "; ".join(filter(None, (
        most.get("note"), f"{whose} (excessive thinning): {over} vertices at or over it, "
                          f"{near} over half of it, in the final state")))
    return [entry("min_thickness", "Minimum thickness", h[i], "m", at_vertex(i, mid)), most,
            _most("max_thickening", "Maximum thickening", 0.0 - thin, mid,
                  ("thicker", "thinning"))]


def _most(name: str, label: str, change: np.ndarray, mid: np.ndarray,
          words: tuple[str, str]) -> dict:
    """The largest thinning (or thickening) ``change`` over the vertices; 0 where no vertex
    thinned (thickened), with the nearest one's opposite change in the note: "-6.8e-5 %"
    reads as a measurement of thinning where the sheet only thickened."""
    j = int(np.argmax(change))
    if change[j] >= 0.0:
        return entry(name, label, change[j], "1", at_vertex(j, mid))
    return entry(name, label, 0.0, "1", at_vertex(j, mid),
                 note=f"no vertex {words[0]} than the blank; the least {words[1]} "
                      f"{-100.0 * change[j]:.3g} %, at the vertex given")


@quantity("forming_limit", needs=("flc",))
def _forming_limit(view: View) -> list[dict]:
    m = view.model
    flc = forming_limits.curve_of(m.scene.material, m.scene.shell)
    end = view.x if view.loaded is None else view.loaded
    major, minor = element_strains(m, end)
    zone = forming_limits.zones(major, minor, flc)
    margin = flc(minor) - major
    e = int(np.argmin(margin))
    counts = {name: int(np.count_nonzero(zone == code))
              for code, name in forming_limits.ZONES.items()}
    worst = forming_limits.ZONES[int(zone.max())]
    centre = view.mid(end)[m.shell.mesh.faces[e]].mean(0)
    return [entry("forming_limit_margin", "Forming limit margin", margin[e], "1",
                  {"step": min(view.sim.step_index, view.sim.stroke_steps), "element": e,
                   "point": measure(centre, "m"), "major": measure(major[e], "1"),
                   "minor": measure(minor[e], "1"), "zone_counts": counts},
                  flag=worst if worst in ("marginal", "failure") else None,
                  note=f"the least distance of an element's major strain below the forming "
                       f"limit curve (true strain), at the end of the stroke (the last step "
                       f"of a run that ended before it) as the FLD; under "
                       f"{100 * flc.margin:g} %: marginal, at or under 0: on or over the "
                       f"curve (failure)")]


@quantity("draw_in", needs=("punch", "edge"))
def _draw_in(view: View) -> list[dict]:
    edge = view.summary.edge
    rest = view.model.shell.mesh.vertices
    d = blank.draw_in(rest, view.mid(), edge)
    note = "in-plane displacement of the blank's outer edge towards the inside"
    return [entry(name, label, d[k], "m", {"vertex": int(edge.vertices[k]),
                                            "rest_point": measure(rest[edge.vertices[k]], "m")},
                  note=note)
            for name, label, k in (("max_draw_in", "Largest draw-in", int(np.argmax(d))),
                                   ("min_draw_in", "Smallest draw-in", int(np.argmin(d))))]


@quantity("part_height", needs=("punch",))
def _part_height(view: View) -> list[dict]:
    dirs = [h["direction"] for h in punches(view).values() if h["direction"] is not None]
    if not dirs or any(abs(d @ dirs[0]) < PARALLEL for d in dirs):
        return []
    z = view.mid() @ dirs[0]
    return [entry("part_height", "Part height", z.max() - z.min(), "m",
                  {"direction": [float(c) for c in dirs[0]]},
                  note="extent of the mid-surface along the punch's direction")]


@quantity("flange_wrinkle_amplitude", needs=("flange",))
def _wrinkles(view: View) -> list[dict]:
    if not view.summary.wrinkles:
        return []
    step, ptv = max(view.summary.wrinkles, key=lambda w: w[1])
    return [entry("flange_wrinkle_amplitude", "Flange wrinkle amplitude", ptv / 2, "m",
                  {"step": step, "peak_to_valley": measure(ptv, "m"),
                   "edge_left_die_face": view.summary.flange_left},
                  note="half the peak-to-valley of the blank edge's heights about its "
                       "best-fit plane, the largest over the stroke while the edge is on the "
                       "die's face")]


def aligned(view: View) -> tuple[np.ndarray, np.ndarray]:
    """The rotation and translation that best fit the released mid-surface onto the loaded."""
    return blank.best_fit(view.mid(), view.mid(view.loaded))


@quantity("springback", needs=("release",))
def _springback(view: View) -> list[dict]:
    if view.loaded is None:
        return []
    R, c = aligned(view)
    Q = view.mid(view.loaded)
    dev = np.linalg.norm(view.mid() @ R.T + c - Q, axis=1)
    k = int(np.argmax(dev))
    angle = np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0)))
    note = ("released part against its loaded shape after the best-fit rigid motion (the "
            "release holds the part only up to a rigid motion)")
    fit = {"rigid_rotation": measure(angle, "deg"), "rigid_translation": measure(c, "m")}
    return [entry("springback_max", "Springback, largest deviation", dev[k], "m",
                  at_vertex(k, Q) | fit, note=note),
            entry("springback_mean", "Springback, mean deviation", dev.mean(), "m", note=note)]


def tool_deviations(view: View, R: np.ndarray, c: np.ndarray) -> list[tuple[str, int, float]]:
    """(tool, node, change) of every skin node in a tool's contact layer at the end of the
    stroke: how much its distance from that tool changed from the loaded part to the
    released one moved by (R, c). The change, not the distance: a loaded node sits inside the
    contact layer (penalty contact needs a penetration to push), which is no deviation."""
    out = []
    for t in (t for t in view.model.terms if isinstance(t, ToolContact)):
        gap = t.gap(view.loaded)
        inside = gap < t.delta
        if not inside.any():
            continue
        X = view.x[t.nodes[inside]] @ R.T + c
        d = sdf_world_distance(t.prog, t.R_now, t.translation(view.loaded), X)
        out += [(t.tool, int(n), abs(float(v - g)))
                for n, v, g in zip(t.nodes[inside], d, gap[inside], strict=True)]
    return out


@quantity("tool_deviation", needs=("release", "tools"))
def _tool_deviation(view: View) -> list[dict]:
    if view.loaded is None:
        return []
    rows = tool_deviations(view, *aligned(view))
    if not rows:
        return []
    d = np.array([r[2] for r in rows])
    tool, node, dist = rows[int(np.argmax(d))]
    note = ("change of the distance from the tools it touched at the end of the stroke of "
            "the part's skin, released (after the best-fit rigid motion onto the loaded "
            "shape) against loaded")
    return [entry("tool_deviation_max", "Deviation from the tool surface, largest", dist, "m",
                  {"tool": tool, "node": node}, note=note),
            entry("tool_deviation_mean", "Deviation from the tool surface, mean", d.mean(), "m",
                  note=note)]


@quantity("rim_height", needs=("punch", "edge"))
def _rim_height(view: View) -> list[dict]:
    """A drawn cup's rim: its heights around the punch axis (the ``profile``), the earing and
    the four-fold (ears) and six-fold (a hexagonal mesh's pattern) harmonics. Only where the
    edge is a rim, up the wall: on average above half the part's height."""
    hist = punches(view)
    dirs = [(t, h["direction"]) for t, h in hist.items() if h["direction"] is not None]
    if len(dirs) != 1:
        return []
    tool, d = dirs[0]
    mid, rest, edge = view.mid(), view.model.shell.mesh.vertices, view.summary.edge.vertices
    # a rim once the whole edge has left the blank's plane with the punch (drawn through the
    # die), not a flange still held, whose heights show no ears (its draw-in does)
    if np.min((mid[edge] - rest[edge]) @ d) <= 2 * float(view.model.shell.thickness.max()):
        return []
    r = earing.rim(rest, mid, edge, d, view.summary.starts[tool])
    i, j = int(np.argmax(r.height)), int(np.argmin(r.height))
    deg = np.degrees(r.angle)
    profile = {"angle": measure(deg, "deg"), "height": measure(r.height, "m")}
    harmonics = {k: r.harmonic(k) for k in (4, 6)}  # k -> (amplitude, first crest)
    lattice = (_round_draw_earing(view, tool, d, r)
               or _mesh_earing(harmonics[4][0], harmonics[6][0], r.height[i] - r.height[j]))
    out = [entry("max_rim_height", "Rim height, largest", r.height[i], "m",
                 {"angle": measure(deg[i], "deg"), **at_vertex(r.vertices[i], mid)}),
           entry("min_rim_height", "Rim height, smallest", r.height[j], "m",
                 {"angle": measure(deg[j], "deg"), **at_vertex(r.vertices[j], mid)}),
           entry("earing", "Earing", r.earing, "1", profile=profile,
                 note="(largest - smallest) / mean rim height; angles about the punch axis "
                      "from the x axis" + lattice,
                 # shown on the card, not only in its note: an isotropic cup's earing on a
                 # lattice is its mesh's six waves
                 flag="mesh" if lattice else None)]
    for k, name in ((4, "four-fold (ears)"), (6, "six-fold (mesh)")):
        amp, crest = harmonics[k]
        out.append(entry(f"rim_harmonic_{k}", f"Rim height, {name} harmonic", amp, "m",
                         {"first_crest": measure(np.degrees(crest), "deg")},
                         note=f"amplitude of the {k}-fold term of the rim height's "
                              "least-squares Fourier series"))
    return out


# what the earing's note says of a draw that has nothing to make ears but the mesh
ROUND_NOTE = ("; all the mesh's: a sheet isotropic in its plane, drawn from a round blank by "
              "tools round about the punch's axis, has no ears (a converged mesh shows none); "
              "a finer mesh, or an outline blank with mesh.mesher = \"meshadapt\", shows less")
# a blank's edge within this share of its mean radius of one radius about the punch's axis is
# round (a polygon of 360 chords is within 4e-5, a square's corners 41 % out)
ROUND_BLANK = 0.01
# a tool whose distance around each ring about the punch's axis spreads by less than this share
# of the sheet's thickness is round about it (an analytic punch, die or holder: round-off; a
# tessellated one: the sag left of its facets, micrometres; a square punch: millimetres)
ROUND_TOOL = 0.01


def _round_draw_earing(view: View, punch: str, d: np.ndarray, rim: earing.Rim) -> str:
    """What the earing note says of a draw from a round blank by round tools (_round_draw):
    on a sheet isotropic in its plane (von Mises, or Hill48 with r0 = r45 = r90) every ear is
    the mesh's (ROUND_NOTE). An orthotropic sheet's rim is mirror-symmetric about its
    rolling and transverse directions, so its four-fold term is a cos(4 phi), phi from the
    rolling direction, its crests on those directions or at 45 degrees to them; the term's
    b sin(4 phi) is the mesh's, and where it outgrows a the ears are mostly the mesh's (a crest
    more than 11.25 degrees off). '' where neither is said."""
    if not _round_draw(view, punch, d):
        return ""
    hill = view.model.scene.material.hill48
    if hill is None or hill.planar_isotropic():
        return ROUND_NOTE
    rolling = float(earing.angle_about(d, np.asarray(hill.rolling_vector(), float)[None])[0])
    a, b = rim.terms(4, rolling)
    if abs(b) <= abs(a):
        return ""
    crest = abs(np.degrees(np.arctan2(b, a) / 4))  # 0: on the rolling direction, 45: between
    return (f"; mostly the mesh's: the four ears' crest lies {min(crest, 45 - crest):.0f} "
            f"degrees off the sheet's axes (the rolling direction, "
            f"{np.degrees(rolling) % 360:.0f} degrees, and 45 degrees from it), where a rolled "
            "sheet drawn from a round blank by round tools has its ears; the part of the "
            f"four-fold off them ({mm(abs(b))}) outgrows the part on them ({mm(abs(a))}). A "
            "finer mesh, or an outline blank with mesh.mesher = \"meshadapt\", shows the "
            "sheet's")


def _round_draw(view: View, punch: str, d: np.ndarray) -> bool:
    """Whether the draw is the same all round the punch's axis but for the sheet: its blank's
    edge round about the axis (through the punch's start along ``d``), and every tool the
    same all round it (its distance sampled on rings of radii and heights about it, where it
    is at the end)."""
    m = view.model
    axis = view.summary.starts[punch]

    def about(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # radius, height
        rel = points - axis
        along = rel @ d
        return np.linalg.norm(rel - np.outer(along, d), axis=1), along

    radius = about(m.shell.mesh.vertices[view.summary.edge.vertices])[0]
    if np.ptp(radius) > ROUND_BLANK * radius.mean():
        return False
    e1 = np.cross(d, [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(d, e1)
    angle = np.linspace(0.0, 2.0 * np.pi, 36, endpoint=False)
    ring = np.outer(np.cos(angle), e1) + np.outer(np.sin(angle), e2)  # (36, 3)
    scale = radius.mean()
    bound = ROUND_TOOL * float(m.shell.thickness.max())
    for t in (t for t in m.terms if isinstance(t, ToolContact)):
        where = t.translation(view.x)
        centre = axis + about(where[None])[1][0] * d
        for r in scale * np.array([0.25, 0.5, 0.75, 1.0, 1.25]):
            for h in scale * np.array([-0.5, -0.25, 0.0, 0.25, 0.5]):
                dist = sdf_world_distance(t.prog, t.R_now, where, centre + h * d + r * ring)
                if np.ptp(dist) > bound:
                    return False
    return True


def _mesh_earing(ears: float, mesh: float, spread: float) -> str:
    """What the earing note adds when the rim's six-fold wave, which a blank meshed in one
    60-degree lattice gives linear triangles, outgrows the rolled sheet's four ears and makes
    at least half the rim's spread (its peak to valley, twice its amplitude): that this
    earing is the mesh's (docs/elements-ans.md, "The cup's lateral force"). On a blank without
    a lattice both terms are small beside the spread, and neither says whose it is."""
    if mesh <= ears or 2.0 * mesh < 0.5 * spread:
        return ""
    return (f"; mostly the mesh's: its six-fold wave ({mm(mesh)}) is larger than the "
            f"four ears ({mm(ears)}), the pattern of a blank meshed in one lattice; an "
            "outline blank with mesh.mesher = \"meshadapt\", or a finer mesh, shows the sheet's")


@quantity("volume_change")
def _volume_change(view: View) -> list[dict]:
    return [entry("volume_change", "Volume change",
                  volume(view.model, view.x) / view.summary.volume0 - 1, "1")]


# ---- as text ---------------------------------------------------------------------------------
def _shown(m: dict) -> str:
    v, unit = m["display"]["value"], m["display"]["unit"]
    text = f"({', '.join(f'{c:.4g}' for c in v)})" if isinstance(v, list) else f"{v:.4g}"
    return f"{text} {unit}"


def _where(at: dict) -> str:
    parts = []
    for key, v in at.items():
        if isinstance(v, dict) and "display" in v:
            parts.append(f"{key.replace('_', ' ')} {_shown(v)}")
        elif v is not None and key != "direction":
            parts.append(f"{key.replace('_', ' ')} {v}")
    return ", ".join(parts)


def rows(entries: list[dict]) -> list[tuple[str, str, str]]:
    """(quantity, value with its unit, where) of each entry, as shown to an engineer."""
    return [(f"{e['label']} ({e['tool']})" if "tool" in e else e["label"], _shown(e),
             _where(e["at"])) for e in entries]


def table(entries: list[dict]) -> str:
    """The summary as a markdown table (the recording's ``summary`` document)."""
    lines = ["| quantity | value | where |", "|---|---|---|"]
    return "\n".join(lines + [f"| {q} | {v} | {w} |" for q, v, w in rows(entries)])

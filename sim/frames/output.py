"""What a run gives out of a Simulation (sim.stepping.simulation): the viewer's frame of its
state, its result (result.json) and the final state (final.npz)."""

from __future__ import annotations

import functools
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from sim.frames import fields, forming_limits, results, series
from sim.frames.display import DisplayMesh
from sim.model.build import Model, frame_fields
from sim.solve.newton import Timing


class RunSummary(Protocol):
    def result(self, sim: Run) -> list[dict]: ...

    def punch_starts(self) -> dict[str, list[float]]: ...


class Run(Protocol):
    """What this module reads of a run: sim.stepping.simulation.Simulation, which imports it."""

    model: Model
    x: np.ndarray
    series: series.FrameSeries | None  # the frames it saves, if it does
    h0: np.ndarray  # rest thickness per mid-surface vertex (n_v,)
    t: float
    step_index: int
    records: list  # its StepRecords (dataclasses)
    display: DisplayMesh
    timing: Timing
    wall: float
    parameter_log: list[dict]
    failure: dict | None
    stopped: str | None
    summary: RunSummary  # sim.frames.summary.Summary
    loaded: np.ndarray | None  # the state at the end of the stroke, before any release
    release_support: list[dict]
    sections: dict[str, list[dict]]
    field_ranges: dict[str, tuple[float, float]]  # over the frames made of it (frame())

    @property
    def n_steps(self) -> int: ...

    @property
    def stroke_steps(self) -> int: ...  # the steps before the release (tool_speed sets them)

    def result(self) -> dict: ...


@dataclass
class Frame:
    """What a viewer needs of one step. positions ``(n_display, 3)`` float32; fields per display
    vertex (``thickness_mm``, ``thinning_pct``)."""

    step: int
    time: float
    positions: np.ndarray
    fields: dict[str, np.ndarray]
    probes: dict[str, float]
    iterations: int
    residual: float


def grow(seen: dict[str, tuple[float, float]], fields: dict[str, np.ndarray]) -> None:
    """Widen each field's ``seen`` min..max to hold the finite values of ``fields`` too (a
    frame that is not finite fails its run, sim.stepping and server.worker: its NaN must not
    take the range, which run.json and the colour scale carry, with it)."""
    for key, v in fields.items():
        v = np.asarray(v)
        v = v[np.isfinite(v)]
        if not v.size:
            continue
        lo, hi = float(np.min(v)), float(np.max(v))
        if key in seen:
            lo, hi = min(lo, seen[key][0]), max(hi, seen[key][1])
        seen[key] = (lo, hi)


def frame(sim: Run) -> Frame:
    """The viewer's frame: positions and the fields ``model.frame_fields`` names (the one
    list of them: the recording's channels and ``built`` read it too)."""
    m, x = sim.model, sim.x
    rec = sim.records[-1] if sim.records else None
    h = fields.thickness(m, x)
    limits = functools.cache(lambda: fields.limit_fields(m, x))  # three fields, one computation
    field_of = {"thickness_mm": lambda: 1e3 * h,
                "thinning_pct": lambda: 100 * fields.thinning(h, sim.h0, x),
                "von_mises_MPa": lambda: 1e-6 * fields.vertex_average(
                    m, m.elasticity.von_mises(x)),
                # the strains in %, as the FLD, the probes and the summary give them
                "eq_plastic_strain_pct": lambda: 100 * fields.vertex_average(m, m.elasticity.ep),
                "major_strain_pct": lambda: 100 * limits()["major_strain"],
                "minor_strain_pct": lambda: 100 * limits()["minor_strain"],
                "fld_zone": lambda: limits()["fld_zone"]}
    values = {name: sim.display.per_vertex(field_of[name]()) for name in frame_fields(m)}
    return Frame(sim.step_index, sim.t, sim.display.positions(sim.x), values,
                 rec.probes if rec else {}, rec.iterations if rec else 0,
                 rec.residual if rec else 0.0)


def result(sim: Run) -> dict:
    """What the run did, in numbers JSON carries: a value that is not finite is written
    as null, listed in ``non_finite``, and the run did not converge."""
    out, bad = results.finite(_result(sim))
    if bad:
        out["non_finite"] = bad
        out["converged"] = False
        out["failure"] = out["failure"] or {
            "step": sim.step_index, "t": sim.t, "cutbacks": 0, "iterations": 0,
            "reason": f"not finite: {', '.join(bad[:5])}", "residuals": []}
    return out


def _result(sim: Run) -> dict:
    m = sim.model
    t = sim.timing
    n_it = max(t.iterations, 1)
    return {
        "scene": m.scene.name,
        "element": m.shell.element.name,
        # static: a step's time is the scene's pseudo-time, 0 to 1 over the run; dynamic: seconds
        "stepping": m.scene.stepping.kind,
        "quadrature": [len(np.unique(m.elasticity.rule.points[:, :2], axis=0)),
                       len(np.unique(m.elasticity.rule.points[:, 2]))],
        "counts": {"vertices": m.shell.n_vertices, "nodes": m.shell.n_nodes,
                   "elements": len(m.shell.conn), "dofs": 3 * len(m.x0),
                   "free_dofs": int((~m.fixed).sum())},
        "built": m.built,
        "parameters": sim.parameter_log,
        "converged": sim.failure is None and sim.step_index == sim.n_steps,
        "failure": sim.failure,
        # why a run that neither finished nor failed ended early (a user's stop, the service
        # shutting down); None otherwise
        "stopped": sim.stopped,
        # the DoFs springback added to hold the rigid-body modes the scene left free: node,
        # component, position (m) where the release started, force (N) once released
        "release_support": sim.release_support,
        "steps": [asdict(r) for r in sim.records],
        # what the step records' numbers need to be read: each punch's start translation (m;
        # its stroke is its travel from there, sim.frames.punch) and each probe's kind (its
        # unit, sim.frames.probes), as the server's run.json has them
        "punches": sim.summary.punch_starts(),
        "probe_kinds": {p.name: p.kind for p in m.scene.probes},
        "sections": sim.recorded_sections(),
        # each frame field's min and max over every frame made of the run (a viewer's frame of
        # each step in the service), so that a view of it later, from the frames kept, colours
        # on the scale it was watched on; {} when none was made (a run without a viewer)
        "field_ranges": {k: list(v) for k, v in sim.field_ranges.items()},
        "fields": fields.field_summary(fields.output_fields(m, sim.x, sim.h0)),
        "summary": sim.summary.result(sim),
        "forming_limits": forming_limit_diagram(sim),
        "timing": {"total": sim.wall, "assembly": t.assembly,
                   "factorisation": t.factorisation, "solve": t.solve,
                   "line_search": t.line_search, "newton_iterations": t.iterations,
                   "per_iteration": (t.assembly + t.factorisation + t.solve
                                     + t.line_search) / n_it},
    }


def forming_limit_diagram(sim: Run) -> dict | None:
    """The FLD of a plastic scene (None for an elastic one): each element's minor and major
    true strain of the mid-surface (sim.frames.forming_limits) at the end of the stroke (before
    any release), and with a forming limit curve the curve over the points' range, the zone
    thresholds, each element's zone code and how many elements each zone holds."""
    m = sim.model
    if not m.elasticity.plastic:
        return None
    x = sim.loaded if sim.loaded is not None else sim.x
    step = min(sim.step_index, sim.stroke_steps)
    major, minor = fields.element_strains(m, x)
    out = {"strain": "true (log) in-plane principal strains of the mid-surface, per element",
           "step": step, "minor": np.round(minor, 6).tolist(),
           "major": np.round(major, 6).tolist(), "curve": None}
    flc = forming_limits.curve_of(m.scene.material, m.scene.shell)
    if flc is None:
        return out
    zone = forming_limits.zones(major, minor, flc)
    lo, hi = min(-0.3, 1.1 * float(minor.min())), max(0.3, 1.1 * float(minor.max()))
    return out | {
        "curve": {"kind": flc.kind, **flc.sample(lo, hi),
                  "flc0": float(flc(0.0))},
        "warnings": list(flc.warnings),
        "margin": flc.margin, "insufficient_stretch": flc.insufficient_stretch,
        "zone": zone.tolist(), "zones": forming_limits.ZONES,
        "zone_counts": {name: int((zone == code).sum())
                        for code, name in forming_limits.ZONES.items()}}


def write(sim: Run, out: Path) -> dict:
    """result.json and final.npz, each written to a temporary name first so an interrupted
    run never leaves a half-written file, and the last frame of the run's series (when it saves
    one) unless saved already. Returns the result written. final.npz: the rest and deformed
    positions of every node, the faces, the element connectivity, each mid-surface vertex's
    top and bottom skin node (``skins (2, n_v)``), the rest thickness and the result fields;
    what a later stage needs to go on from the state (``q3t splitring``): the validated scene
    as JSON (``scene``, overrides applied) and, for a plastic material, the committed plastic
    state per element and quadrature point (``fp_inv (n_elem, n_qp, 3, 3)``, ``ep (n_elem,
    n_qp)``)."""
    out.mkdir(parents=True, exist_ok=True)
    m = sim.model
    sh, el = m.shell, m.elasticity
    plastic = {"fp_inv": el.fp_inv, "ep": el.ep} if el.plastic else {}
    series.save_npz(out / "final.npz", rest=sh.rest, deformed=sim.x[: sh.n_nodes],
                    faces=sh.mesh.faces, conn=sh.conn, skins=series.skins(m),
                    rest_thickness=sim.h0, scene=np.array(m.scene.model_dump_json()),
                    **plastic, **fields.output_fields(m, sim.x, sim.h0))
    res = sim.result()
    results.write(out / "result.json", res)
    if sim.series is not None:
        sim.series.observe(sim, last=True)
    return res

"""The plan of a refinement study (``q3t study``, a study from the page): which elements, at
which mesh levels, against which reference, and each case's size before anything is built.
The command line runs it (sim.apps.study); the server plans it too, so it is here, apart from
the command line."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path


def element_overrides(spec: str) -> dict:
    """The overrides of an element as a study names it: ``NAME``, or ``NAME:NxM`` for that
    element with the quadrature rule of N in-plane by M through-thickness points
    (``shell.quadrature``; the scene's ``thickness_points`` would replace M, so it is unset).
    ValueError naming the spec and what is wrong with it."""
    from sim.elements import ELEMENTS
    from sim.geometry.quadrature import prism_rule

    name, colon, rule = spec.partition(":")
    if name not in ELEMENTS:
        raise ValueError(f"unknown element {name!r} in {spec!r}; known: {sorted(ELEMENTS)}")
    if not colon:
        return {"shell.element": name}
    n, x, m = rule.partition("x")
    if not (x and n.isdigit() and m.isdigit()):
        raise ValueError(f"element {spec!r}: after ':' comes the rule as N x M points "
                         "(in-plane x through the thickness), e.g. q3t:3x3")
    try:
        prism_rule(int(n), int(m))
    except ValueError as exc:
        raise ValueError(f"element {spec!r}: {exc}") from None
    return {"shell.element": name, "shell.quadrature": [int(n), int(m)],
            "shell.thickness_points": None}


@dataclass(frozen=True)
class Plan:
    scene: str
    probe: str  # what is measured, as the report names it
    measure: dict  # probe, measure, over, section, field, step, norm (sim.scene.StudySpec)
    elements: list[str]
    levels: list[float]  # mesh edge lengths (m), coarse to fine
    reference: tuple[str, float] | None  # (element, edge length) of a numerical reference
    analytic: dict | None = None  # {"name", "value", "about"} (sim.analytic)
    overrides: dict = field(default_factory=dict)  # applied to every case (--set)
    notes: list[str] = field(default_factory=list)  # which defaults were taken and why


def _label(m: dict) -> str:
    if m["measure"] == "final":
        return m["probe"]
    if m["measure"] == "curve":
        return f"{m['probe']} over {m['over']} ({m['norm']})"
    return f"{m['section']}.{m['field']} profile ({m['norm']})"


def make_plan(scene_path: str, elements: list[str] | None = None,
              levels: list[float] | None = None,
              reference: tuple[str, float] | None = None, overrides: dict | None = None,
              study: dict | None = None) -> Plan:
    """The scene's ``[study]`` table (validated with the scene, after ``overrides`` and the
    ``study`` keys given on the command line); without one, its first probe at 4, 2 and 1 times
    its own edge length."""
    from sim.elements import ELEMENTS
    from sim.scene.load import load_scene

    overrides = dict(overrides or {})
    sc = load_scene(scene_path, {**overrides, **{f"study.{k}": v for k, v in
                                                 (study or {}).items()}})
    st, notes = sc.study, []
    if hasattr(sc.mesh, "cells"):
        raise ValueError(f"{sc.name}: mesh kind {sc.mesh.kind!r} is refined by cells: "
                         "the shell obstacle course runs with q3t study --course")
    if getattr(sc.mesh, "edge_length", None) is None:
        raise ValueError(f"{sc.name}: mesh kind {sc.mesh.kind!r} has no edge_length to refine")
    if st is None:
        notes.append("scene has no [study] table: its first probe"
                     + ("" if levels else ", edge lengths 4x, 2x, 1x its own"))
        if not sc.probes:
            raise ValueError(f"{sc.name}: no probe to study")
    elements = elements or (st.elements if st else ["linear", "q3t", "quadratic"])
    for spec in elements:
        element_overrides(spec)  # ValueError naming a bad one
    e0 = sc.mesh.edge_length
    if not levels and not (st and st.edge_lengths):
        if st is not None:
            notes.append("no study.edge_lengths: 4x, 2x, 1x the mesh's own")
        levels = [4 * e0, 2 * e0, e0]
    levels = sorted(levels or st.edge_lengths, reverse=True)
    m = {"probe": sc.probes[0].name if sc.probes else None, "measure": "final", "over": "time",
         "section": None, "field": "thickness", "step": None, "norm": "l2"}
    if st is not None:
        m.update({k: getattr(st, k) for k in m if getattr(st, k) is not None})
    analytic = None
    if st is not None and st.published and reference is None:
        analytic = {"name": "published", "value": st.published.value,
                    "about": st.published.source}
    elif st is not None and st.analytic and reference is None:
        from sim.analytic import reference as formula

        analytic = formula(sc, st.analytic, m["probe"])
    elif reference is None:
        ref_edge = st.reference_edge_length if st and st.reference_edge_length else None
        if ref_edge is None:
            ref_edge = levels[-1] / 2
            notes.append(f"reference edge length: half the finest level ({ref_edge:.6g} m)")
        reference = (st.reference_element if st else "quadratic", ref_edge)
    if reference is not None and reference[0] not in ELEMENTS:
        raise ValueError(f"--reference: unknown element {reference[0]!r}")
    return Plan(str(scene_path), _label(m), m, list(elements), list(levels),
                tuple(reference) if reference else None, analytic, overrides, notes)


def case_sizes(plan: Plan) -> list[dict]:
    """The cases of ``plan`` in the order the study runs them (the reference first), each
    with its model's size counted from the mesh parameters, nothing built (sim.model.size):
    ``{element, edge_length, reference, dofs, bytes}``. ValueError for a mesh that cannot be
    counted before it is built."""
    from sim.model import size
    from sim.scene.load import load_scene

    cases = [(el, edge, False) for el in plan.elements for edge in plan.levels]
    if plan.reference:
        cases.insert(0, (*plan.reference, True))
    out = []
    for el, edge, is_ref in cases:
        s = size.estimate(load_scene(plan.scene, {**plan.overrides, **element_overrides(el),
                                                  "mesh.edge_length": edge}))
        if s is None:
            raise ValueError(f"{Path(plan.scene).stem}: its mesh cannot be counted before it "
                             "is built")
        out.append({"element": el, "edge_length": edge, "reference": is_ref, "dofs": s.dofs,
                    "bytes": s.bytes})
    return out

"""What building only the needed terms saves: a scene as it is against the same scene with every
term built, each added term without effect on the answer (``q3t study --overhead-only``)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from sim.model.build import Model
    from sim.scene.load import Scene

OVERHEAD_REPEAT = 3


FAR_TOOL = {"name": "far_plane", "shape": {"kind": "plane", "point": [0.0, 0.0, -1.0e3]}}


def all_terms_overrides(scene: Scene) -> dict:
    """Scene overrides that add, with no effect on the answer, the terms a scene can add
    through its file: a contact term with a plane 1 km below the sheet (every skin node is
    tested against it at every evaluation and none ever reaches it), and a zero gravity
    load."""
    o = {}
    if not scene.tools:
        o["tools"] = [FAR_TOOL]
    if not scene.loads:
        o["loads"] = [{"kind": "gravity", "vector": [0.0, 0.0, 0.0]}]
    return o


def all_terms_model(scene: Scene) -> Model:
    """The model of ``scene`` (see ``all_terms_overrides``) with every other term too, each
    without effect and with the scene's own material law: plastic state under a yield stress
    of 1e30 Pa (never reached: the return map never flows, but runs at every commit and the
    element kernel maps through Fp^-1 at every quadrature point), and inertia with zero mass
    (its energy, gradient and Hessian are evaluated and are zero)."""
    from sim.materials.plasticity import PERFECT
    from sim.model.build import build_model, describe
    from sim.model.terms import lame
    from sim.terms.elasticity import Elasticity
    from sim.terms.inertia import Inertia

    m = build_model(scene)
    el = m.elasticity
    if el not in m.terms:
        raise ValueError("material.model: a linear_elastic scene has no all-terms variant (no "
                         "plastic state can join its small-strain term)")
    if not el.plastic:
        mu, lam = lame(scene.material.E, scene.material.nu)
        full = Elasticity(m.shell, el.rule, el.model, np.array([mu, lam, PERFECT, 1e30]),
                          m.pattern, el.project, plastic=True)
        m.terms[m.terms.index(el)] = full  # the list Problem sums
        m.elasticity = full
    if m.inertia is None:
        m.inertia = Inertia(np.zeros(len(m.x0)), m.pattern, m.x0)
        m.terms.append(m.inertia)
    m.built = describe(m)
    return m


def terms_overhead(scene_path: str, overrides: dict | None = None,
                   repeat: int = OVERHEAD_REPEAT) -> dict:
    """Run time of the scene as it is against the same scene with every term built
    (``all_terms_model``): the two interleaved, after one warm-up each, and the fastest of
    ``repeat`` (other processes on the machine only ever add time)."""
    from sim.model.build import build_model
    from sim.scene.load import load_scene
    from sim.stepping.simulation import Simulation

    base = dict(overrides or {})
    lean_scene = load_scene(scene_path, base)
    extra = all_terms_overrides(lean_scene)
    full_scene = load_scene(scene_path, {**base, **extra})
    variants = {"lean": lambda: build_model(lean_scene),
                "all_terms": lambda: all_terms_model(full_scene)}
    runs: dict[str, list] = {k: [] for k in variants}
    for i in range(repeat + 1):
        for name, build in variants.items():
            sim = Simulation(build())
            sim.run()
            if i:
                runs[name].append(sim)
    out = {"scene": Path(scene_path).stem, "overrides": base, "all_terms_overrides": extra,
           "repeat": repeat}
    for name, sims in runs.items():
        r = sims[0].result()
        out[name] = {"built": r["built"], "converged": r["converged"],
                     "wall": min(s.wall for s in sims),
                     "per_iteration": min(s.result()["timing"]["per_iteration"] for s in sims),
                     "iterations": r["timing"]["newton_iterations"],
                     "probes": r["steps"][-1]["probes"] if r["steps"] else {}}
    lean, full = out["lean"], out["all_terms"]
    out["added_terms"] = [t for t in full["built"]["terms"] if t not in lean["built"]["terms"]]
    out["added_state"] = sorted(set(full["built"]["state"]) - set(lean["built"]["state"]))
    out["saved_wall"] = 1 - lean["wall"] / full["wall"]
    out["saved_per_iteration"] = 1 - lean["per_iteration"] / full["per_iteration"]
    return out


"""q3t check on a handful of its cases (child processes with a budget), the sliver mesh, the
timeout kill, and units: the same scenes in mm-N-s-tonne give the same answers.

Unit system of the scaled scenes (consistent: 1 N = 1 t mm/s^2): lengths mm (x1e3), forces N
(x1), stresses MPa = N/mm^2 (x1e-6), density t/mm^3 (x1e-12), accelerations mm/s^2 (x1e3),
time s (x1). Gravity per volume rho g then scales by 1e-9, as N/m^3 -> N/mm^3 must.
"""

import math
from pathlib import Path

import numpy as np
import pytest

from sim.check import (
    Case,
    make_cases,
    run_check,
    run_isolated,
    select,
    table,
    verdict,
    write_sliver_obj,
)
from sim.mesh import load
from sim.scene import load_scene
from sim.simulation import Simulation

ROOT = Path(__file__).resolve().parent.parent
CANTILEVER = str(ROOT / "scenes" / "cantilever.toml")


def test_sliver_mesh_has_slivers_and_no_inverted_triangle(tmp_path):
    n = write_sliver_obj(tmp_path / "s.obj")
    m = load(tmp_path / "s.obj")  # through the same loader as mesh.kind = "file"
    assert len(m.faces) == n == 320
    V, F = m.vertices, m.faces
    e = [np.linalg.norm(V[F[:, (i + 1) % 3]] - V[F[:, i]], axis=1) for i in range(3)]
    area = 0.5 * np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])[:, 2]
    aspect = np.max(e, axis=0) ** 2 / (2 * area)  # longest edge over its height
    assert area.min() > 0 and 4 <= (aspect > 500).sum() <= 8 and np.median(aspect) < 5


def test_a_handful_of_hard_cases_end_in_an_expected_way():
    cases = select(make_cases(load_scene(CANTILEVER)),
                   "nu=0.4999,h/L=1e-04,1 step,sliver,zero thickness,varying")
    assert len(cases) == 6
    # 80 triangles instead of the check's 320: the same outcomes, a quarter of the time
    rows = run_check(cases, ["linear", "q3t"], budget=40.0, scene_path=CANTILEVER,
                     edges={"linear": 0.035, "q3t": 0.035})
    by = {(r["case"], r["element"]): r for r in rows}
    for r in rows:
        assert r["verdict"] in ("ok", "skipped"), table([r])
        assert r["status"] in ("converged", "failed", "invalid", "skipped"), r
        assert all(math.isfinite(v) for v in r.get("probes", {}).values())
        if r["status"] == "failed":
            assert r["reason"] and r["residual"] is not None and r["cutbacks"] >= 0
    for el in ("linear", "q3t"):
        z = by["zero thickness", el]
        assert z["status"] == "invalid" and "shell.thickness" in z["reason"]
        assert "greater than 0" in z["reason"]
        assert by["varying thickness", el]["status"] == "converged"
        assert by["sliver triangles", el]["status"] == "converged"
        assert by["nu=0.4999", el]["status"] == "converged"
    # Q3T does not lock: at nu = 0.4999 it bends far more than the linear prism
    tip = {el: by["nu=0.4999", el]["probes"]["tip_deflection"] for el in ("linear", "q3t")}
    assert abs(tip["q3t"]) > 1.5 * abs(tip["linear"])
    md = table(rows)
    assert md.count("\n") == len(rows) + 2 and "| zero thickness | linear |" in md


def test_a_run_over_budget_is_killed_and_reported():
    out = run_isolated(CANTILEVER, {"shell.element": "quadratic", "mesh.edge_length": 0.0175},
                       budget=0.5)
    assert out["status"] == "timeout" and "0.5 s budget" in out["reason"]
    assert out["elapsed"] < 8


def test_a_missing_mesh_file_is_rejected_and_a_bug_is_a_crash():
    out = run_isolated(CANTILEVER, {"mesh.kind": "file", "mesh.path": "/nonexistent.obj"}, 30)
    assert out["status"] == "invalid" and "/nonexistent.obj" in out["reason"]
    # no scene path at all: a TypeError inside the run, which no diagnosis covers
    out = run_isolated(None, {}, 30)
    assert out["status"] == "crashed" and "TypeError" in out["reason"]
    assert verdict(Case("x", "x"), out) == "PROBLEM"


def to_mm(sc) -> dict:
    """Overrides that restate scene ``sc`` in mm-N-s-tonne (see the module docstring)."""
    L, S = 1e3, 1e-6
    o = {"shell.thickness": sc.shell.thickness * L, "material.E": sc.material.E * S,
         "material.density": sc.material.density * 1e-12}
    m = sc.mesh
    for k in ("size", "edge_length", "r_outer", "radius", "height"):
        if getattr(m, k) is not None:
            v = getattr(m, k)
            o[f"mesh.{k}"] = [x * L for x in v] if isinstance(v, tuple) else v * L
    o["mesh.origin"] = [x * L for x in m.origin]
    for i, r in enumerate(sc.regions):
        if r.plane:
            o[f"regions.{i}.plane.point"] = [x * L for x in r.plane.point]
            o[f"regions.{i}.plane.tolerance"] = r.plane.tolerance * L
        else:
            o[f"regions.{i}.box.min"] = [x * L for x in r.box.min]
            o[f"regions.{i}.box.max"] = [x * L for x in r.box.max]
    for i, ld in enumerate(sc.loads):
        f = {"gravity": L, "traction": S, "pressure": S, "point": 1.0}[ld.kind]
        if ld.vector is not None:
            o[f"loads.{i}.vector"] = [x * f for x in ld.vector]
        if ld.value is not None:
            o[f"loads.{i}.value"] = ld.value * f
        if ld.point is not None:
            o[f"loads.{i}.point"] = [x * L for x in ld.point]
    for i, bc in enumerate(sc.bcs):
        o[f"bcs.{i}.displacement"] = [x * L for x in bc.displacement]
    for i, p in enumerate(sc.probes):
        if p.point is not None:
            o[f"probes.{i}.point"] = [x * L for x in p.point]
    return o


# probe kind -> its unit's factor from SI to mm-N-s-tonne
PROBE_SCALE = {"displacement": 1e3, "thickness": 1e3, "reaction": 1.0, "volume": 1e9}


@pytest.mark.parametrize("scene,over", [
    ("cantilever", {"mesh.edge_length": 0.035, "stepping.steps": 2}),
    ("stretch_plate", {"mesh.edge_length": 0.07, "stepping.steps": 1}),
], ids=["gravity", "traction"])
@pytest.mark.parametrize("element", ["linear", "q3t"])
def test_scene_in_millimetres_gives_the_same_answer(scene, over, element):
    """Every Newton test is scale-free (rtol relative to the load, the round-off floor in force
    units, xtol in thicknesses), so both runs take the same iterations and differ by round-off
    only: measured 1e-13 to 2e-11 relative. The tolerance, 1e-8, is Newton's own stopping
    tolerance: a unit slip anywhere (a tolerance in metres, a modulus left in Pa) is either an
    O(1) error or a different iteration count, both caught."""
    path = ROOT / "scenes" / f"{scene}.toml"
    base = {**over, "shell.element": element}
    si = Simulation.from_scene(load_scene(path, base))
    mm = Simulation.from_scene(load_scene(path, {**base, **to_mm(load_scene(path, base))}))
    assert si.run() and mm.run()
    assert [r.iterations for r in si.records] == [r.iterations for r in mm.records]
    kinds = {p.name: p.kind for p in si.model.scene.probes}
    for name, v in si.records[-1].probes.items():
        assert mm.records[-1].probes[name] == pytest.approx(v * PROBE_SCALE[kinds[name]],
                                                            rel=1e-8, abs=1e-12), name
    u_si = si.x - si.model.shell.rest
    u_mm = (mm.x - mm.model.shell.rest) / 1e3
    assert np.abs(u_mm - u_si).max() <= 1e-8 * np.abs(u_si).max()

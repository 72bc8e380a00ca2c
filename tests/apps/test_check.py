"""q3t check on a handful of its cases (child processes with a budget), the sliver mesh, the
timeout kill, and units: the same scenes in mm-N-s-tonne give the same answers.

Unit system of the scaled scenes (consistent: 1 N = 1 t mm/s^2): lengths mm (x1e3), forces N
(x1), stresses MPa = N/mm^2 (x1e-6), density t/mm^3 (x1e-12), accelerations mm/s^2 (x1e3),
time s (x1). Gravity per volume rho g then scales by 1e-9, as N/m^3 -> N/mm^3 must.
"""

import math

import numpy as np
import pytest

from sim.apps.cases import run_isolated
from sim.apps.check import (
    BALANCE,
    FAILURES,
    Case,
    make_cases,
    outcome,
    run_check,
    select,
    summary,
    table,
    verdict,
    write_sliver_obj,
)
from sim.geometry.trimesh import load
from sim.scene.load import load_scene
from sim.stepping.simulation import Simulation
from tests.support import ROOT

CANTILEVER = str(ROOT / "scenes" / "cantilever.toml")
# s per case: a hang guard, never a clock a case races. A case here takes seconds; on a cold
# numba cache (a fresh clone, or any change to sim/) its child compiles the kernels first
HANG = 600.0


def _areas(path):
    m = load(path)  # through the same loader as mesh.kind = "file"
    V, F = m.vertices, m.faces
    return m, 0.5 * np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])[:, 2]


def test_sliver_mesh_has_slivers_and_no_inverted_triangle(tmp_path):
    n = write_sliver_obj(tmp_path / "s.obj")
    m, area = _areas(tmp_path / "s.obj")
    assert len(m.faces) == n == 320
    V, F = m.vertices, m.faces
    e = [np.linalg.norm(V[F[:, (i + 1) % 3]] - V[F[:, i]], axis=1) for i in range(3)]
    aspect = np.max(e, axis=0) ** 2 / (2 * area)  # longest edge over its height
    assert area.min() > 0 and 4 <= (aspect > 500).sum() <= 8 and np.median(aspect) < 5


@pytest.mark.parametrize("kind", ["inverted", "flat"])
def test_bad_input_meshes_have_one_bad_triangle_and_are_rejected(tmp_path, kind):
    write_sliver_obj(tmp_path / "m.obj", kind=kind)
    _, area = _areas(tmp_path / "m.obj")
    rel = np.sort(area / np.median(area))
    if kind == "inverted":  # one triangle wound the other way, the rest as generated
        assert rel[0] == pytest.approx(-1.0) and rel[1] > 0.5
    else:  # one triangle of zero area to round-off (either sign), none inverted
        assert abs(rel[0]) < 1e-12 and rel[1] > 0.5
    with pytest.raises(ValueError, match=r"1 element\(s\) inverted or flat"):
        Simulation.from_scene(load_scene(CANTILEVER, {"mesh.kind": "file",
                                                     "mesh.path": str(tmp_path / "m.obj")}))


def test_each_case_names_the_outcome_of_every_element():
    """`q3t check` runs every registered element by default: a case whose outcome is given per
    element names each one it does not skip, else the check stopped there with a KeyError (it
    did once q3t_ans was registered)."""
    from sim.elements import ELEMENTS

    for c in make_cases(load_scene(CANTILEVER)):
        if isinstance(c.expect, dict):
            missing = set(ELEMENTS) - set(c.expect) - set(c.skip)
            assert not missing, (c.name, sorted(missing))


def test_outcomes_are_classified_and_a_wrong_one_is_a_problem():
    """A regression to "no convergence" everywhere must not pass: every case names the outcome
    it must end in, and a converged run must balance its loads."""
    out = {"status": "failed", "reason": "no convergence in 200 iterations (residual 1)"}
    assert outcome(out) == "iteration budget"
    assert verdict(Case("x", "x"), "q3t", out).startswith("PROBLEM")
    floor = {"status": "failed", "reason": "load below force round-off floor (load 1e-8 N, "
             "floor 1e-6 N; line search stalled (residual 1e-6))"}
    assert outcome(floor) == "load below round-off floor"
    case = Case("x", "x", expect={"q3t": "load below round-off floor", "linear": "converged"})
    assert verdict(case, "q3t", floor) == "ok"
    assert verdict(case, "linear", floor).startswith("PROBLEM")
    for cls, words in FAILURES.items():
        assert outcome({"status": "failed", "reason": f"{words} (details)"}) == cls
    assert outcome({"status": "failed", "reason": "something else"}) == "unclassified failure"
    ok = {"status": "converged", "measured": {"balance": 10 * BALANCE}}
    assert verdict(Case("x", "x"), "q3t", ok).startswith("PROBLEM: supports miss")
    assert verdict(Case("x", "x", expect="rejected", reject="shell.thickness"), "q3t",
                   {"status": "invalid", "reason": "mesh.path: missing"}).startswith("PROBLEM")


def test_a_handful_of_hard_cases_end_in_their_expected_outcome():
    cases = select(make_cases(load_scene(CANTILEVER)),
                   "nu=0.4999,h/L=1e-04,1 step,sliver,zero thickness,varying,inverted,zero-area,"
                   "E=1e+06,dt x100")
    assert len(cases) == 10
    # 80 triangles instead of the check's 320: the same outcomes, a quarter of the time. Not
    # for h/L = 1e-4, which is at the edge of double precision either way and is run at the
    # check's size, where Q3T's load is 100x below its floor (it fails in 0.1 s)
    thin = [c for c in cases if c.name == "h/L=1e-04"]
    rows = run_check([c for c in cases if c not in thin], ["linear", "q3t"], budget=HANG,
                     edges={"linear": 0.035, "q3t": 0.035})
    rows += run_check(thin, ["linear", "q3t"], budget=HANG)
    by = {(r["case"], r["element"]): r for r in rows}
    for r in rows:
        assert r["verdict"] == "ok", table([r])
        assert all(math.isfinite(v) for v in r.get("probes", {}).values())
        if r["outcome"] == "converged":
            # the clamp carries the weight (the weight, for the dynamic case: it has settled)
            ms = r["measured"]
            assert ms["support_z"] == pytest.approx(ms["applied_z"], rel=BALANCE)
            assert r["residual"] <= 2 * ms["floor"] or r["residual"] <= 1e-8 * 3.4
    weight = by["nu=0.4999", "q3t"]["measured"]["applied_z"]
    assert weight == pytest.approx(3.36483, rel=1e-5)  # rho g h A of the default plate
    assert by["E=1e+06", "q3t"]["probes"]["clamp_reaction_z"] == pytest.approx(weight,
                                                                                rel=1e-6)
    for el in ("linear", "q3t"):
        z = by["zero thickness", el]
        # refused as not positive, naming the field
        assert "shell.thickness: Input should be greater than 0 m" in z["reason"], z["reason"]
    low = by["h/L=1e-04", "q3t"]["reason"]
    assert "load below force round-off floor (load" in low and "floor" in low
    # Q3T does not lock: at nu = 0.4999 it bends far more than the linear prism
    tip = {el: by["nu=0.4999", el]["probes"]["tip_deflection"] for el in ("linear", "q3t")}
    assert abs(tip["q3t"]) > 1.5 * abs(tip["linear"])
    # the plate hanging down (E = 1 MPa) goes past 30 iterations without a cut-back
    big = by["E=1e+06", "q3t"]
    assert big["cutbacks"] == 0 and big["probes"]["tip_deflection"] < -0.6
    md = table(rows)
    assert md.count("\n") == len(rows) + 2 and "| zero thickness | linear |" in md
    sm = summary(rows)
    assert sm.count("\n") == len(cases) + 2 and "| zero thickness | rejected | rejected |" in sm


def test_the_punch_100x_faster_converges_and_balances_the_die():
    """The 13.2 mm stroke in one step: sub-steps keep the punch within a thickness per
    increment, and the beam, held in z by nothing else, is pressed between punch and mold
    into the mold's curvature."""
    (row,) = run_check(select(make_cases(load_scene(CANTILEVER)), "punch 100x"), ["linear"],
                       budget=HANG)
    assert row["verdict"] == "ok" and row["outcome"] == "converged", table([row])
    assert row["measured"]["support_z"] == 0.0  # no z support: the tools balance each other
    # the closed mold's 10 1/m (measured 9.9951, as in 100 steps); the squeezing force is
    # path-dependent (27.2 kN here, 30.5 kN in 100 steps) and not compared
    assert row["probes"]["curvature"] == pytest.approx(10.0, rel=1e-3)


def test_a_run_over_budget_is_killed_and_reported():
    """100,000 steps run for minutes: the case blocks until its 0.5 s budget kills it (SIGTERM,
    SIGKILL 2 s later), however slow the machine."""
    out = run_isolated(CANTILEVER, {"mesh.edge_length": 0.07, "stepping.steps": 100_000},
                       budget=0.5)
    assert out["status"] == "timeout" and "0.5 s budget" in out["reason"]
    assert out["elapsed"] < 60  # killed, not run to its end


def test_a_missing_mesh_file_is_rejected_and_a_bug_is_a_crash():
    out = run_isolated(CANTILEVER, {"mesh.kind": "file", "mesh.path": "/nonexistent.obj"},
                       HANG)
    assert out["status"] == "invalid" and "/nonexistent.obj" in out["reason"]
    # no scene path at all: a TypeError inside the run, which no diagnosis covers
    out = run_isolated(None, {}, HANG)
    assert out["status"] == "crashed" and "TypeError" in out["reason"]
    assert verdict(Case("x", "x"), "q3t", out).startswith("PROBLEM")


def to_mm(sc) -> dict:
    """Overrides that restate scene ``sc`` in mm-N-s-tonne (see the module docstring)."""
    L, S = 1e3, 1e-6
    o = {"shell.thickness": sc.shell.thickness * L, "material.E": sc.material.E * S,
         "material.density": sc.material.density * 1e-12}
    m = sc.mesh
    for k in ("size", "edge_length", "r_outer", "radius", "height"):  # those its kind has
        if getattr(m, k, None) is not None:
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
        if getattr(ld, "vector", None) is not None:
            o[f"loads.{i}.vector"] = [x * f for x in ld.vector]
        if getattr(ld, "value", None) is not None:
            o[f"loads.{i}.value"] = ld.value * f
        if getattr(ld, "point", None) is not None:
            o[f"loads.{i}.point"] = [x * L for x in ld.point]
    for i, bc in enumerate(sc.bcs):
        o[f"bcs.{i}.displacement"] = [x * L for x in bc.displacement]
    for i, p in enumerate(sc.probes):
        if p.point is not None:
            o[f"probes.{i}.point"] = [x * L for x in p.point]
    return o


# probe kind -> its unit's factor from SI to mm-N-s-tonne
PROBE_SCALE = {"displacement": 1e3, "thickness": 1e3, "height_range": 1e3, "reaction": 1.0,
               "volume": 1e9}


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

"""q3t study: the plan's defaults, studies run on a local Dask cluster (a two-level study with
its report and plots, an analytic reference, curve and profile measures), a failing reference,
the Fig. 7 factorisation timing at tiny size, and "leave out what a scene does not need": every
scene in scenes/ builds and records only what it needs, and the all-terms variant used for the
time comparison builds every term with the same answer."""

import json
import math

import numpy as np
import pytest

from sim.apps.cli import main
from sim.apps.factorisation import factorisation_times
from sim.apps.overhead import all_terms_model, all_terms_overrides, terms_overhead
from sim.apps.study import curve_error, make_plan, run_study
from sim.apps.study_report import write_factorisation, write_study
from sim.model.build import build_model, frame_fields
from sim.scene.load import SceneError, load_scene
from sim.stepping.simulation import Simulation
from tests.support import ROOT
from tests.support.scenes import SCENES, coarsest_mesh

CONVERGENCE = str(ROOT / "scenes" / "convergence.toml")
CANTILEVER = str(ROOT / "scenes" / "cantilever.toml")
QUIET = {"progress": lambda s: None}


def test_plan_takes_the_study_table_or_says_which_defaults_it_used():
    p = make_plan(CONVERGENCE)
    assert p.probe == "tip_deflection" and p.elements == ["linear", "q3t", "quadratic"]
    assert p.reference == ("quadratic", 0.0035) and p.levels[0] > p.levels[-1] and not p.notes
    q = make_plan(CANTILEVER, ["q3t"])
    e = load_scene(CANTILEVER).mesh.edge_length
    assert q.levels == [4 * e, 2 * e, e] and q.reference == ("quadratic", e / 2)
    assert any("no [study] table" in n for n in q.notes)
    assert any("half the finest" in n for n in q.notes)


def test_plan_only_prints_the_cases_sizes_and_runs_nothing(tmp_path, capsys):
    """``--plan``: the cases in the order they run, each sized by sim.model.size from the
    mesh parameters (what the page's plan also shows, with times), and nothing written."""
    from sim.model import size
    from sim.refinement import case_sizes

    rc = main(["study", "convergence", "--elements", "q3t,linear", "--levels", "0.035,0.0175",
               "--plan", "--out", str(tmp_path / "out")])
    out = capsys.readouterr().out
    assert rc == 0 and not (tmp_path / "out").exists()
    sizes = case_sizes(make_plan(CONVERGENCE, ["q3t", "linear"], [0.035, 0.0175]))
    assert [(c["element"], c["edge_length"], c["reference"]) for c in sizes] == [
        ("quadratic", 0.0035, True), ("q3t", 0.035, False), ("q3t", 0.0175, False),
        ("linear", 0.035, False), ("linear", 0.0175, False)]
    for c in sizes:
        s = size.estimate(load_scene(CONVERGENCE, {"shell.element": c["element"],
                                                   "mesh.edge_length": c["edge_length"]}))
        assert (c["dofs"], c["bytes"]) == (s.dofs, s.bytes)
        case = ("reference " if c["reference"] else "") + c["element"]
        assert f"| {case} | {c['edge_length']:.6g} | {c['dofs']:,} | " in out, out


def test_two_level_study_on_dask_writes_report_and_plots(tmp_path):
    plan = make_plan(CONVERGENCE, ["linear", "q3t"], [0.07, 0.035], ("quadratic", 0.035))
    study = run_study(plan, overhead={"overrides": {"mesh.edge_length": 0.07}, "repeat": 1},
                      **QUIET)
    rows = {(r["element"], r["edge_length"]): r for r in study["rows"]}
    assert len(rows) == 4 and all(r["status"] == "converged" for r in rows.values())
    for edge in (0.07, 0.035):  # Poisson locking at nu = 0.499 (paper Fig. 8)
        assert rows["q3t", edge]["error"] < rows["linear", edge]["error"] < 1
        assert rows["q3t", edge]["time"] > 0 and rows["q3t", edge]["dofs"] > 0
    assert "1 worker process" in study["cluster"] and "1 thread" in study["cluster"]
    write_study(study, [study["overhead"]], tmp_path)
    md = (tmp_path / "report.md").read_text()
    assert "reference **quadratic at edge 0.035 m**" in md and "Dask" in md
    assert "Leave out what a scene does not need" in md and "saved" in md
    for stem in ("error_time", "error_dofs"):
        assert (tmp_path / f"{stem}.png").stat().st_size > 0
        assert (tmp_path / f"{stem}.svg").is_file()
    data = json.loads((tmp_path / "report.json").read_text())
    assert data["study"]["reference"]["value"] == pytest.approx(study["reference"]["value"])


EB = {"material.nu": 0.0, "material.E": 1e11, "stepping.steps": 1}  # tip at 0.1 % of L


def test_analytic_reference_euler_bernoulli_on_the_cantilever_at_nu_zero(tmp_path):
    plan = make_plan(CANTILEVER, ["quadratic"], [0.07, 0.035, 0.0175], None, EB,
                     {"analytic": "euler_bernoulli"})
    assert plan.reference is None and plan.analytic["name"] == "euler_bernoulli"
    # 3 rho g L^4 / (2 E h^2), from the scene's numbers
    assert plan.analytic["value"] == pytest.approx(-1.5 * 1000 * 9.81 * 0.7**4 / (1e11 * 0.007**2))
    study = run_study(plan, **QUIET)
    err = [r["error"] for r in study["rows"]]
    # measured 2.8e-3, 4.5e-4, 8e-7: the quadratic element converges to beam theory (shear
    # adds ~(h/L)^2 = 1e-4 of flexibility, so below that the ordering is not guaranteed)
    assert err[0] > err[1] > err[2] and err[1] < 1e-3
    assert study["reference_label"] == "euler_bernoulli (analytic)"
    # what the service shows for a finished run: the study's error against the formula
    from server.estimate import estimate

    write_study(study, [], tmp_path / "study-cantilever")
    assert "euler_bernoulli (analytic)" in (tmp_path / "study-cantilever" / "report.md").read_text()
    est = estimate(tmp_path, "cantilever", "quadratic", 0.035, None)
    assert est["available"] and est["reference"]["kind"] == "analytic"
    assert est["relative_error"] == pytest.approx(err[1], rel=1e-12)


def test_analytic_reference_rejects_a_scene_outside_its_assumptions(capsys):
    with pytest.raises(SceneError, match="study.analytic: euler_bernoulli needs material.nu = 0"):
        make_plan(CANTILEVER, study={"analytic": "euler_bernoulli"})
    assert main(["study", "plastic_bending", "--analytic", "euler_bernoulli"]) == 2
    assert "an elastic material" in capsys.readouterr().err
    plan = make_plan(str(ROOT / "scenes" / "plastic_bending.toml"), ["q3t"], [0.005], None,
                     {}, {"analytic": "springback", "probe": "curvature"})
    # X = (2/sqrt3) 16 MPa / (1 1/m * 200 GPa / (1 - 0.33^2) * 5 mm) = 0.0165: 95 % kept
    assert plan.analytic["value"] == pytest.approx(0.9506, abs=1e-4)


def test_curve_error_is_the_relative_norm_on_the_common_range():
    x = np.linspace(0.0, 1.0, 11)
    xr = np.linspace(0.2, 1.5, 40)
    # a line: linear interpolation is exact, so the error is the 3 % scale alone
    assert curve_error(x, 1.03 * x, xr, xr, "l2") == pytest.approx(0.03, rel=1e-12)
    assert curve_error(x, 1.03 * x, xr, xr, "max") == pytest.approx(0.03, rel=1e-12)
    assert curve_error(x[::-1], x[::-1], xr, xr) == 0.0  # a decreasing abscissa (a stroke)
    assert math.isnan(curve_error(np.r_[0, 1, 0.5], np.r_[0, 1, 2], xr, xr))  # folds back
    assert math.isnan(curve_error(x, x, xr + 2, xr))  # no common range


SECTION = [{"name": "edge", "direction": [1.0, 0.0], "width": 1e-4}]


def test_curve_and_profile_measures_on_the_cantilever_in_load_steps(tmp_path):
    """The tip deflection over the 4 load steps, and the deflection line along the edge y = 0
    (a section) after them, each against the quadratic element at the finest level: that case
    is the reference itself (error 0), the coarser one is not."""
    o = {"sections": SECTION}
    plan = make_plan(CANTILEVER, ["quadratic"], [0.07, 0.035], ("quadratic", 0.035), o,
                     {"measure": "curve", "probe": "tip_deflection"})
    study = run_study(plan, **QUIET)
    coarse, fine = study["rows"]
    assert fine["error"] == 0.0 and 0.01 < coarse["error"] < 1
    rc = main(["study", "cantilever", "--elements", "quadratic", "--levels", "0.07,0.035",
               "--reference", "quadratic:0.035", "--measure", "profile",
               "--set", "sections=[{name = 'edge', direction = [1.0, 0.0], width = 1e-4}]",
               "--set", "study.section=edge", "--set", "study.field=z",
               "--set", "study.norm=max", "--no-overhead", "--out", str(tmp_path)])
    assert rc == 0
    rows = json.loads((tmp_path / "report.json").read_text())["study"]["rows"]
    assert rows[1]["error"] == 0.0 and 0.01 < rows[0]["error"] < 1
    assert "edge.z profile (max)" in (tmp_path / "report.md").read_text()


def test_study_command_line_and_its_exit_codes(tmp_path, capsys):
    rc = main(["study", "convergence", "--elements", "q3t", "--levels", "0.07",
               "--reference", "quadratic:0.07", "--no-overhead", "--out", str(tmp_path)])
    assert rc == 0
    rows = json.loads((tmp_path / "report.json").read_text())["study"]["rows"]
    assert rows[0]["element"] == "q3t" and np.isfinite(rows[0]["error"])
    assert main(["study", "convergence", "--reference", "quadratic", "--out",
                 str(tmp_path)]) == 2
    assert "q3t study: --reference needs ELEMENT:EDGE" in capsys.readouterr().err
    assert main(["study", "convergence", "--set", "study.measure=profile"]) == 2
    assert "a profile study needs section" in capsys.readouterr().err
    # the reference cannot converge: reported, exit 1 (a run failed), no traceback
    rc = main(["study", "convergence", "--elements", "q3t", "--levels", "0.07",
               "--reference", "quadratic:0.07", "--set", "solver.max_iterations=1",
               "--set", "stepping.max_cutbacks=0", "--no-overhead", "--out",
               str(tmp_path / "bad")])
    err = capsys.readouterr().err
    assert rc == 1 and "reference run quadratic at 0.07 m ended failed: no convergence" in err
    assert "Traceback" not in err and not (tmp_path / "bad" / "report.json").exists()


def test_a_case_over_its_budget_stops_after_a_step_and_the_study_goes_on(tmp_path):
    """--budget: a case that has spent its seconds stops after the step that used them up,
    marked timeout with where it stood; the others and the report go on."""
    from sim.apps.cases import run_case

    # a budget of 1 ns is spent before the first step ends: the case stops after it
    r = run_case(CONVERGENCE, {"mesh.edge_length": 0.07, "stepping.steps": 3}, budget=1e-9)
    assert r["status"] == "timeout" and not r["converged"]
    assert r["reason"].startswith("over its budget of 1e-09 s after step 1 of 3")
    assert r["probes"] and r["iterations"] > 0  # what the finished step gave
    # the last step is never cut: a run done within its steps converges whatever the budget
    r = run_case(CONVERGENCE, {"mesh.edge_length": 0.07, "stepping.steps": 1}, budget=1e-9)
    assert r["status"] == "converged"
    rc = main(["study", "convergence", "--elements", "q3t", "--levels", "0.07",
               "--reference", "quadratic:0.07", "--set", "stepping.steps=2", "--budget",
               "1e-9", "--no-overhead", "--out", str(tmp_path)])
    assert rc == 0
    rows = json.loads((tmp_path / "report.json").read_text())["study"]["rows"]
    assert rows[0]["status"] == "timeout" and rows[0]["error"] is None
    assert "over its budget" in rows[0]["reason"]
    assert main(["study", "convergence", "--budget", "0"]) == 2


def test_factorisation_mode_times_each_element(tmp_path):
    rows = factorisation_times(CONVERGENCE, ["linear", "q3t"], [0.07], repeat=10)
    lin, q3t = rows
    assert lin["elements"] == q3t["elements"] == 20
    assert q3t["nodes"] == lin["nodes"] * 3 // 2  # a mid-surface layer: 3 layers against 2
    assert all(0 < r["factorisation_min"] <= r["factorisation"] for r in rows)
    assert all(r["repeat"] == 10 for r in rows)
    write_factorisation(CONVERGENCE, rows, tmp_path, "here")
    md = (tmp_path / "report.md").read_text()
    assert "Fig. 7" in md and "median and minimum of 10" in md
    assert (tmp_path / "factorisation.png").stat().st_size > 0


@pytest.mark.parametrize("scene,o", [("convergence", {"mesh.edge_length": 0.07}),
                                     ("plastic_bending", {})])
def test_all_terms_variant_builds_every_term_and_keeps_the_answer(scene, o):
    r = terms_overhead(str(ROOT / "scenes" / f"{scene}.toml"), o, repeat=1)
    lean, full = r["lean"], r["all_terms"]
    assert lean["converged"] and full["converged"]
    assert {"elasticity", "external_force", "inertia", "contact:far_plane"} <= set(
        full["built"]["terms"])
    assert full["built"]["plastic_state"] and "inertia.v" in full["built"]["state"]
    # same elastic law, zero mass, a tool that is never reached, a yield never met: the
    # added terms contribute exact zeros, so Newton takes the same path to the same bits
    assert full["iterations"] == lean["iterations"]
    assert full["probes"] == lean["probes"]
    assert lean["per_iteration"] > 0 and full["per_iteration"] > 0


@pytest.mark.parametrize("path", SCENES, ids=[p.stem for p in SCENES])
def test_scene_builds_only_what_it_needs(path):
    o = coarsest_mesh(load_scene(path))
    sc = load_scene(path, o)
    sim = Simulation.from_scene(sc)
    built = sim.model.built
    terms, state = built["terms"], built["state"]
    small = sc.material.model == "linear_elastic"  # the elastic term linearised at rest
    assert terms[0] == ("small_strain_elasticity" if small else "elasticity")
    assert len(terms) == len(set(terms))
    tools = [t.name for t in sc.tools]
    assert ("inertia" in terms) == (sc.stepping.kind == "dynamic") == ("inertia.v" in state)
    plastic = sc.material.model == "plastic"
    assert built["plastic_state"] == plastic == ("plastic.ep" in state)
    assert sim.model.elasticity.ep.size == (state["plastic.ep"][0] * state["plastic.ep"][1]
                                            if plastic else 0)
    assert ("external_force" in terms) == bool(sc.loads)
    assert [t for t in terms if t.startswith("contact:")] == [f"contact:{t}" for t in tools]
    assert built["outputs"]["tools"] == tools
    assert built["outputs"]["probes"] == [p.name for p in sc.probes]
    # the report says what a frame carries: no plastic strain field for an elastic scene
    assert list(sim.frame().fields) == built["outputs"]["frame_fields"]
    assert ("eq_plastic_strain_pct" in built["outputs"]["frame_fields"]) == plastic
    if small:  # no plastic state can join a small-strain term: no all-terms variant
        return
    full = all_terms_model(load_scene(path, {**o, **all_terms_overrides(sc)})).built
    assert {"elasticity", "external_force", "inertia"} <= set(full["terms"])
    assert full["plastic_state"] and any(t.startswith("contact:") for t in full["terms"])


def test_frame_fields_follow_the_plastic_state():
    m = build_model(load_scene(CANTILEVER, {"mesh.edge_length": 0.07}))
    assert frame_fields(m) == ["thickness_mm", "thinning_pct", "von_mises_MPa"]

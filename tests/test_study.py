"""q3t study: the plan's defaults, a two-level study and the Fig. 7 factorisation timing at tiny
size with their reports and plots, and "leave out what a scene does not need": every scene in
scenes/ builds no inertia when static, no plastic state when elastic, no load term without
loads, while the all-terms variant used for the time comparison builds all of them."""

import json
from pathlib import Path

import numpy as np
import pytest

from sim.cli import main
from sim.model import build_model
from sim.scene import load_scene
from sim.study import (
    all_terms_overrides,
    factorisation_times,
    make_plan,
    run_study,
    terms_overhead,
    write_factorisation,
    write_study,
)

ROOT = Path(__file__).resolve().parent.parent
CONVERGENCE = str(ROOT / "scenes" / "convergence.toml")
SCENES = sorted((ROOT / "scenes").glob("*.toml"))


def test_plan_takes_the_study_table_or_says_which_defaults_it_used():
    p = make_plan(CONVERGENCE)
    assert p.probe == "tip_deflection" and p.elements == ["linear", "q3t", "quadratic"]
    assert p.reference == ("quadratic", 0.0035) and p.levels[0] > p.levels[-1] and not p.notes
    q = make_plan(str(ROOT / "scenes" / "cantilever.toml"), ["q3t"])
    e = load_scene(ROOT / "scenes" / "cantilever.toml").mesh.edge_length
    assert q.levels == [4 * e, 2 * e, e] and q.reference == ("quadratic", e / 2)
    assert any("no [study] table" in n for n in q.notes)
    assert any("half the finest" in n for n in q.notes)


def test_two_level_study_writes_report_and_plots(tmp_path):
    plan = make_plan(CONVERGENCE, ["linear", "q3t"], [0.07, 0.035], ("quadratic", 0.035))
    study = run_study(plan, progress=lambda s: None)
    rows = {(r["element"], r["edge_length"]): r for r in study["rows"]}
    assert len(rows) == 4 and all(r["status"] == "converged" for r in rows.values())
    for edge in (0.07, 0.035):  # Poisson locking at nu = 0.499 (paper Fig. 8)
        assert rows["q3t", edge]["error"] < rows["linear", edge]["error"] < 1
        assert rows["q3t", edge]["time"] > 0 and rows["q3t", edge]["dofs"] > 0
    overhead = terms_overhead(CONVERGENCE, {"mesh.edge_length": 0.07}, repeat=1)
    write_study(study, overhead, tmp_path)
    md = (tmp_path / "report.md").read_text()
    assert "reference **quadratic at edge 0.035 m**" in md
    assert "Leave out what a scene does not need" in md
    for stem in ("error_time", "error_dofs"):
        assert (tmp_path / f"{stem}.png").stat().st_size > 0
        assert (tmp_path / f"{stem}.svg").is_file()
    data = json.loads((tmp_path / "report.json").read_text())
    assert data["study"]["reference"]["value"] == pytest.approx(study["reference"]["value"])


def test_all_terms_variant_builds_every_term_and_keeps_the_answer():
    o = terms_overhead(CONVERGENCE, {"mesh.edge_length": 0.07}, repeat=1)
    lean, full = o["lean"], o["all_terms"]
    assert lean["built"]["terms"] == ["elasticity", "external_force"]
    assert not lean["built"]["plastic_state"]
    assert {"elasticity", "external_force", "inertia"} <= set(full["built"]["terms"])
    assert full["built"]["plastic_state"] and lean["converged"] and full["converged"]
    # inertia weight M/dt^2 at dt = 1e6 s is ~1e-12 of the stiffness and the yield stress is
    # never reached; what remains is Hencky (plastic model) against neo-Hookean at strains of
    # ~1e-4, a relative difference of the order of the strain
    p0, p1 = lean["probes"]["tip_deflection"], full["probes"]["tip_deflection"]
    assert p1 == pytest.approx(p0, rel=1e-3)
    assert lean["per_iteration"] > 0 and full["per_iteration"] > 0


def _coarse(path: Path) -> dict:
    sc = load_scene(path)
    if sc.mesh.kind == "rectangle":
        return {"mesh.edge_length": max(sc.mesh.size) / 8}
    if sc.mesh.kind in ("annulus", "disk"):
        return {"mesh.edge_length": sc.mesh.r_outer / 4}
    return {}


@pytest.mark.parametrize("path", SCENES, ids=[p.stem for p in SCENES])
def test_scene_builds_only_the_terms_it_needs(path):
    o = _coarse(path)
    sc = load_scene(path, o)
    built = build_model(sc).built
    terms = built["terms"]
    assert terms[0] == "elasticity" and len(terms) == len(set(terms))
    assert ("inertia" in terms) == (sc.stepping.kind == "dynamic")
    assert built["plastic_state"] == (sc.material.model == "plastic")
    assert ("external_force" in terms) == bool(sc.loads)
    tools = [t.name for t in getattr(sc, "tools", [])]
    assert len(set(terms) - {"elasticity", "external_force", "inertia"}) <= len(tools)
    if not tools:
        assert set(terms) <= {"elasticity", "external_force", "inertia"}
    full = build_model(load_scene(path, {**o, **all_terms_overrides(sc)})).built
    assert {"elasticity", "external_force", "inertia"} <= set(full["terms"])
    assert full["plastic_state"]


def test_factorisation_mode_times_each_element(tmp_path):
    rows = factorisation_times(CONVERGENCE, ["linear", "q3t"], [0.07], repeat=2)
    lin, q3t = rows
    assert lin["elements"] == q3t["elements"] == 20
    assert q3t["nodes"] == lin["nodes"] * 3 // 2  # a mid-surface layer: 3 layers against 2
    assert all(r["factorisation"] > 0 for r in rows)
    write_factorisation(CONVERGENCE, rows, tmp_path)
    assert "Fig. 7" in (tmp_path / "report.md").read_text()
    assert (tmp_path / "factorisation.png").stat().st_size > 0


def test_study_command_line(tmp_path, capsys):
    rc = main(["study", "convergence", "--elements", "q3t", "--levels", "0.07",
               "--reference", "quadratic:0.07", "--no-overhead", "--out", str(tmp_path)])
    assert rc == 0
    rows = json.loads((tmp_path / "report.json").read_text())["study"]["rows"]
    assert rows[0]["element"] == "q3t" and np.isfinite(rows[0]["error"])
    assert main(["study", "convergence", "--reference", "quadratic", "--out",
                 str(tmp_path)]) == 2
    assert "q3t study" in capsys.readouterr().err

"""What the accuracy and springback tables of docs/results/ are made with: a study element
with its quadrature rule (``q3t:3x3``), the Richardson extrapolation of a study's finest three
levels, and ``q3t springback``'s bad input, refused before any case runs. The generators
themselves run at their smallest size in test_results.py."""

import pytest

from sim.apps.cli import main
from sim.apps.study_report import extrapolation_md, extrapolations, richardson
from sim.model.build import build_model
from sim.refinement import element_overrides
from sim.scene.load import load_scene
from tests.support import ROOT

pytestmark = pytest.mark.fast  # no solve: a model build at most


def test_richardson_recovers_a_known_limit_and_rate():
    h = [0.04, 0.02, 0.01]
    limit, rate = richardson(h, [0.7 - 3.0 * x**1.5 for x in h])
    assert limit == pytest.approx(0.7, rel=1e-12) and rate == pytest.approx(1.5, rel=1e-9)
    h = [0.0175, 0.00875, 0.0046667]  # any ratios, as the cantilever's levels
    limit, rate = richardson(h, [1.0 + 0.2 * x**2.2 for x in h])
    assert limit == pytest.approx(1.0, rel=1e-12) and rate == pytest.approx(2.2, rel=1e-9)
    with pytest.raises(ValueError, match="not monotone"):
        richardson(h, [0.5, 0.6, 0.55])
    with pytest.raises(ValueError, match="no rate"):  # steps that grow: not asymptotic
        richardson([0.035, 0.0175, 0.00875], [0.49, 0.66, 0.87])


def _row(el, h, w, status="converged"):
    return {"element": el, "edge_length": h, "probe": w, "status": status}


def test_a_study_extrapolates_each_element_through_its_three_finest_converged_levels():
    h = [0.04, 0.02, 0.01, 0.005]
    rows = [_row("q3t", x, -2.0 * (1 - 4 * x**2)) for x in h]
    rows += [_row("linear", x, -1.0) for x in h[:2]]  # two levels: nothing to fit
    rows.append(_row("linear", 0.01, None, "failed"))
    study = {"plan": {"measure": {"measure": "final"}, "analytic": None,
                      "elements": ["linear", "q3t"]},
             "reference": {"value": -2.0}, "rows": rows}
    (q3t,) = extrapolations(study)
    assert q3t["element"] == "q3t" and q3t["edges"] == "0.02, 0.01, 0.005"
    assert q3t["rate"] == pytest.approx(2) and q3t["ratio"] == pytest.approx(1)
    assert "| fit |" not in extrapolation_md([q3t])  # every fit held: no column to say so
    rows += [_row("linear", x, w) for x, w in ((0.01, -1.1), (0.005, -1.05))]  # not monotone
    lin, q3t = extrapolations(study)
    assert lin["fit"] == "none: the values are not monotone" and "limit" not in lin
    assert "| fit |" in extrapolation_md([lin, q3t])
    study["plan"]["measure"]["measure"] = "curve"  # a curve's error has no probe to fit
    assert extrapolations(study) == []


def test_a_study_element_carries_its_quadrature_rule_to_the_model():
    # plastic_bending sets thickness_points = 9, which would replace the rule's 40
    o = {**element_overrides("q3t:1x40"), "mesh.edge_length": 0.01}
    m = build_model(load_scene(ROOT / "scenes" / "plastic_bending.toml", o))
    assert m.quadrature == {"rule": [1, 40], "why": "scene"}
    assert element_overrides("linear") == {"shell.element": "linear"}


@pytest.mark.parametrize("spec, why", [("prism", "unknown element 'prism'"),
                                       ("q3t:3", "N x M points"),
                                       ("q3t:2x3", "no triangle rule with 2 points"),
                                       ("q3t:3x0", "at least one point")])
def test_a_bad_study_element_is_refused_naming_it(spec, why, tmp_path, capsys):
    out = tmp_path / "runs"
    assert main(["study", "cantilever", "--elements", f"linear,{spec}", "--out", str(out)]) == 2
    assert why in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize("argv, why", [
    (["--X", "1.5"], "--X: each X must lie in (0, 1)"),
    (["--X", "0.1,abc"], "--X: '0.1,abc' is not"),
    (["--elements", "q3t,prism"], "--elements: unknown 'prism'"),
    (["--spacing", "0"], "--spacing must be positive"),
    (["--points", "0"], "--points must be at least 1"),
    (["--scene", "cantilever"], "bcs: springback needs one bent end"),
    (["--scene", "HARDENING"], "needs an elastic-perfectly-plastic material"),  # no formula
    (["--scene", "nonesuch"], "no scene 'nonesuch'"),
])
def test_springback_refuses_bad_input_before_any_case_runs(argv, why, tmp_path, capsys):
    if "HARDENING" in argv:  # plastic_bending with a hardening material
        text = (ROOT / "scenes" / "plastic_bending.toml").read_text()
        scene = tmp_path / "hardening.toml"
        scene.write_text(text.replace('law = "perfect"', 'law = "linear", modulus = 1e9'))
        argv = ["--scene", str(scene)]
    path = tmp_path / "springback.md"
    assert main(["springback", *argv, "--out", str(tmp_path / "runs"),
                 "--results", str(path)]) == 2
    assert why in capsys.readouterr().err
    assert not path.exists() and not (tmp_path / "runs").exists()

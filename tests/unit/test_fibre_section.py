"""The fibre model of a bent section (sim.analytic.fibre_section), the reference for springback
of any hardening law: against the closed form of a bilinear section in plane stress, and against
the classical plane-strain formula of perfect plasticity."""

import math

import pytest

from sim.analytic import fibre_section, reference
from sim.materials.plasticity import LINEAR, PERFECT
from sim.scene.load import load_scene

E, NU, Y, T = 200e9, 0.33, 16e6, 0.005  # scenes/plastic_bending.toml


def bilinear_moment(H: float, k: float) -> float:
    """Moment per unit width of a uniaxial section (plane stress) of linear isotropic hardening
    Y = Y0 + H ep bent to curvature k: elastic E below the yield strain, tangent E H / (E + H)
    above it, integrated over the elastic core |z| < z_y and the plastic skins."""
    c, ey = T / 2, Y / E
    zy, Et = min(ey / k, c), E * H / (E + H)
    return 2 * (E * k * zy**3 / 3 + Y * (c * c - zy * zy) / 2 + Et * k * (c**3 - zy**3) / 3
                - Et * ey * (c * c - zy * zy) / 2)


@pytest.mark.parametrize("H, k", [(0.0, 1.0), (2e9, 1.0), (2e9, 0.1)])
def test_plane_stress_section_matches_the_bilinear_closed_form(H, k):
    """400 fibres: the midpoint rule's error at the elastic core's kink is O(1/n^2), 1e-5 here
    (measured 1e-6); the 1e-4 bound leaves room for it and for the 40 load increments (exact
    in uniaxial stress: the return map is then the bilinear law itself). k = 0.1 keeps a core
    of 0.16 t."""
    r = fibre_section(E, NU, LINEAR, [Y, H], T, k, plane_strain=False)
    M = bilinear_moment(H, k)
    assert r["moment"] == pytest.approx(M, rel=1e-4)
    assert r["springback"] == pytest.approx(M / (E * T**3 / 12), rel=1e-4)
    assert r["released"] == pytest.approx(k - r["springback"], rel=1e-12)


def test_plane_strain_section_matches_the_classical_formula():
    """Perfect plasticity in plane strain: K = 4 X^3 - 3 X + 1 with E / (1 - nu^2) and
    2 Y / sqrt(3) assumes the fully plastic fibres' stress ratio from the core on, where the
    fibre model lets it move from nu to 1/2 over a few yield strains: a fraction of order X of
    the section (X = 0.016 at 1 / m). Measured 2.5e-5 of the springback; bound 1e-3."""
    Ep, Yp = E / (1 - NU**2), 2 * Y / math.sqrt(3)
    X = Yp / (Ep * T)
    r = fibre_section(E, NU, PERFECT, [Y], T, 1.0, plane_strain=True)
    assert r["springback"] == pytest.approx(3 * X - 4 * X**3, rel=1e-3)


def test_fibre_is_the_scenes_study_reference():
    """plastic_bending as a study: its bend, plane strain from its BC, its hardening law."""
    sc = load_scene("scenes/plastic_bending.toml")
    ref = reference(sc, "fibre", "curvature")
    assert ref["value"] == pytest.approx(reference(sc, "springback", "curvature")["value"],
                                         rel=1e-4)
    assert "plane strain" in ref["about"]
    hard = load_scene("scenes/plastic_bending.toml", {
        "material.hardening": {"law": "linear", "modulus": 2e9}, "bcs.0.components": "x"})
    ref = reference(hard, "fibre", "curvature")
    assert "plane stress" in ref["about"] and "linear" in ref["about"]
    with pytest.raises(ValueError, match="elastic-perfectly-plastic"):
        reference(hard, "springback", "curvature")
    hill = load_scene("scenes/plastic_bending.toml", {
        "material.hill48": {"r0": 0.663, "r45": 0.860, "r90": 0.717, "rolling_angle": 0.0}})
    with pytest.raises(ValueError, match="no material.hill48"):
        reference(hill, "fibre", "curvature")

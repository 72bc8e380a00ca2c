"""The CalculiX input deck written from our model (sim.apps.calculix) and the reading of ccx's
output, on a stored sample of real ccx 2.20 output (tests/data/calculix: the cantilever at a
35 mm edge, linear prisms as C3D6; ``linear-matched`` converged at *CONTROLS 1e-4,
``linear-rtol1e-8`` is ccx giving up at our default tolerance). No ccx needed."""

import re

import numpy as np
import pytest

from sim.apps import calculix as cx
from sim.apps.common import load
from sim.model.build import build_model
from tests.support import ROOT

DATA = ROOT / "tests" / "data" / "calculix"
EDGE = 0.035  # the samples' mesh: 20 x 2 cells, 80 triangles, 63 vertices


def _model(element: str = "linear", **extra):
    return build_model(load("cantilever", {"shell.element": element, "mesh.edge_length": EDGE,
                                           **extra}))


def _blocks(text: str) -> dict[str, list[str]]:
    """Keyword line -> the data lines under it, for the first occurrence of each keyword."""
    out: dict[str, list[str]] = {}
    key = None
    for line in text.splitlines():
        if line.startswith("**"):
            continue
        if line.startswith("*"):
            key = line if line not in out else None
            if key:
                out[key] = []
        elif key:
            out[key].append(line)
    return out


def test_linear_prisms_are_c3d6_on_the_same_nodes_and_elements():
    m = _model()
    d = cx.write_deck(m, "default")
    b = _blocks(d.text)
    nodes, elems = b["*NODE, NSET=Nall"], b["*ELEMENT, TYPE=C3D6, ELSET=Eall"]
    assert d.element == "C3D6"
    assert len(nodes) == d.nodes == m.shell.n_nodes == 2 * 63
    assert len(elems) == d.elements == len(m.shell.conn) == 80
    assert d.dofs == 3 * d.nodes and d.free_dofs == d.dofs - int(m.fixed.sum())
    # coordinates in the deck's length unit; the first element's nodes are ours, bottom then top
    xyz = {int(r.split(",")[0]): np.array([float(v) for v in r.split(",")[1:]]) for r in nodes}
    first = [int(v) for v in elems[0].split(",")[1:]]
    assert first == [int(i) + 1 for i in m.shell.conn[0]]
    X = np.array([xyz[i] for i in first]) * cx.LENGTH
    assert np.allclose(X, m.x0[m.shell.conn[0]], rtol=0, atol=1e-15)
    # ccx's wedge wants the bottom triangle counter-clockwise seen from the top (positive volume)
    assert np.dot(np.cross(X[1] - X[0], X[2] - X[0]), X[3] - X[0]) > 0


def test_quadratic_prisms_are_c3d15_without_the_face_centre_nodes():
    m = _model("quadratic")
    d = cx.write_deck(m, "default")
    b = _blocks(d.text)
    elems = b["*ELEMENT, TYPE=C3D15, ELSET=Eall"]
    assert d.element == "C3D15" and len(elems) == len(m.shell.conn)
    row = [int(v) - 1 for v in elems[0].split(",")[1:]]
    assert len(row) == 15
    X = m.x0[row]
    # corners 1-6 at the skins, 7-12 mid-edges of the skins, 13-15 mid-height of the corners
    h = m.shell.thickness.mean()
    assert np.allclose(X[:3, 2], -h / 2) and np.allclose(X[3:6, 2], h / 2)
    assert np.allclose(X[6:9], (X[[0, 1, 2]] + X[[1, 2, 0]]) / 2)
    assert np.allclose(X[9:12], (X[[3, 4, 5]] + X[[4, 5, 3]]) / 2)
    assert np.allclose(X[12:15], (X[:3] + X[3:6]) / 2)
    # the mid-layer edge nodes (face centres) are in no element, so not written
    n_plane = m.shell.n_plane
    assert d.nodes == m.shell.n_nodes - (n_plane - m.shell.n_vertices)


def test_the_clamp_the_material_and_the_load_in_the_same_steps():
    m = _model()
    d = cx.write_deck(m, "default")
    b = _blocks(d.text)
    held = {(int(r.split(",")[0]) - 1, int(r.split(",")[1]) - 1) for r in b["*BOUNDARY"]}
    assert held == {(int(i), int(c)) for i, c in zip(*np.nonzero(m.fixed), strict=True)}
    mat = m.scene.material
    mu, K = mat.E / (2 * (1 + mat.nu)), mat.E / (3 * (1 - 2 * mat.nu))
    c10, d1 = (float(v) for v in b["*HYPERELASTIC, NEO HOOKE"][0].split(","))
    assert c10 == pytest.approx(mu / 2, rel=1e-12) and d1 == pytest.approx(2 / K, rel=1e-12)
    # the density times gravity is the same body force in the deck's units (N/m^3 -> FORCE/L^3)
    rho = float(b["*DENSITY"][0])
    steps = re.findall(r"\*STEP, NLGEOM.*?\*END STEP", d.text, re.S)
    assert len(steps) == d.steps == m.scene.stepping.steps == 4
    for k, step in enumerate(steps, 1):
        assert "*STATIC, DIRECT\n1., 1." in step  # one increment per step: one of our steps
        grav = re.search(r"Eall, GRAV, (.*)", step)[1].split(",")
        g, direction = float(grav[0]), [float(v) for v in grav[1:]]
        assert direction == [0.0, 0.0, -1.0]
        body = rho * g * cx.FORCE / cx.LENGTH ** 3
        assert body == pytest.approx(mat.density * 9.81 * k / 4, rel=1e-12)
        assert "*CONTROLS" not in step


def test_matched_and_strict_controls_carry_our_force_level_and_tolerance():
    m = _model(**{"solver.rtol": 1e-4})
    level = float(np.linalg.norm(m.external.f))
    for setting, r in (("matched", 1e-4), ("strict", 1e-4 / np.sqrt(cx.write_deck(
            m, "default").free_dofs))):
        d = cx.write_deck(m, setting)
        lines = re.findall(r"\*CONTROLS, PARAMETERS=FIELD\n(.*)", d.text)
        assert len(lines) == 4
        for k, line in enumerate(lines, 1):
            rn, cn, q0, qu, rp, eps, ceps, rl = line.split(",")
            assert q0 == ""  # the initial average force: ccx's default
            assert float(qu) * cx.FORCE == pytest.approx(level * k / 4, rel=1e-12)
            assert float(rn) == float(rp) == float(rl) == pytest.approx(r, rel=1e-12)


def test_every_number_fits_ccx_s_20_character_field():
    """ccx misread a 22-character D1 (2.4000000000000004E-09) as another value and the sheet
    came out 4.5 times too soft; no field of any deck may be longer than 20 characters."""
    for element in ("linear", "quadratic"):
        text = cx.write_deck(_model(element, **{"material.nu": 0.3}), "strict").text
        fields = [f.strip() for line in text.splitlines() if not line.startswith("*")
                  for f in line.split(",")]
        assert max(map(len, fields)) <= 20


def test_a_scene_the_deck_cannot_carry_is_refused_naming_the_field():
    with pytest.raises(ValueError, match="element 'q3t' has no CalculiX counterpart"):
        cx.write_deck(_model("q3t"))
    with pytest.raises(ValueError, match="material.model"):
        cx.write_deck(_model(**{"material.model": "hencky"}))
    with pytest.raises(ValueError, match="stepping.release"):
        cx.write_deck(_model(**{"stepping.release": True}))
    with pytest.raises(ValueError, match="setting: unknown 'loose'"):
        cx.write_deck(_model(), "loose")


def test_the_sta_cvg_and_dat_of_a_converged_run():
    folder = DATA / "linear-matched"
    sta = cx.parse_sta((folder / "job.sta").read_text())
    assert [(i.step, i.increment, i.attempt, i.iterations) for i in sta] == [
        (s, 1, "1", 3) for s in (1, 2, 3, 4)]
    cvg = cx.parse_cvg((folder / "job.cvg").read_text())
    assert len(cvg) == 12 and [c.iteration for c in cvg[:3]] == [1, 2, 3]
    assert cvg[0].correction_pct == 100.0  # the first correction is the whole increment
    # the sample converged at R_n = 1e-4: its last residual of each step is below 1e-2 %
    ends = [c for c in cvg if c.iteration == 3]
    assert all(c.residual_pct <= 1e-2 for c in ends)
    blocks = cx.parse_dat_displacements((folder / "job.dat").read_text())
    assert [t for t, _ in blocks] == [1.0, 2.0, 3.0, 4.0]
    assert sorted(blocks[-1][1]) == [62, 125]
    assert blocks[-1][1][125][2] == pytest.approx(-99.87160)


def test_a_converged_run_read_back_against_its_deck():
    m = _model(**{"solver.rtol": 1e-4})
    d = cx.write_deck(m, "matched")
    folder = DATA / "linear-matched"
    assert d.tip_nodes == [62, 125]  # the sample is this deck's run
    r = cx.read_run(folder, d, 1.0, 0, (folder / "ccx.log").read_text())
    assert r.iterations == 12 and r.per_step == [3, 3, 3, 3] and r.attempts == 4
    # the tip is the mid-surface (the mean of the skins), in metres
    assert r.tip[-1] == pytest.approx(-0.5 * (99.85761 + 99.87160) * cx.LENGTH, rel=1e-12)
    assert r.threads >= 1


def test_a_run_ccx_gave_up_on_is_an_error_with_its_words():
    d = cx.write_deck(_model(), "matched")
    folder = DATA / "linear-rtol1e-8"
    sta = cx.parse_sta((folder / "job.sta").read_text())
    assert [(i.attempt, i.iterations) for i in sta] == [("1U", 11)]
    with pytest.raises(cx.CalculixError, match="0 increments converged.*diverge"):
        cx.read_run(folder, d, 1.0, 201, (folder / "ccx.log").read_text())

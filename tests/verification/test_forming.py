"""Forming with rigid tools, measured: the beam's springback per element, the cookie cutter's
shear at the strip edges, the cup's volume, punch force and thickness stages, the linear prism's
failure where Q3T completes the stroke, a flange wrinkling without a blank holder, a
force-controlled blank holder on its stop."""

import functools

import numpy as np
import pytest

from sim.scene.load import load_scene
from sim.stepping.simulation import Simulation
from tests.support.scenes import probe_series

pytestmark = pytest.mark.fast  # make test-fast runs all but the tests marked slow

T = 0.002


@functools.cache
def beam(element: str) -> Simulation:
    """beam_forming as shipped (2.5 mm edges, 24 steps, then release)."""
    sim = Simulation.from_scene(load_scene("scenes/beam_forming.toml",
                                           {"shell.element": element}))
    sim.run()
    return sim


@pytest.mark.slow
def test_beam_springs_back_more_with_linear_prisms():
    """Paper Fig. 1: the beam is bent into the closed mold (mid-surface radius 100 mm) and
    released with only its rigid motion held. In the mold all three elements have the mold's
    curvature; after release Q3T tracks the quadratic reference and linear prisms, locked in
    bending, store mostly elastic strain and spring back. Measured (2.5 mm mesh): curvature
    10.0 1/m in the mold; after release 8.84 (Q3T), 8.96 (quadratic), 1.75 (linear); largest
    distance from the mold shape 0.28, 0.32 and 10.3 mm."""
    sims = {e: beam(e) for e in ("linear", "q3t", "quadratic")}
    formed, after = {}, {}
    for e, sim in sims.items():
        assert sim.result()["converged"] and len(sim.records) == 25, (e, sim.failure)
        formed[e], after[e] = sim.records[-2].probes, sim.records[-1].probes
        # the closed mold leaves the mid-surface at 100 mm give or take the two contact
        # layers (20 um): 0.1 % of curvature, plus the fit of the 21 vertices along x
        assert formed[e]["curvature"] == pytest.approx(10.0, rel=2e-3)
        assert formed[e]["springback"] == 0.0  # no reference before the release
        assert sims[e].records[-1].tools == {}  # both tools retracted
    f = np.array([r.probes["punch_force"] for r in sims["q3t"].records[:-1]])
    assert np.all(np.diff(f) > 0)  # the punch force rises over the stroke (23 N to 15.9 kN)
    q, ref, lin = after["q3t"], after["quadratic"], after["linear"]
    assert q["curvature"] == pytest.approx(ref["curvature"], rel=0.03)
    assert q["springback"] == pytest.approx(ref["springback"], rel=0.25)
    assert lin["springback"] > 10 * ref["springback"]
    assert lin["curvature"] < 0.5 * ref["curvature"]


@pytest.mark.slow
def test_cookie_cutter_linear_prisms_shear_at_the_strip_edges():
    """Paper Fig. 13 on the 3 mm mesh: the band is pressed into the die's 5 valleys (the
    punch nests there at the end of the stroke, the band taut over the tips). Linear prisms
    shear excessively towards the boundaries of the strip, Q3T bends it: the largest fibre
    tilt on the rims is 43.1 deg for linear against 9.5 for Q3T (30.5 and 8.7 at mid-height);
    linear then springs back 6.3 mm, Q3T 0.21 mm. (2 mm mesh: 45.8 against 5.2 deg, 7.5
    against 0.22 mm.)"""
    out = {}
    for e in ("q3t", "linear"):
        sim = Simulation.from_scene(load_scene("scenes/cookie_cutter.toml", {
            "shell.element": e, "mesh.edge_length": 0.003}))
        assert sim.run() and len(sim.records) == 25, (e, sim.failure)
        nodes = [r.probes["die_contact_nodes"] for r in sim.records[:-1]]
        assert nodes[0] > 0 and nodes[-1] > 40  # on the tips at rest, wrapped at the end
        end = sim.records[-2].probes
        # pressed into the valley: the band at 36 deg has moved from r = 35.46 mm to the
        # punch's nest (valley arc centre 24.52 mm + 1 % t, less the punch radius and t / 2);
        # the probe's vertex may sit half a node spacing (1.5 mm) off the bisector, on the
        # band's arc of radius 3.5 mm around the punch: 3.5 (1 - cos(1.5 / 3.5)) = 0.32 mm less
        nest = 0.035463 - (0.024529 - 0.0035)
        if e == "q3t":
            assert end["valley_depth"] == pytest.approx(nest, abs=4e-4)
        else:  # thinned to 0.65 mm, the band does not fill the 1 mm gap at the nest
            assert nest - 1e-3 < end["valley_depth"] < nest
        out[e] = (end, sim.records[-1].probes)
    (q, q_rel), (lin, lin_rel) = out["q3t"], out["linear"]
    assert lin["rim_fibre_tilt"] > 3 * q["rim_fibre_tilt"]
    assert lin["rim_fibre_tilt"] > 1.3 * lin["middle_fibre_tilt"]  # at the edges most
    assert q["rim_fibre_tilt"] < 15.0
    assert lin_rel["springback"] > 10 * q_rel["springback"]


@functools.cache
def cup(element: str, edge: float = 0.002) -> Simulation:
    """The cup as shipped (2 mm edges, 25 mm stroke in 50 steps) or coarser."""
    if (element, edge) == ("q3t_ans", 0.002):  # the shipped scene's: its run shared with others
        from tests.support.scenes import shipped_cup

        return shipped_cup()[0]
    sim = Simulation.from_scene(load_scene("scenes/cup_drawing.toml", {
        "shell.element": element, "mesh.edge_length": edge}))
    sim.run()
    return sim


@pytest.mark.slow
def test_cup_volume_force_and_thickness():
    """The shipped cup (2 mm mesh, q3t_ans). Measured (2026-12-07): volume within 6e-4; punch
    force peaking at 21.06 kN at 10.5 mm of stroke and falling; thinnest 0.920 mm; the flange
    drawn in by 12.4-12.9 mm."""
    sim = cup("q3t_ans")
    assert sim.result()["converged"], sim.failure
    p = probe_series(sim)
    v0 = float(np.sum(sim.model.elasticity.wdetJ))
    assert np.abs(p["volume"] / v0 - 1).max() < 0.01  # isochoric plastic flow
    f = p["punch_force"]
    peak = int(np.argmax(f))
    assert 0 < peak < len(f) - 5  # rises, peaks, then falls as the flange is drawn in
    assert f[-1] < 0.8 * f[peak]
    # tearing bound pi d_punch t UTS (22.8 kN), UTS of AA5754-O ~ 220 MPa. q3t_ans peaks at
    # 21.1 kN at 2 mm, the quadratic prism at 18.1 (2026-12-07). Q3T's peak fell with the
    # mesh: 21.9 kN (4 mm), 23.0 (3 mm, whose peak comes late, at 14.7 mm: the coarse rings
    # catching on the 5 mm die shoulder), 20.8 (2.5 mm), 20.6 (2 mm), 19.8 (1.5 mm); contact
    # stiffness x0.25 .. x4 moves it by 0.3 %, friction 0.1 adds 2.4 kN, the holder force
    # (3 vs 1.5 kN) 0.2 kN. So the bound is checked at the shipped 2 mm.
    assert f.max() < np.pi * 0.033 * 0.001 * 220e6
    # Fig. 10 stages: thinning at the punch radius, thickening of the flange under compression
    h_min = p["min_thickness"]
    # contact chatter moves the thinnest node by ~1 um between steps: the trend is what counts
    assert np.all(np.diff(h_min) < 5e-6)
    # how thin: the quadratic prism on this mesh ends at 0.908 mm, Q3T on the paper's 0.5 mm
    # mesh at 0.926 (docs/results/forming-cup_elements-2mm.md, forming-cup_drawing-paper.md):
    # between the two, to 1 %; Q3T on this mesh thins to 0.804 mm, its one-point rule's noise
    assert 0.90e-3 < h_min[-1] < 0.935e-3
    assert p["max_thickness"][-1] > 1.1e-3
    assert p["punch_penetration"].max() <= 0.01 * 0.001  # the documented bound: 1 % of t
    # cup height: while the flange lies on the die (rim at the die's top, z = 0) it follows
    # the punch; drawn in, the rim goes down into the die and the wall is what is left
    travel = -p["centre_dz"]
    assert abs(p["cup_height"][29] - travel[29]) < 1e-3
    assert p["cup_height"][-1] < travel[-1] - 3e-3
    assert p["flange_draw_in"][-1] > 0.01  # the blank edge has moved in by more than 10 mm


@pytest.mark.slow
def test_cup_rim_thickens_then_is_ironed_to_the_gap():
    """Drawn in from r0 = 30 mm to r, the free rim is compressed in hoop only (no radial
    stress at the edge), so volume constancy gives t = t0 (r0 / r)^(1/2): 1.32 mm at the
    rim's 17.2 mm. At the end of the stroke the rim is in the punch-die gap (1.2 mm) or on the
    last millimetre of the die's shoulder, and ironed: no rim point thicker than the gap where
    it is, plus the two contact layers (the documented penetration bound, 1 % of t on each
    side); the quadratic prism on this mesh irons the whole rim to 1.200-1.207 mm, Q3T's rim
    pokes 0.049 mm past its gap. The rim's mean within 3 % of the quadratic prism's 1.205 mm
    (q3t_ans 1.176, its rim's six waves on the disk's lattice; Q3T 1.264; measured 2026-12-07:
    ring means along the radius differ from the quadratic's by at most 2.5 % (q3t_ans) and 5 %
    (Q3T))."""
    from sim.frames import fields

    sim = cup("q3t_ans")
    # an isotropic sheet has no ears: the rim's spread is the disk's lattice (six waves of
    # 1.05 mm against a four-fold 0.03 mm), which the summary flags as the mesh's
    summary = {e["name"]: e for e in sim.result()["summary"]}
    assert summary["earing"]["flag"] == "mesh"
    m, x = sim.model, sim.x
    V = m.shell.mesh.vertices
    rim = np.hypot(V[:, 0], V[:, 1]) > 0.0295
    h = fields.thickness(m, x)[rim]
    mid = fields.mid_surface(m, x)[rim]
    free_edge = 1e-3 * np.sqrt(0.03 / np.hypot(mid[:, 0], mid[:, 1]).mean())
    assert h.max() < free_edge
    assert abs(h.mean() / 1.205e-3 - 1) < 0.03
    # the die's opening (radius 17.7 mm) and its 5 mm shoulder from z = -0.5 mm down to -5.5
    dz = np.clip(mid[:, 2] + 5.5e-3, 0.0, 5e-3)
    gap = 22.7e-3 - np.sqrt(25e-6 - dz**2) - 16.5e-3
    assert (gap < 1.25e-3).sum() > rim.sum() / 2  # most of the rim is in the gap
    assert np.all(h <= gap + 2 * 0.01e-3)


@pytest.mark.slow
def test_cup_section_shows_thinning_then_thickening():
    """Paper Fig. 10 along the radial section of cup_drawing, each stage where it happens:
    (1) at 5 mm of stroke the blank bent over the punch nose has thinned slightly while the
    flange has not thickened yet (measured 2026-12-07: 0.970 mm at rest radius 12 mm, the
    flange at most 1.008 mm); (2) the flange thickens under hoop compression (1.084 mm at 15
    mm, 1.188 mm at 20 mm). The thinnest point over the punch radius ends at 0.941 mm. The
    third stage, the thickened rim ironed to the punch-die gap, is the rim's test above: on
    this ray (+x, where the disk mesh's six waves leave the rim highest) the rim has not
    reached the gap's straight part at 25 mm."""
    sec = cup("q3t_ans").sections["radial"]
    assert [s["step"] for s in sec] == [0, 10, 20, 30, 40, 50]
    h = np.array([s["thickness"] for s in sec])
    r = np.array([s["radius"] for s in sec])
    r0 = np.array(sec[0]["rest_radius"])
    assert np.allclose(h[0], 1e-3, rtol=1e-9)
    # stage 1 at 5 mm: the thinnest point lies on the punch nose (r 11.5 - 16.5 mm), slightly
    # thinned, and no point has thickened by 2 % yet
    k = int(np.argmin(h[1]))
    assert 0.95e-3 < h[1, k] < 0.98e-3 and 0.0115 < r[1, k] < 0.0165
    assert h[1].max() < 1.02e-3
    assert h[-1].min() < 0.95e-3  # and it stays thinned
    # stage 2: the compressed flange (rest r > 20 mm) thickens by more than 5 %
    assert h[:4, r0 > 0.02].max() > 1.05e-3


@pytest.mark.slow
def test_linear_prisms_fail_where_q3t_completes_the_stroke():
    """The paper's Fig. 11 on the 3 mm mesh. Q3T completes the stroke: every one of the 50
    steps converges and the punch reaches 25 mm. Linear prisms converge too, but relieve the
    volumetric constraint by shearing instead of bending, and the rule that tells them apart
    is all three symptoms at the end of the stroke, each against Q3T on the same mesh:
    * fibre tilt (largest angle between the through-thickness fibres and the deformed
      mid-surface normal) above 60 deg, Q3T below 25 deg (measured 76.8 against 19.5);
    * the sheared wall necks: minimum thickness below 60 % of Q3T's (measured 0.34 mm
      against 0.64 mm);
    * so the flange is hardly drawn in: draw-in of the blank edge below half of Q3T's
      (measured 2.4 mm against 12.2 mm)."""
    q3t, lin = cup("q3t", 0.003), cup("linear", 0.003)
    res = q3t.result()
    assert res["converged"] and len(q3t.records) == 50, q3t.failure
    assert np.isclose(q3t.tool_poses()["punch"][2], 0.0005 - 0.025, atol=1e-12)
    assert lin.result()["converged"], lin.failure
    p, pl = q3t.records[-1].probes, lin.records[-1].probes
    assert p["max_fibre_tilt"] < 25.0 and pl["max_fibre_tilt"] > 60.0
    assert pl["min_thickness"] < 0.6 * p["min_thickness"]
    # draw-in: the blank edge moves inwards (negative x displacement)
    assert pl["flange_draw_in"] < 0.5 * p["flange_draw_in"]


@pytest.mark.slow
def test_flange_wrinkles_without_blank_holder():
    """Paper Fig. 12: without the holder the compressed flange lifts and buckles out of plane.
    Compared at 7.5 mm of stroke (step 15 of 50), while the outer flange (rest r > 24 mm) is
    still a flange: measured 2.6 mm without the holder, 0.15 mm with it (3 mm mesh). Later the
    region is drawn into the wall in both runs and the measure no longer applies."""
    held = cup("q3t", 0.003).records[14].probes["flange_height_spread"]
    free = Simulation.from_scene(load_scene("scenes/cup_wrinkling.toml", {
        "mesh.edge_length": 0.003, "stepping.steps": 15, "tools.0.velocity": [0, 0, -0.0075]}))
    assert free.run(), free.failure
    loose = free.records[-1].probes["flange_height_spread"]
    assert loose > 5 * held and loose > 1e-3


@pytest.mark.slow
def test_force_controlled_blank_holder_holds_its_force_then_rests_on_its_stop():
    """The holder's height is solved with the sheet: while it is off its stop the sheet
    pushes back with the set force, friction included (it is coupled to the holder's height),
    it rises as the flange thickens, and once the flange has been drawn in it rests on its
    stop (3 mm mesh: lifted 0.46 mm by step 30)."""
    recs = cup("q3t", 0.003).records
    force = np.array([r.probes["holder_force"] for r in recs])
    z = np.array([r.probes["holder_height"] for r in recs])
    stop = 0.0005 - 0.0001
    off = z > stop + 1e-6
    assert off[:30].all() and not off[-1]
    # 1e-3: Newton may stop on a correction below 1e-6 t, at which the holder's stiffness
    # (all contact springs in series, ~1e11 N/m) leaves up to ~1 N unbalanced
    assert np.allclose(force[off], 3000.0, rtol=1e-3)
    assert z[29] > z[0] + 3e-4  # lifted by the thickening flange
    assert force[-1] == 0.0 and np.isclose(z[-1], stop, atol=1e-6)

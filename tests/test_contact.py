"""Tools and contact through the whole solver: load transfer, the penetration bound, Coulomb
friction, and the deep-drawn cup (volume, punch force, thickness stages, linear-prism shear)."""

import functools

import numpy as np
import pytest

from sim.scene import load_scene, scene_from_dict
from sim.simulation import Simulation

T = 0.002


def sheet_on_ground(mu: float, slide: float) -> Simulation:
    """A 40 x 40 x 2 mm sheet on a ground plane under a 10 kPa pressure (16 N in all)."""
    raw = {"name": "sheet", "mesh": {"kind": "rectangle", "size": [0.04, 0.04],
                                     "edge_length": 0.005, "origin": [-0.02, -0.02]},
           "shell": {"thickness": T, "element": "q3t"},
           "material": {"model": "neo_hookean", "E": 1e8, "nu": 0.3},
           "regions": [{"name": "centre", "box": {"min": [-0.001, -0.001, -1],
                                                  "max": [0.001, 0.001, 1]}},
                       {"name": "edge", "plane": {"point": [-0.02, 0, 0],
                                                  "normal": [1, 0, 0]}}],
           "bcs": ([{"region": "edge", "components": "xy", "displacement": [slide, 0, 0]}]
                   if slide else [{"region": "centre", "components": "xy"}]),
           "loads": [{"kind": "pressure", "value": 1e4}],
           "tools": [{"name": "ground", "friction": mu,
                      "shape": {"kind": "plane", "point": [0, 0, -T / 2], "normal": [0, 0, 1]}}],
           "stepping": {"steps": 4},
           "probes": [{"name": "fz", "kind": "tool_force", "tool": "ground", "component": "z"},
                      {"name": "fx", "kind": "tool_force", "tool": "ground", "component": "x"},
                      {"name": "pen", "kind": "penetration", "tool": "ground"}]}
    return Simulation.from_scene(scene_from_dict(raw))


def test_pressed_sheet_transfers_the_load_without_penetrating():
    sim = sheet_on_ground(0.0, 0.0)
    assert sim.run(), sim.failure
    for rec in sim.records:
        assert set(rec.tools["ground"]) == {"fx", "fy", "fz", "contact_nodes", "penetration", "z"}
        tool = rec.tools["ground"]
        assert tool["fz"] == rec.probes["fz"] and tool["contact_nodes"] > 0
        # the plane carries the applied pressure resultant (Newton's rtol 1e-8 of the load)
        assert np.isclose(rec.probes["fz"], -1e4 * 0.04**2 * rec.time, rtol=1e-6)
        assert rec.probes["pen"] <= 0.01 * T  # documented bound: 1 % of the thickness
    assert "contact:ground" in sim.model.built["terms"]


def test_dragged_sheet_needs_mu_times_the_normal_force():
    """Friction lags the normal force by one step (IPC-style), so the drag of step k is mu
    times the normal force of step k - 1 once the sheet slides."""
    mu = 0.3
    sim = sheet_on_ground(mu, 0.005)
    assert sim.run(), sim.failure
    fz = [r.probes["fz"] for r in sim.records]
    fx = [r.probes["fx"] for r in sim.records]
    for k in (2, 3):
        # smoothing of the stick-slip transition below 1 % of t of slip: 1e-6 relative
        assert np.isclose(fx[k], -mu * fz[k - 1], rtol=1e-6)


def test_no_tools_no_contact_term():
    sim = Simulation.from_scene(load_scene("scenes/cantilever.toml",
                                           {"mesh.edge_length": 0.035}))
    assert not any(t.startswith("contact") for t in sim.model.built["terms"])


@functools.cache
def cup(element: str, edge: float = 0.002) -> Simulation:
    """The cup as shipped (2 mm edges, 25 mm stroke in 50 steps) or coarser."""
    sim = Simulation.from_scene(load_scene("scenes/cup_drawing.toml", {
        "shell.element": element, "mesh.edge_length": edge}))
    sim.run()
    return sim


@pytest.mark.slow
def test_cup_volume_force_and_thickness():
    sim = cup("q3t")
    assert sim.result()["converged"], sim.failure
    p = {k: np.array([r.probes[k] for r in sim.records]) for k in sim.records[0].probes}
    v0 = float(np.sum(sim.model.elasticity.wdetJ))
    assert np.abs(p["volume"] / v0 - 1).max() < 0.01  # isochoric plastic flow
    f = p["punch_force"]
    peak = int(np.argmax(f))
    assert 0 < peak < len(f) - 5  # rises, peaks, then falls as the flange is drawn in
    assert f[-1] < 0.8 * f[peak]
    # tearing bound pi d_punch t UTS, UTS of AA5754-O ~ 220 MPa (measured peak 21.6 kN of
    # 22.8; the 3 mm mesh overshoots to 23.0 kN, so the bound is checked at the shipped 2 mm)
    assert f.max() < np.pi * 0.033 * 0.001 * 220e6
    # Fig. 10 stages: thinning at the punch radius, thickening of the flange under compression
    h_min = p["min_thickness"]
    # contact chatter moves the thinnest node by ~1 um between steps: the trend is what counts
    assert h_min[-1] < 0.9e-3 and np.all(np.diff(h_min) < 5e-6)
    assert p["max_thickness"][-1] > 1.1e-3
    assert p["punch_penetration"].max() <= 0.01 * 0.001  # the documented bound: 1 % of t


@pytest.mark.slow
def test_cup_section_shows_the_three_thickness_stages():
    """Paper Fig. 10 along the radial section of cup_drawing: thinning over the punch radius,
    thickening of the flange under compression, and ironing of that thickened wall to the
    punch-die gap (1.2 mm) as it passes through it. Measured: 0.934 mm at the punch radius; a
    flange point thickened to 1.263 mm at 20 mm of stroke is 1.191 mm inside the gap at 25 mm."""
    sec = cup("q3t").sections["radial"]
    assert [s["step"] for s in sec] == [0, 10, 20, 30, 40, 50]
    h = np.array([s["thickness"] for s in sec])
    r = np.array([s["radius"] for s in sec])
    assert np.allclose(h[0], 1e-3, rtol=1e-9)
    assert h[-1].min() < 0.95e-3  # stage 1: thinning at the punch radius
    assert h[:4].max() > 1.05e-3  # stage 2: the compressed flange thickens
    in_gap = (r[-1] > 0.0165) & (r[-1] < 0.0177)
    ironed = in_gap & (h.max(0) > 1.22e-3) & (h[-1] < 1.205e-3)  # stage 3
    assert ironed.any()


@pytest.mark.slow
def test_linear_prisms_shear_where_q3t_bends():
    """The paper's Fig. 11: linear prisms relieve the volumetric constraint by shearing. We
    tell them apart by the largest angle between the through-thickness fibres and the deformed
    mid-surface normal at the end of the stroke, on the 3 mm mesh: measured 17 deg for Q3T,
    81 deg for linear (on 2 mm Q3T shows 11 deg)."""
    q3t, lin = cup("q3t", 0.003), cup("linear", 0.003)
    assert q3t.records[-1].probes["max_fibre_tilt"] < 25.0
    assert lin.records[-1].probes["max_fibre_tilt"] > 60.0


@pytest.mark.slow
def test_flange_wrinkles_without_blank_holder():
    """Paper Fig. 12: without the holder the compressed flange lifts and buckles out of plane.
    Compared at 7.5 mm of stroke (step 15 of 50), while the outer flange (rest r > 24 mm) is
    still a flange: measured 2.6 mm without the holder, 0.15 mm with it (3 mm mesh). Later the
    region is drawn into the wall in both runs and the measure no longer applies."""
    held = cup("q3t", 0.003).records[14].probes["flange_wrinkle_amplitude"]
    free = Simulation.from_scene(load_scene("scenes/cup_wrinkling.toml", {
        "mesh.edge_length": 0.003, "stepping.steps": 15, "tools.0.velocity": [0, 0, -0.0075]}))
    assert free.run(), free.failure
    loose = free.records[-1].probes["flange_wrinkle_amplitude"]
    assert loose > 5 * held and loose > 1e-3


@pytest.mark.slow
def test_force_controlled_blank_holder_holds_its_force_then_rests_on_its_stop():
    """The holder's height is solved with the sheet: while it touches the flange the sheet
    pushes back with the set force, it
    rises as the flange thickens, and once the flange has been drawn in it rests on its stop."""
    recs = cup("q3t", 0.003).records
    force = np.array([r.probes["holder_force"] for r in recs])
    z = np.array([r.probes["holder_height"] for r in recs])
    touching = force > 1500.0
    assert touching[:30].all()
    # while the flange lies under the flat part of the holder (first 30 steps) the sheet alone
    # holds it up with the set force; later the flange edge slides over the holder's rounded
    # inner edge, where friction (not coupled to the holder's height, see terms/contact.py)
    # adds up to 2 % to the measured force
    # 1e-3: Newton may stop on a correction below 1e-6 t, at which the holder's stiffness
    # (all contact springs in series, ~1e11 N/m) leaves up to ~1 N unbalanced (measured 1.1 N)
    assert np.allclose(force[:30], 3000.0, rtol=1e-3)
    assert z[29] > z[0] + 3e-4  # lifted by the thickening flange (measured 0.45 mm)
    assert not touching[-1] and np.isclose(z[-1], 0.0005 - 0.0001, atol=1e-6)


def test_tool_follows_its_keyframes():
    """A punch path given as keyframes (down 2 mm by t = 0.5, held, up 1 mm by t = 1) is followed
    step by step."""
    sim = sheet_on_ground(0.0, 0.0)
    raw = sim.model.scene.model_dump()
    raw["tools"].append({"name": "punch", "position": [0.0, 0.0, 0.01],
                         "shape": {"kind": "punch", "radius": 0.005, "height": 0.02},
                         "keyframes": [[0.0, 0, 0, 0], [0.5, 0, 0, -0.002], [0.75, 0, 0, -0.002],
                                       [1.0, 0, 0, -0.001]]})
    sim = Simulation.from_scene(scene_from_dict(raw))
    z = []
    for _ in range(4):
        sim.step()
        z.append(sim.tool_poses()["punch"][2])
    assert np.allclose(z, [0.009, 0.008, 0.008, 0.009], atol=1e-12)
    with pytest.raises(Exception, match="times must increase"):
        raw["tools"][-1]["keyframes"] = [[0.5, 0, 0, 0], [0.2, 0, 0, 0]]
        scene_from_dict(raw)

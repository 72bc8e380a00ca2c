"""Implicit Euler against closed forms: free fall, and prescribed motion over time (the default
ramp and keyframes) with the support reaction it takes to move the sheet's mass."""

import numpy as np
import pytest

from sim.scene.load import SceneError, scene_from_dict
from sim.stepping.simulation import Simulation

pytestmark = pytest.mark.fast  # seconds: make test-fast runs it

RHO, SIDE, H = 1000.0, 0.1, 0.004
G = 9.81
# Prescribed-motion runs carry gravity: a strain-free motion with no load at all has no force
# scale, and Newton, started at round-off, then reports a stalled line search (reported to the
# Newton work; not what these tests are about)
GRAVITY = [{"kind": "gravity", "vector": [0, 0, -G]}]


def plate(**extra) -> dict:
    """A 10 x 10 cm, 4 mm Q3T plate of 8 triangles, dynamic at dt = 10 ms."""
    raw = {"name": "plate", "mesh": {"kind": "rectangle", "size": [SIDE, SIDE],
                                     "edge_length": 0.05},
           "shell": {"thickness": H, "element": "q3t"},
           "material": {"E": 1e6, "nu": 0.3, "density": RHO},
           "regions": [{"name": "all", "box": {"min": [-1, -1, -1], "max": [1, 1, 1]}}],
           "stepping": {"kind": "dynamic", "dt": 0.01, "steps": 10},
           "probes": [{"name": "rz", "kind": "reaction", "region": "all", "component": "z"},
                      {"name": "z", "kind": "displacement", "point": [0.05, 0.05, 0],
                       "component": "z"}]}
    raw.update(extra)
    return raw


def test_free_fall_follows_implicit_euler():
    """A free sheet under gravity: no strain, so every node obeys the implicit-Euler recurrence
    v_{n+1} = v_n + dt g, x_{n+1} = x_n + dt v_{n+1}, i.e. z_n = -g dt^2 n (n + 1) / 2."""
    g, dt = 9.81, 0.01
    sim = Simulation.from_scene(scene_from_dict(plate(
        loads=[{"kind": "gravity", "vector": [0, 0, -g]}], probes=[
            {"name": "z", "kind": "displacement", "point": [0.05, 0.05, 0], "component": "z"}])))
    assert sim.run(), sim.failure
    for k, rec in enumerate(sim.records, start=1):
        exact = -g * dt * dt * k * (k + 1) / 2
        # Newton stops at rtol 1e-8 of the load on a strain-free state: 1e-7 relative is
        # round-off plus that tolerance (measured 1.0e-11)
        assert rec.probes["z"] == pytest.approx(exact, rel=1e-7)
    u = sim.x - sim.model.x0
    assert np.abs(u - u.mean(0)).max() < 1e-9 * abs(u[:, 2]).max()  # a rigid translation


def test_default_ramp_is_linear_in_time():
    """Without load_ramp a prescribed displacement takes 1 s, linear in t (it used to jump to
    the full value in the first step); with load_ramp it takes that long."""
    bc = [{"region": "all", "components": "z", "displacement": [0, 0, 0.01]}]
    sim = Simulation.from_scene(scene_from_dict(plate(bcs=bc, loads=GRAVITY)))
    rec = sim.step()
    assert rec.probes["z"] == pytest.approx(0.01 * 0.01, rel=1e-12)
    raw = plate(bcs=bc, loads=GRAVITY)
    raw["stepping"] = {**raw["stepping"], "load_ramp": 0.05}
    sim = Simulation.from_scene(scene_from_dict(raw))
    sim.run()
    assert [r.probes["z"] for r in sim.records][3:] == pytest.approx(
        [0.008, 0.01, 0.01, 0.01, 0.01, 0.01, 0.01], rel=1e-12)


def test_keyframed_motion_and_the_inertia_it_costs():
    """The whole sheet moved in z along keyframes (x, y free, gravity): no strain, so z follows
    the piecewise-linear curve u(t) exactly, x and y stay at rest, and the support reaction is
    the implicit-Euler inertia force M (u_{n+1} - 2 u_n + u_{n-1}) / dt^2 of the total mass
    plus its weight."""
    kf = [[0.02, 0.002], [0.05, 0.002], [0.08, -0.001]]  # from rest at t = 0, held after 0.08
    sim = Simulation.from_scene(scene_from_dict(plate(
        bcs=[{"region": "all", "components": "z", "keyframes": kf}], loads=GRAVITY)))
    assert sim.run(), sim.failure
    dt = 0.01
    t = dt * np.arange(11)
    u = np.interp(t, [0.0] + [k[0] for k in kf], [0.0] + [k[1] for k in kf])
    z = np.array([r.probes["z"] for r in sim.records])
    assert np.abs(z - u[1:]).max() < 1e-15  # prescribed: exact
    assert np.abs(sim.x[:, :2] - sim.model.x0[:, :2]).max() < 1e-12
    mass = RHO * SIDE * SIDE * H
    accel = (u[2:] - 2 * u[1:-1] + u[:-2]) / dt**2
    accel = np.concatenate([[u[1] / dt**2], accel])  # from rest: u_{-1} = u_0 = 0
    rz = np.array([r.probes["rz"] for r in sim.records])
    # the reaction is the energy gradient summed over the held nodes: inertia (lumped masses
    # sum to M) plus the load's -f = M g; no strain, so no elastic part: round-off, 1e-9 of
    # the largest force
    exact = mass * (accel + G)
    assert np.abs(rz - exact).max() < 1e-9 * np.abs(exact).max()
    assert np.abs(accel).max() > 0


def test_static_keyframes_follow_scene_time():
    """Static stepping: keyframe times are the run's pseudo-time 0 -> 1."""
    raw = plate(bcs=[{"region": "all", "components": "xz", "keyframes": [[0.5, 0.0, 0.001],
                                                                         [1.0, 0.0, 0.0]]}],
                loads=GRAVITY)
    raw["stepping"] = {"kind": "static", "steps": 4}
    sim = Simulation.from_scene(scene_from_dict(raw))
    assert sim.run(), sim.failure
    assert [r.probes["z"] for r in sim.records] == pytest.approx([5e-4, 1e-3, 5e-4, 0.0],
                                                                 abs=1e-15)


@pytest.mark.parametrize("bc,message", [
    ({"components": "z", "keyframes": [[0.1, 0.0, 1.0]]}, "keyframes.0: needs [t, z]"),
    ({"components": "xz", "keyframes": [[0.2, 0.0, 0.0], [0.1, 0.0, 0.0]]}, "must increase"),
    ({"components": "z", "keyframes": [[-0.1, 0.0]]}, ">= 0"),
    ({"components": "z", "keyframes": [[0.0, 0.01]]}, "from rest"),
    ({"components": "z", "keyframes": [[0.1, 0.01]], "displacement": [0, 0, 1.0]}, "either"),
    ({"components": "zz"}, "twice"),
])
def test_bad_keyframes_name_the_field(bc, message):
    with pytest.raises(SceneError) as err:
        scene_from_dict(plate(bcs=[{"region": "all", **bc}]))
    assert "bcs.0" in str(err.value) and message in str(err.value)


def test_release_of_a_dynamic_run_is_static_springback():
    """A dynamic, elastic cantilever swinging under gravity is released: the release stage
    solves static equilibrium without the load, so the sheet comes back to rest (with the
    inertia kept it would take one more time step from where it was moving)."""
    raw = plate(loads=GRAVITY, probes=[{"name": "z", "kind": "displacement",
                                        "point": [0.1, 0.05, 0], "component": "z"}])
    raw["regions"] = [{"name": "left", "plane": {"point": [0, 0, 0], "normal": [1, 0, 0]}}]
    raw["bcs"] = [{"region": "left", "components": "xyz"}]
    raw["stepping"] |= {"steps": 3, "release": True}
    sim = Simulation.from_scene(scene_from_dict(raw))
    assert sim.run(), sim.failure
    swing = sim.records[-2].probes["z"]
    assert swing < -1e-4  # the tip fell under gravity during the steps
    # released, elastic, unloaded: back at rest to Newton's tolerance (rtol 1e-8 of the force
    # level, on a tip deflection of 1e-4 m or more: 1e-6 of it is generous)
    assert abs(sim.records[-1].probes["z"]) < 1e-6 * abs(swing)
    assert "inertia" not in [t.name for t in sim.model.problem.terms]

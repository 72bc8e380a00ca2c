"""Radial sections (sim.frames.fields.section_points / section): where the ray crosses the blank.
On the structured disk, whose spoke along +x is a line of vertices, they are those vertices;
on an unstructured blank (an outline's, a user's), which has almost none on any ray, the
points where the ray cuts the edges, values linear along each edge."""

from types import SimpleNamespace

import numpy as np
import pytest

from sim.frames import fields
from sim.scene.load import load_scene, scene_from_toml
from sim.stepping.simulation import Simulation
from tests.support import ROOT

# the outline cup has no section of its own (it had none before sections cut edges)
RAYS = "".join(f'\n[[sections]]\nname = "{n}"\ndirection = {d}\nsteps = [0]\n'
               for n, d in (("x", "[1.0, 0.0]"), ("diagonal", "[1.0, 1.0]")))


def model(name: str, edge: float, extra: str = ""):
    text = (ROOT / "scenes" / f"{name}.toml").read_text() + extra
    sc = scene_from_toml(text, {"mesh.edge_length": edge, "stepping.steps": 1}, ROOT / "scenes")
    return Simulation.from_scene(sc).model


def test_on_the_disk_the_section_is_its_spokes_vertices():
    m = model("cup_drawing", 0.006)
    spec = load_scene(ROOT / "scenes" / "cup_drawing.toml").sections[0]
    pairs, t = fields.section_points(m, spec)
    V = m.shell.mesh.vertices
    on = np.flatnonzero((np.abs(V[:, 1]) <= spec.width) & (V[:, 0] >= 0))
    assert np.all(t == 0) and np.array_equal(pairs[:, 0], pairs[:, 1])
    assert np.array_equal(pairs[:, 0], on[np.argsort(V[on, 0])])


@pytest.mark.parametrize("which", ["x", "diagonal"])
def test_on_an_unstructured_blank_the_section_runs_from_the_centre_to_the_edge(which):
    m = model("cup_drawing_outline", 0.004, RAYS)
    spec = next(s for s in m.scene.sections if s.name == which)
    d = np.asarray(spec.direction) / np.linalg.norm(spec.direction)
    pairs, t = fields.section_points(m, spec)
    V = m.shell.mesh.vertices[:, :2]
    P = (1 - t)[:, None] * V[pairs[:, 0]] + t[:, None] * V[pairs[:, 1]]
    # on the ray: a cut exactly (round-off of the edge's parameter), a vertex within width
    assert np.all(np.abs(P[:, 0] * d[1] - P[:, 1] * d[0]) <= spec.width)
    r = P @ d
    # from the centre (a vertex of the mesh within one edge of it) to the outline, with no
    # gap wider than an edge of the 4 mm mesh (a cut on every triangle the ray crosses)
    assert r[0] < 0.004 and r[-1] == pytest.approx(0.03, abs=1e-4)
    assert np.all(np.diff(r) > 0) and np.diff(r).max() < 0.004 * 1.5
    assert len(r) > 0.03 / 0.004


def test_values_are_linear_along_the_cut_edges():
    """Fields linear in x (not radial, so weights that are wrong, swapped or not summing to one
    fail in section; wrong cut points fail the on-the-ray test above): every node lifted by
    c x, and the sheet's z scaled by 1 + a x. A cut point's height is then c x and its
    thickness t0 (1 + a x) at its own x, exactly."""
    m = model("cup_drawing_outline", 0.004, RAYS)
    x0 = m.x0
    c, a = 0.3, 5.0
    for spec in m.scene.sections:
        pairs, t = pts = fields.section_points(m, spec)
        V = m.shell.mesh.vertices
        px = (1 - t) * V[pairs[:, 0], 0] + t * V[pairs[:, 1], 0]
        assert np.any((t > 0.1) & (t < 0.9))  # cut points, not only vertices
        lifted = x0.copy()
        lifted[:, 2] += c * x0[:, 0]
        scaled = x0.copy()
        scaled[:, 2] *= 1 + a * x0[:, 0]
        assert np.allclose(fields.section(m, lifted, pts)["z"], c * px, rtol=0, atol=1e-15)
        assert np.allclose(fields.section(m, scaled, pts)["thickness"], 0.001 * (1 + a * px),
                           rtol=1e-12)
        rest = fields.section(m, x0, pts)
        assert np.allclose(rest["radius"], rest["rest_radius"], rtol=0, atol=1e-12)


def test_a_ray_that_misses_the_blank_is_named():
    """A blank that does not reach the origin's ray (a triangle beside it) has no section;
    the error says where the blank lies (a drawing in its own coordinates lies beside the
    cups' punch)."""
    mesh = SimpleNamespace(vertices=np.array([[0.01, 0.01, 0], [0.02, 0.01, 0], [0.01, 0.02, 0]]),
                           faces=np.array([[0, 1, 2]]))
    spec = SimpleNamespace(name="axis", direction=(1.0, 0.0), width=1e-4)
    with pytest.raises(ValueError, match=r"sections.axis: the ray from the origin along "
                       r"\[1.0, 0.0\] crosses the blank at fewer than two points: the blank "
                       "lies at x 10 mm to 20 mm, y 10 mm to 20 mm"):
        fields.section_points(SimpleNamespace(shell=SimpleNamespace(mesh=mesh)), spec)


def test_a_section_ends_at_the_last_step_made():
    """A section lists its steps for the scene as written; a run that ends before the last
    of them (stopped, its steps or tool speed changed) gets the step it ended at too, at
    that state, so the plot ends where the part is (a review's stopped run ended at step 50
    of 280). Listed steps the run made are kept as they are, the final one not repeated."""
    from tests.support.scenes import tiny_cup_toml

    text = tiny_cup_toml(3) + '\n[[sections]]\nname = "x"\ndirection = [1.0, 0.0]\n' \
        'steps = [0, 2, 5]\n'
    sim = Simulation.from_scene(scene_from_toml(text))
    for _ in range(3):
        sim.step()
    kept = [r["step"] for r in sim.sections["x"]]
    got = sim.recorded_sections()["x"]
    assert kept == [0, 2] and [r["step"] for r in got] == [0, 2, 3]
    final = fields.section(sim.model, sim.x, sim._sections["x"])
    assert got[-1]["thickness"] == final["thickness"] and got[-1]["time"] == sim.t
    assert {r["angle_deg"] for r in got} == {0.0}  # its ray's direction, for the plot's title
    assert [r["step"] for r in sim.sections["x"]] == [0, 2]  # the record itself unchanged
    # a run that made its last listed step: as recorded
    text = text.replace("steps = [0, 2, 5]", "steps = [0, 3]")
    sim = Simulation.from_scene(scene_from_toml(text))
    for _ in range(3):
        sim.step()
    assert [r["step"] for r in sim.recorded_sections()["x"]] == [0, 3]

"""The ``height_range`` probe without a region spans the whole mid-surface: how far a plate
leaves its plane (Fig. 4's stretched plate, docs/results/fig4.md)."""

import numpy as np

from sim.frames import probes
from sim.frames.fields import mid_surface
from sim.scene.load import load_scene
from sim.stepping.simulation import Simulation


def test_out_of_plane_is_the_height_range_of_the_whole_mid_surface():
    a = 1e-4  # the seed's amplitude (m): z += a sin(pi s) sin(pi t)
    scene = load_scene("scenes/stretch_plate.toml", {"mesh.edge_length": 0.07,
                                                     "mesh.imperfection": a})
    spec = next(p for p in scene.probes if p.name == "out_of_plane")
    assert spec.kind == "height_range" and spec.region is None
    sim = Simulation.from_scene(scene)
    z = mid_surface(sim.model, sim.x)[:, 2]
    rest = probes.evaluate(sim.model, sim.x)["out_of_plane"]
    assert rest == z.max() - z.min()  # every vertex, not a region's
    # the bump is 0 on the rim and a at the centre, a vertex of this 10 x 10 grid
    assert np.isclose(rest, a, rtol=1e-9)

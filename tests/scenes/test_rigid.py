"""The statically determinate support of a released part (sim.geometry.rigid): exactly one held DoF
per
rigid-body mode the scene leaves free, a regular Hessian with it, and no force in it once the
part has sprung back."""

import numpy as np
import pytest

from sim.elements import ROUTINE
from sim.geometry.rigid import determinate_support, free_modes, rigid_modes
from sim.model.build import build_model
from sim.scene.load import load_scene
from sim.stepping.simulation import Simulation
from tests.support.scenes import coarse


def _stiffness_eigenvalues(model, held):
    """Eigenvalues of the elastic Hessian at rest on the DoFs not held (dense: a small mesh)."""
    p = model.pattern
    data = np.zeros(p.nnz)
    model.elasticity.add_hessian(model.x0, data)
    K = p.matrix(data).toarray()
    free = np.flatnonzero(~held.ravel())
    return np.linalg.eigvalsh(K[np.ix_(free, free)])


def test_rigid_modes_are_the_null_space_of_the_elastic_hessian():
    """The six fields are rigid motions: the Hessian at rest maps each to zero (to round-off of
    its largest entries), and they are independent."""
    m = build_model(load_scene("scenes/cantilever.toml", {"mesh.edge_length": 0.1}))
    modes = rigid_modes(m.x0)
    p = m.pattern
    data = np.zeros(p.nnz)
    m.elasticity.add_hessian(m.x0, data)
    K = p.matrix(data).toarray()
    Km = K @ modes.reshape(-1, 6)
    # K u for a unit rigid field: round-off of sums of entries up to max|K|
    assert np.abs(Km).max() <= 1e-9 * np.abs(K).max()
    assert np.linalg.matrix_rank(modes.reshape(-1, 6)) == 6


def test_a_free_plate_gets_six_supports_and_a_regular_hessian():
    """Nothing held: six DoFs, after which the smallest stiffness is that of the plate (bending
    of the 0.7 m plate), not zero: without them six eigenvalues are round-off."""
    m = build_model(load_scene("scenes/cantilever.toml", {"mesh.edge_length": 0.1}))
    n = m.shell.n_nodes
    nothing = np.zeros((n, 3), bool)
    picked = determinate_support(m.x0, nothing, m.shell.layer_nodes(0))
    assert len(picked) == 6 and len(set(picked)) == 6
    held = nothing.copy()
    for node, c in picked:
        held[node, c] = True
    assert free_modes(rigid_modes(m.x0), held).shape[1] == 0
    loose, tight = _stiffness_eigenvalues(m, nothing), _stiffness_eigenvalues(m, held)
    # the free plate: six zero modes, at round-off of the largest stiffness (measured 3e-17 of
    # it), then the plate's softest bending mode, 1e-9 of the largest on this thin plate
    # (measured 4e7 times the largest of the six)
    zero = np.abs(loose[:6]).max()
    assert zero <= 1e-14 * loose[-1] and loose[6] > 1e6 * zero
    # held determinately: the soft end of the spectrum is the plate's own (its seventh
    # eigenvalue before); a support that missed a mode would leave one near zero
    assert tight[0] > 1e-3 * loose[6]


def test_supports_the_scene_gives_are_kept_and_only_the_free_modes_added():
    """beam_forming's release keeps plane strain, the symmetry plane and the centre's z: held.
    cookie_cutter's keeps u_z on the bottom rim and u_y on two lines: x is free, one support."""
    beam = Simulation.from_scene(coarse("scenes/beam_forming.toml", "q3t"))
    band = Simulation.from_scene(coarse("scenes/cookie_cutter.toml", "q3t"))
    for sim, expect in ((beam, []), (band, ["x"])):
        held = sim._release_supports()
        assert [s["component"] for s in sim.release_support] == expect
        assert free_modes(rigid_modes(sim.x[: sim.model.shell.n_nodes]),
                          held[: sim.model.shell.n_nodes]).shape[1] == 0


@pytest.mark.parametrize("element", ROUTINE)
def test_the_added_support_carries_no_force_after_springback(element, tmp_path):
    """The band springs back from the die's valleys; the support added in x holds a part in
    equilibrium, so it carries nothing but Newton's residual: measured 1e-9 N against punch
    forces of 1e2-1e3 N. It is reported in result.json with the node and its position."""
    sim = Simulation.from_scene(coarse("scenes/cookie_cutter.toml", element))
    assert sim.run(), sim.failure
    (s,) = sim.release_support
    forming = max(abs(r.probes["punch1_force"]) for r in sim.records[:-1])
    # Newton stops at rtol 1e-8 of the run's force level; 1e-6 of the punch force is far above
    # that and far below any real reaction
    assert abs(s["force"]) <= 1e-6 * forming
    sim.write(tmp_path)
    import json

    res = json.loads((tmp_path / "result.json").read_text())
    assert res["release_support"] == [s] and s["component"] == "x" and len(s["position"]) == 3

"""The anisotropic sheet in a scene: material.hill48's bad input named by field, the material
frames from the rest mid-surface, and the elasticity term's derivatives under Hill48."""

import numpy as np
import pytest

from sim.materials.hill import HILL48
from sim.model.build import build_model
from sim.scene.load import SceneError, load_scene
from tests.support.fd import fd_check_term

PLASTIC = {"material.model": "plastic", "material.yield_stress": 200e6,
           "mesh.edge_length": 0.035}
AA5754 = {"r0": 0.663, "r45": 0.860, "r90": 0.717}
RNG = np.random.default_rng(48)


def scene(hill: dict, **extra):
    return load_scene("scenes/cantilever.toml", {**PLASTIC, "material.hill48": hill, **extra})


@pytest.mark.parametrize("hill, extra, message", [
    ({**AA5754, "r0": 0.0, "rolling_angle": 0.0}, {}, "material.hill48.r0: Input should be"),
    ({**AA5754, "r45": -0.5, "rolling_angle": 0.0}, {}, "material.hill48.r45"),
    (AA5754, {}, "material.hill48: rolling_direction: missing"),
    ({**AA5754, "F": 0.5, "rolling_angle": 0.0}, {}, "give either r0, r45, r90 or F, G, H, N"),
    ({"F": 0.5, "G": 0.5, "H": 0.6, "N": 1.5}, {}, "material.hill48: G + H = 1.1 must be 1"),
    ({**AA5754, "rolling_angle": 0.0, "rolling_direction": [1.0, 0.0, 0.0]}, {},
     "give one of rolling_direction and rolling_angle"),
    ({**AA5754, "rolling_direction": [0.0, 0.0, 0.0]}, {}, "material.hill48.rolling_direction"),
    ({**AA5754, "L": 0.0, "rolling_angle": 0.0}, {}, "material.hill48.L"),
    ({"r0": 1.0, "r45": 1.0, "r90": 1.0}, {"material.model": "hencky"},
     "hill48: a yield criterion, for model 'plastic'"),
])
def test_bad_hill48_is_rejected_naming_the_field(hill, extra, message):
    o = {**PLASTIC, "material.hill48": hill, **extra}
    if extra.get("material.model") == "hencky":
        del o["material.yield_stress"]
    with pytest.raises(SceneError) as err:
        load_scene("scenes/cantilever.toml", o)
    assert message in str(err.value), str(err.value)


def test_rolling_direction_along_the_normal_is_rejected_at_build():
    with pytest.raises(ValueError, match=r"material\.hill48\.rolling_direction: parallel to the "
                                         r"sheet normal at \d+ element"):
        build_model(scene({**AA5754, "rolling_direction": [0.0, 0.0, 1.0]}))


def test_in_plane_isotropic_sheet_needs_no_rolling_direction():
    m = build_model(scene({"r0": 1.6, "r45": 1.6, "r90": 1.6}))
    assert m.elasticity.model == HILL48


def test_material_frames_follow_the_rolling_direction():
    """A vector with an out-of-plane part is projected on the flat sheet; rolling_angle is the
    same direction as a vector (cos, sin, 0)."""
    a = build_model(scene({**AA5754, "rolling_direction": [1.0, 1.0, 5.0]})).elasticity.frames
    b = build_model(scene({**AA5754, "rolling_angle": 45.0})).elasticity.frames
    r = np.sqrt(0.5)
    # rolling, transverse, normal (the cantilever's mid-surface is z = 0, normal +z or -z)
    np.testing.assert_allclose(a[:, :, 0], np.tile([r, r, 0.0], (len(a), 1)), atol=1e-15)
    np.testing.assert_allclose(abs(a[:, 2, 2]), 1.0, atol=1e-15)
    np.testing.assert_allclose(a, b, atol=1e-15)
    for f in a:
        np.testing.assert_allclose(f.T @ f, np.eye(3), atol=1e-15)


@pytest.mark.parametrize("element", ["q3t", "q3t_ans"])
def test_elasticity_term_fd_in_a_plastic_state(element):
    """Energy, gradient and Hessian of the element loop under Hill48, after a committed plastic
    step (Fp != I): central differences along random directions (tests/support/fd.py); for
    q3t_ans through its assumed strain (sim.terms.ans), the frames from the scene."""
    m = build_model(scene({**AA5754, "rolling_angle": 30.0}, **{
        "material.E": 20e9, "solver.hessian_projection": "none", "shell.element": element}))
    term = m.elasticity
    rest = m.shell.rest
    # 2 % stretch along x with a random part: beyond the yield strain 1 % (200 MPa / 20 GPa)
    x = rest * [1.02, 1.0, 1.0] + 1e-4 * RNG.standard_normal(rest.shape)
    term.commit(x)
    assert term.ep.max() > 0.0
    x = x + 2e-4 * RNG.standard_normal(rest.shape)

    fd_check_term(term, m.pattern, x, 1e-3, RNG)

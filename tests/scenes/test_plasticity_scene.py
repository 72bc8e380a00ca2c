"""Scene validation of the plastic material: every hardening parameter out of range, missing, or
belonging to another law is an error that names the field; nothing is silently ignored."""

import numpy as np
import pytest

from sim.model.terms import material_params
from sim.scene.load import SceneError, load_scene

PLASTIC = {"material.model": "plastic", "material.yield_stress": 200e6}


def material(hardening: dict | None = None, **extra):
    o = {**PLASTIC, **extra}
    if hardening is not None:
        o["material.hardening"] = hardening
    return load_scene("scenes/cantilever.toml", o).material


@pytest.mark.parametrize("hardening, extra, field", [
    # K = 0 was a zero flow stress
    ({"law": "swift", "n": 0.2}, {}, "material.hardening.K: Field required"),
    ({"law": "swift", "K": 0.0, "n": 0.2}, {}, "material.hardening.K"),
    ({"law": "swift", "K": 5e8, "n": 0.2, "e0": 0.0}, {}, "material.hardening.e0"),  # was 1/0
    ({"law": "swift", "K": 5e8, "n": -0.1}, {}, "material.hardening.n"),
    ({"law": "swift", "K": 5e8, "n": 0.2, "e0": 0.01}, {}, "hardening.e0: K e0^n"),
    ({"law": "swift", "K": 5e8, "n": 0.0}, {}, "hardening.K: with n = 0"),
    ({"law": "swift", "K": 1e8, "n": 1e-300}, {}, "not a positive finite strain"),  # overflow
    ({"law": "swift", "K": 5e8, "n": 1e-300}, {}, "not a positive finite strain"),  # underflow
    # Ysat = 0 softened to zero
    ({"law": "voce", "rate": 20.0}, {}, "material.hardening.saturation: Field required"),
    ({"law": "voce", "saturation": 1e8, "rate": 20.0}, {}, "hardening.saturation"),
    ({"law": "voce", "saturation": 4e8, "rate": -1.0}, {}, "material.hardening.rate"),
    ({"law": "voce", "saturation": 4e8}, {}, "material.hardening.rate: Field required"),
    ({"law": "linear", "modulus": -1e12}, {}, "material.hardening.modulus"),
    ({"law": "linear"}, {}, "material.hardening.modulus: Field required"),
    ({"law": "perfect", "modulus": 2e9}, {},
     "material.hardening.modulus: not a field of law 'perfect'"),
    ({"rate": 20.0}, {}, "material.hardening: give its law"),
    ({"law": "linear", "modulus": 2e9, "K": 5e8}, {},
     "material.hardening.K: not a field of law 'linear' (it takes modulus)"),
    (None, {"material.yield_stress": 0.0}, "material.yield_stress"),
    (None, {"material.yield_stress": float("nan")}, "material.yield_stress"),
    (None, {"material.E": float("inf")}, "material.E"),
    (None, {"material.model": "hencky"}, "yield_stress: only used by model 'plastic'"),
])
def test_bad_hardening_is_rejected_naming_the_field(hardening, extra, field):
    with pytest.raises(SceneError) as err:
        material(hardening, **extra)
    assert field in str(err.value), str(err.value)


def test_swift_initial_yield_is_the_yield_stress():
    """Swift's e0 is derived so that K e0^n = yield_stress: the yield stress is never ignored."""
    m = material({"law": "swift", "K": 5e8, "n": 0.2})
    K, e0, n = material_params(m)[3:]
    assert K * e0**n == pytest.approx(200e6, rel=1e-14)
    # an explicit e0 that agrees with the yield stress is accepted as given
    m2 = material({"law": "swift", "K": 5e8, "n": 0.2, "e0": (0.4) ** 5})
    assert np.allclose(material_params(m2), material_params(m), rtol=1e-14)


def test_every_law_builds_its_kernel_parameters():
    for h, hp in [({"law": "perfect"}, [200e6]), ({"law": "linear", "modulus": 2e9}, [200e6, 2e9]),
                  ({"law": "voce", "saturation": 4e8, "rate": 20.0}, [200e6, 4e8, 20.0])]:
        assert material_params(material(h))[3:].tolist() == hp

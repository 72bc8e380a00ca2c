"""The SI unit of a scene field by the dotted path an override names it with (the Runs table
shows a run's overrides in the units the scene form shows them in)."""

from __future__ import annotations

import pytest

from sim.scene.load import unit_of


@pytest.mark.parametrize(("path", "unit"), [
    ("mesh.edge_length", "m"), ("mesh.size", "m"), ("material.E", "Pa"),
    ("material.nu", "1"), ("tools.0.friction", "1"), ("tools.1.force", "N"),
    ("material.hardening.saturation", "Pa"),  # a field of one of several kinds
    ("material.flc.n", "1"), ("name", None), ("mesh.no_such_field", None), ("nope.x", None),
])
def test_unit_of_a_scene_field(path, unit):
    assert unit_of(path) == unit

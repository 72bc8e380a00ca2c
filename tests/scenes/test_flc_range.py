"""Keeler and Brazier's forming limit correlation outside the range it was fitted on (hardening
exponents up to 0.21, sheets up to about 3 mm): the curve is still drawn, with a warning
naming the scene field the value came from, in the run's result."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from sim.frames import forming_limits
from sim.scene.load import scene_from_dict
from sim.stepping.simulation import Simulation
from tests.support.scenes import tiny_cup_toml


def cup(flc: dict, thickness: float | None = None, hardening: dict | None = None) -> dict:
    raw = tomllib.loads(tiny_cup_toml(steps=1))
    raw["material"]["flc"] = flc
    if thickness is not None:
        raw["shell"]["thickness"] = thickness
    if hardening is not None:
        raw["material"]["hardening"] = hardening
    return raw


def warnings_of(raw: dict) -> tuple[str, ...]:
    sc = scene_from_dict(raw)
    return forming_limits.curve_of(sc.material, sc.shell).warnings


def test_inside_the_range_there_is_no_warning():
    # the edges themselves are inside: n = 0.21, 3 mm
    assert warnings_of(cup({"kind": "keeler_brazier", "n": 0.21}, thickness=0.003)) == ()
    points = {"kind": "points", "points": [[-0.1, 0.3], [0.1, 0.3]]}
    assert warnings_of(cup(points, thickness=0.005)) == ()


def test_a_hardening_exponent_above_the_range_is_named():
    (w,) = warnings_of(cup({"kind": "keeler_brazier", "n": 0.25}))
    assert w.startswith("material.flc.n = 0.25 is above 0.21") and "extrapolated" in w, w
    swift = {"law": "swift", "K": 500e6, "n": 0.3}
    (w,) = warnings_of(cup({"kind": "keeler_brazier"}, hardening=swift))
    assert w.startswith("material.hardening.n = 0.3 is above 0.21"), w


def test_a_thickness_above_the_range_is_named():
    (w,) = warnings_of(cup({"kind": "keeler_brazier", "n": 0.2}, thickness=0.004))
    assert w.startswith("shell.thickness = 4 mm is above about 3 mm"), w
    both = warnings_of(cup({"kind": "keeler_brazier", "n": 0.3, "thickness": 0.005}))
    assert [w.split(" =")[0] for w in both] == ["material.flc.n", "material.flc.thickness"]


def test_the_warning_is_in_the_runs_result():
    sim = Simulation.from_scene(scene_from_dict(cup({"kind": "keeler_brazier", "n": 0.25})))
    assert sim.run(), sim.failure
    fl = sim.result()["forming_limits"]
    # still drawn: FLC0 in true strain, ln(1 + FLD0)
    assert fl["curve"]["flc0"] == pytest.approx(
        np.log1p(forming_limits.keeler_brazier_fld0(0.0005, 0.25)), rel=1e-12)
    assert len(fl["warnings"]) == 1 and "material.flc.n" in fl["warnings"][0]

"""Friction per tool as a live parameter: ``friction_scale.<tool>`` for each tool with
friction, on top of the run-wide ``friction_scale``, checked, applied from the next step and
logged like the others."""

from __future__ import annotations

import pytest

from sim.scene.load import scene_from_toml
from sim.stepping.simulation import Simulation
from tests.support.scenes import PRESS_TOML, tiny_cup_toml


def _cup() -> Simulation:
    return Simulation.from_scene(scene_from_toml(tiny_cup_toml()))


def _mu(sim: Simulation) -> dict[str, float]:
    return {t.tool: t.mu for t in sim.tools}


def test_each_tool_with_friction_has_its_own_multiplier():
    sim = _cup()  # punch and die, friction 0.1 each
    assert sim.parameters == {"load_scale": 1.0, "tool_speed": 1.0, "friction_scale": 1.0,
                              "holder_force_scale": 1.0, "friction_scale.punch": 1.0,
                              "friction_scale.die": 1.0}
    # a tool without friction (the press's ground and punch) gets none
    press = Simulation.from_scene(scene_from_toml(PRESS_TOML))
    assert not [k for k in press.parameters if "." in k]


def test_a_tools_multiplier_scales_that_tool_only_times_the_run_wide_one():
    sim = _cup()
    sim.step()
    sim.set_parameter("friction_scale.die", 2.0)
    assert _mu(sim) == pytest.approx({"punch": 0.1, "die": 0.2})
    sim.set_parameter("friction_scale", 1.5)
    assert _mu(sim) == pytest.approx({"punch": 0.15, "die": 0.3})
    assert sim.parameter_log == [{"step": 2, "name": "friction_scale.die", "value": 2.0},
                                 {"step": 2, "name": "friction_scale", "value": 1.5}]
    assert sim.step() is not None and not sim.failure
    assert _mu(sim) == pytest.approx({"punch": 0.15, "die": 0.3})  # kept across the step
    assert sim.result()["parameters"][0]["name"] == "friction_scale.die"


def test_scaled_names_the_other_multiplier_of_each_friction():
    sc = _cup().scaled()
    assert sc["friction_scale"] == [
        {"what": "punch", "unit": "1", "value": 0.1, "also": ["friction_scale.punch"]},
        {"what": "die", "unit": "1", "value": 0.1, "also": ["friction_scale.die"]}]
    assert sc["friction_scale.die"] == [{"what": "die", "unit": "1", "value": 0.1,
                                         "also": ["friction_scale"]}]


def test_an_unknown_tool_or_a_value_out_of_range_is_refused_naming_it():
    sim = _cup()
    with pytest.raises(ValueError, match=r"^friction_scale\.dye: unknown tool 'dye'.*"
                                         r"those with one: die, punch"):
        sim.set_parameter("friction_scale.dye", 2.0)
    with pytest.raises(ValueError, match=r"^friction_scale\.die: 11.0 out of range "
                                         r"\[0.0, 10.0\]"):
        sim.set_parameter("friction_scale.die", 11.0)
    press = Simulation.from_scene(scene_from_toml(PRESS_TOML))
    with pytest.raises(ValueError, match=r"^friction_scale\.ground: unknown tool 'ground'.*"
                                         r"none has one"):
        press.set_parameter("friction_scale.ground", 2.0)
    with pytest.raises(ValueError, match=r"^load_scale\.x: unknown parameter"):
        sim.set_parameter("load_scale.x", 2.0)
    assert sim.parameter_log == [] and _mu(sim) == pytest.approx({"punch": 0.1, "die": 0.1})

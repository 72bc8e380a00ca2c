"""The scene schema as the editor reads it: every field described with its unit, a table of
several kinds taking its kind's fields only (naming a field of another kind); and the live
tool_speed as a rate of the planned stroke. (The form's save: tests/service/test_editor.py.)"""

import tomllib

import numpy as np
import pytest

from sim.scene.load import Scene, SceneError, load_scene, scene_from_dict, scene_from_toml
from sim.stepping.simulation import Simulation
from tests.support import ROOT
from tests.support.scenes import PRESS_TOML

NUMBER = ("number", "integer")


def _fields(schema: dict):
    """(table, field, its schema) of every field of every table of the scene schema."""
    yield from (("Scene", k, s) for k, s in schema["properties"].items())
    for table, node in schema["$defs"].items():
        yield from ((table, k, s) for k, s in node.get("properties", {}).items())


def _numeric(s: dict, defs: dict) -> bool:
    """Whether a field holds numbers: a number, or an array (of arrays) of them."""
    alts = [a for a in s.get("anyOf", [s]) if a.get("type") != "null"]
    for a in alts:
        if a.get("type") in NUMBER:
            return True
        if a.get("type") == "array":
            items = a.get("prefixItems") or [a.get("items", {})]
            if any(_numeric(i, defs) for i in items):
                return True
    return False


def test_every_field_has_a_description_and_every_number_its_unit():
    """Walks the whole schema (what the form, /docs and docs/scene-reference.md read): no
    field without a description, no number without a unit, and no field explained only by a
    source comment any more (the descriptions replaced them)."""
    schema = Scene.model_json_schema()
    fields = list(_fields(schema))
    assert len(fields) > 150  # the walk reached every table, not just the top level
    for table, name, s in fields:
        assert s.get("description", "").strip(), f"{table}.{name} has no description"
        if _numeric(s, schema["$defs"]):
            assert s.get("unit"), f"{table}.{name} is a number without a unit"
    units = {s["unit"] for _, _, s in fields if "unit" in s}
    assert {"m", "Pa", "N", "1", "rad", "s"} <= units
    sources = [ROOT / "sim" / "scene" / f for f in ("sheet.py", "boundary.py", "shapes.py",
                                                    "run.py", "load.py")]
    for path in sources:
        for line in path.read_text().splitlines():
            code, _, comment = line.partition("  # ")
            assert not (comment and ":" in code and "=" in code and code.startswith("    ")
                        and not code.lstrip().startswith(("if", "for", "return", "raise"))), \
                f"{path.name}: a field explained by a comment: {line.strip()}"


def _scene(**changes) -> dict:
    raw = tomllib.loads((ROOT / "scenes/cup_drawing.toml").read_text())
    for key, value in changes.items():
        table, field = key.split("__")
        raw[table][field] = value
    return raw


@pytest.mark.parametrize(("where", "change", "loc", "kind"), [
    ("mesh", {"size": [0.06, 0.06]}, "mesh.size", "disk"),
    ("mesh", {"path": "blank.stl"}, "mesh.path", "disk"),
    ("shape", {"n_points": 5}, "tools.0.shape.n_points", "punch"),
    ("shape", {"inner_radius": 0.01}, "tools.0.shape.inner_radius", "punch"),
    ("load", {"value": 1e5}, "loads.0.value", "gravity"),
])
def test_a_field_of_another_kind_is_refused_naming_it(where, change, loc, kind):
    raw = _scene()
    if where == "mesh":
        raw["mesh"].update(change)
    elif where == "shape":
        raw["tools"][0]["shape"].update(change)
    else:
        raw["loads"] = [{"kind": "gravity", "vector": [0.0, 0.0, -9.81], **change}]
    with pytest.raises(SceneError) as err:
        scene_from_dict(raw)
    assert str(err.value).startswith(f"{loc}: not a field of kind '{kind}' (it takes ")


def test_an_override_of_kind_switches_the_table_to_that_kind():
    """mesh.kind=disk on a rectangle: the rectangle's size and origin go, its edge length
    (a disk's field too) stays, a later override completes the disk; so for a law."""
    sc = load_scene(ROOT / "scenes/cantilever.toml", {"mesh.kind": "disk",
                                                      "mesh.r_outer": 0.05})
    assert sc.mesh.kind == "disk" and sc.mesh.edge_length == 0.0046667
    sc = load_scene(ROOT / "scenes/cup_drawing.toml", {"material.hardening.law": "linear",
                                                       "material.hardening.modulus": 1e9})
    assert sc.material.hardening.model_dump() == {"law": "linear", "modulus": 1e9}
    with pytest.raises(SceneError, match=r"^mesh.r_outer: Field required"):
        load_scene(ROOT / "scenes/cantilever.toml", {"mesh.kind": "disk"})


def test_kind_comes_first_and_each_kind_lists_its_own_fields():
    schema = Scene.model_json_schema()
    defs = schema["$defs"]
    mesh = [r["$ref"].rsplit("/", 1)[1] for r in schema["properties"]["mesh"]["oneOf"]]
    assert schema["properties"]["mesh"]["discriminator"]["propertyName"] == "kind"
    for name in mesh:
        assert next(iter(defs[name]["properties"])) == "kind", name
    assert set(defs["DiskMesh"]["properties"]) == {"kind", "edge_length", "r_outer",
                                                   "imperfection"}
    punch = defs["PunchShape"]["properties"]
    assert next(iter(punch)) == "kind"
    assert set(punch) == {"kind", "radius", "height", "edge_radius", "offset", "rotation"}


# ---- tool_speed: the rate of the planned stroke ---------------------------------------------
def _press(steps: int) -> Simulation:
    return Simulation.from_scene(scene_from_toml(
        PRESS_TOML.replace("steps = 3", f"steps = {steps}")))


def _punch_z(sim: Simulation) -> float:
    return float(next(t for t in sim.tools if t.tool == "punch").translation(sim.x)[2])


@pytest.mark.parametrize(("speed", "steps"), [(2.0, 3 + 4), (0.5, 3 + 14)])
def test_tool_speed_keeps_the_planned_stroke(speed, steps):
    """tool_speed 2 from step 4 of 10: the rest of the stroke (7 planned steps) in 4 steps,
    the punch ending where the scene plans it (0.2 mm down), not 1.7 times as far; 0.5 takes
    14 steps for it. The run says how many steps it now has as soon as the speed changes."""
    sim, ref = _press(10), _press(10)
    start = _punch_z(sim)
    for _ in range(3):
        sim.step()
    sim.set_parameter("tool_speed", speed)
    assert sim.n_steps == steps
    assert sim.run(), sim.failure
    assert ref.run(), ref.failure
    assert len(sim.records) == steps and sim.records[-1].time == 1.0
    # the stroke is the planned one to round-off of the summed increments (1e-12 of 0.2 mm)
    assert _punch_z(sim) - start == pytest.approx(-0.0002, rel=1e-9)
    assert _punch_z(sim) == pytest.approx(_punch_z(ref), rel=1e-9)
    # each step after the change moves the punch speed times the planned 0.02 mm
    z = [r.tools["punch"]["z"] for r in sim.records]
    np.testing.assert_allclose(np.diff(z)[3:-1], -0.00002 * speed, rtol=1e-9)


def test_tool_speed_is_refused_for_a_dynamic_run_naming_why():
    raw = tomllib.loads(PRESS_TOML)
    raw["stepping"] = {"kind": "dynamic", "steps": 3, "dt": 1e-3}
    sim = Simulation.from_scene(scene_from_dict(raw))
    with pytest.raises(ValueError, match=r"^tool_speed: the rate of a static run's stroke"):
        sim.set_parameter("tool_speed", 2.0)
    sim.set_parameter("tool_speed", 1.0)  # as written: allowed
    with pytest.raises(ValueError, match=r"tool_speed: 0.0 out of range \[0.1, 10.0\]"):
        _press(3).set_parameter("tool_speed", 0.0)  # a stroke that never ends


def test_scaled_says_what_each_multiplier_multiplies():
    sim = Simulation.from_scene(scene_from_toml((ROOT / "scenes/cup_drawing.toml").read_text()))
    sc = sim.scaled()
    assert {e["what"]: e["value"] for e in sc["friction_scale"]} == \
        {"punch": 0.1, "die": 0.1, "blank_holder": 0.1}
    assert sc["holder_force_scale"] == [{"what": "blank_holder", "unit": "N", "value": 3000.0}]
    punch = next(e for e in sc["tool_speed"] if e["what"] == "punch")
    assert punch["value"] == pytest.approx(0.025 / 50, rel=1e-12) and punch["unit"] == "m/step"


@pytest.mark.parametrize("r_outer", [0.026, 0.03, 0.036])
def test_the_cups_rim_and_flange_follow_the_blanks_size(r_outer):
    """The shipped cup's rim is its blank's edge and its flange reaches it, whatever the blank's
    radius: an engineer's first change (a larger blank) was refused, its rim region, a fixed
    ring of 29.5 to 31 mm, selecting no node of a 32 mm blank."""
    from sim.model.dirichlet import region_mask

    scene = load_scene(ROOT / "scenes" / "cup_drawing.toml",
                       {"mesh.r_outer": r_outer, "mesh.edge_length": 0.004})
    sim = Simulation.from_scene(scene)
    shell = sim.model.shell
    rho = np.hypot(*shell.plane_mid[:, :2].T)
    regions = {r.name: region_mask(shell, r) for r in scene.regions}
    # the rim: the outer edge's nodes, all of them (a disk: its whole boundary)
    assert np.allclose(rho[regions["rim"]], r_outer, rtol=1e-6)
    assert regions["rim"].sum() == np.isclose(rho, r_outer, rtol=1e-6).sum()
    assert np.all(regions["flange"] == (rho >= 0.024 - 1e-9))

"""What a review of issue 12's hardening found past its reproducers: scene values of the wrong
type taken for numbers, magnitudes so small they underflow, angles without bounds, a failed
run's exit code, and a stopped run's result.json that did not say why."""

import json
import math
import queue
import tomllib

import numpy as np
import pytest

from sim.apps.cli import main
from sim.scene.load import SceneError, load_scene, scene_from_dict, scene_from_toml
from tests.support import ROOT

CANTILEVER = ROOT / "scenes" / "cantilever.toml"
COARSE = {"mesh.edge_length": 0.035, "stepping.steps": 1}

WRONG_TYPE = [
    ("material.E", True, "Input should be a valid number"),  # was E = 1 Pa
    ("material.E", "1e9", "Input should be a valid number"),  # was a modulus read from text
    ("stepping.steps", True, "Input should be a valid integer"),  # was 1 step
    ("stepping.steps", 2.5, "Input should be a valid integer"),
    ("loads.0.vector", [0, 0, "x"], "Input should be a valid number"),
]


@pytest.mark.parametrize("key,value,why", WRONG_TYPE, ids=[f"{k}={v!r}" for k, v, _ in
                                                            WRONG_TYPE])
def test_a_value_of_the_wrong_type_is_refused_naming_the_field(key, value, why):
    with pytest.raises(SceneError) as err:
        load_scene(CANTILEVER, {key: value})
    assert str(err.value).startswith(key) and why in str(err.value)


def test_toml_of_the_wrong_type_is_refused_and_integers_are_numbers():
    text = CANTILEVER.read_text()
    with pytest.raises(SceneError, match="material.E: Input should be a valid number"):
        scene_from_toml(text.replace("E = ", "E = true #", 1))
    # an integer where a float is due is a number (TOML writes 200 for 200.0)
    assert load_scene(CANTILEVER, {"material.E": 200}).material.E == 200.0


@pytest.mark.parametrize("key,value,why", [
    ("mesh.edge_length", 0.0, "mesh.edge_length: Input should be greater than 0 m"),
    ("material.E", -1.0, "material.E: Input should be greater than 0 Pa"),
    ("shell.thickness", 1e-13, "shell.thickness: 1e-13 m is below 1e-12 m, under which"),
    ("material.nu", 0.5, "material.nu: Input should be less than 0.5"),  # no unit: none shown
    ("stepping.dt", -1.0, "stepping.dt: Input should be greater than 0 s"),
])
def test_a_bound_is_named_with_its_unit(key, value, why):
    """pydantic writes a bound without its unit, and 1e-12 as 0.000000000001: the page shows
    the message under a box in mm (web/units.js converts "1e-12 m"). A positive magnitude's
    bound is 0, as an engineer says it; its underflow guard (a picometre, a micropascal) is a
    check of its own, met only by a value between the two."""
    with pytest.raises(SceneError) as err:
        load_scene(CANTILEVER, {key: value})
    assert str(err.value).startswith(why), str(err.value)


def test_a_scale_bound_names_no_unit_of_another_kind():
    """mesh.scale is in m per file unit on a file mesh, per drawing unit on an outline: its
    bound is left as pydantic writes it, without either."""
    with pytest.raises(SceneError) as err:
        load_scene(ROOT / "scenes" / "cup_drawing_outline.toml", {"mesh.scale": 5000.0})
    assert str(err.value).startswith("mesh.scale: Input should be less than") \
        and "per" not in str(err.value), str(err.value)


TOO_SMALL_OR_LARGE = [
    ("shell.thickness", 1e-300, "shell.thickness"),  # was a run ending in NaN fields, exit 0
    ("shell.thickness", 4.9e-324, "shell.thickness"),
    ("material.E", 1e-300, "material.E"),  # was 'load below force round-off floor'
    ("mesh.edge_length", 1e-200, "mesh.edge_length"),
    ("tools.0.shape.rotation", [1e308, 0.0, 0.0], "tools.0.shape.rotation.0"),
    ("tools.0.shape.phase", 1e300, "tools.0.shape.phase"),
]


@pytest.mark.parametrize("key,value,field", TOO_SMALL_OR_LARGE,
                         ids=[f"{k}={v!r}" for k, v, _ in TOO_SMALL_OR_LARGE])
def test_magnitudes_that_underflow_or_overflow_are_refused(key, value, field):
    scene = "beam_forming" if key.startswith("tools") else "cantilever"
    with pytest.raises(SceneError) as err:
        load_scene(ROOT / "scenes" / f"{scene}.toml", {key: value})
    assert str(err.value).startswith(field)


def test_a_bend_angle_and_keyframe_rotations_are_bounded():
    with pytest.raises(SceneError, match=r"bcs\.\d+\.bend\.angle"):
        load_scene(ROOT / "scenes" / "plastic_bending.toml",
                   {"bcs.3.bend.angle": 1e308})  # was 'inverted element at the start'
    # held in x alone, the section is turned by its layers' x only: refused past WALL_BEND
    # (1 rad), a rigid end ('xyz') is not
    with pytest.raises(SceneError, match=r"bcs\.3: bend\.angle: -1\.2 rad held in 'x' alone"):
        load_scene(ROOT / "scenes" / "plastic_bending.toml", {"bcs.3.bend.angle": -1.2})
    load_scene(ROOT / "scenes" / "plastic_bending.toml",
               {"bcs.3.bend.angle": 4.0, "bcs.3.components": "xyz"})
    load_scene(ROOT / "scenes" / "plastic_bending.toml", {"bcs.3.bend.angle": 1.0})
    with pytest.raises(SceneError, match=r"tools\.1: keyframes\.0: .* rad is beyond"):
        load_scene(ROOT / "scenes" / "beam_forming.toml",
                   {"tools.1.keyframes": [[0.5, 0, 0, 0, 1e300, 0, 0]]})


def test_wrong_types_over_the_api_are_a_422_naming_the_field(tmp_path):
    from fastapi.testclient import TestClient

    from server.app import create_app
    from server.settings import Settings

    scenes = tmp_path / "scenes"
    scenes.mkdir()
    (scenes / "cantilever.toml").write_text(CANTILEVER.read_text())
    # the frame generator in the solver's place: nothing here runs
    from server.bench import frame_generator

    app = create_app(Settings(scenes_dir=scenes, runs_dir=tmp_path / "runs", viewer=False),
                     worker_target=frame_generator)
    with TestClient(app) as client:
        r = client.post("/api/scenes/validate",
                        json={"toml": CANTILEVER.read_text().replace("E = ", "E = true #", 1)})
        assert r.status_code == 422 and r.json()["detail"].startswith("material.E")
        r = client.post("/api/scenes/render", json={"scene": {"name": "x", "material": {
            "E": "1e9"}}})
        assert any(e["loc"] == "material.E" for e in r.json()["errors"])


def test_a_run_whose_values_are_not_finite_exits_1(monkeypatch, tmp_path, capsys):
    """result.json says converged false when a value is not finite (written as null); the
    command line said 0, from the solver's own verdict."""
    from sim.frames import fields

    real = fields.field_summary
    monkeypatch.setattr(fields, "field_summary",
                        lambda f: {**real(f), "thickness_mm": {"min": float("nan")}})
    code = main(["run", "cantilever", "--quiet", "--out", str(tmp_path), *sum(
        (["--set", f"{k}={v}"] for k, v in COARSE.items()), [])])
    res = json.loads((tmp_path / "result.json").read_text())
    assert code == 1 and not res["converged"] and res["non_finite"]
    assert "not finite" in capsys.readouterr().err


def test_a_stopped_run_says_why_in_its_result(tmp_path):
    """A run ended by a stop (or by the service) is neither finished nor failed: its
    result.json says who ended it, as its status does (it held converged false and no
    reason at all)."""
    from server.worker import Solver

    events = queue.Queue()
    solver = Solver(events, queue.Queue(maxsize=4), record_every=1, step_delay=0.0)
    out = tmp_path / "r"
    out.mkdir()
    text = CANTILEVER.read_text().replace("edge_length = 0.0046667", "edge_length = 0.035")
    solver.handle({"id": 1, "cmd": "start", "run": "r", "out": str(out), "scene_toml": text,
                   "overrides": {}})
    solver.step()
    solver.handle({"id": 2, "cmd": "stop", "reason": "stopped by request"})
    res = json.loads((out / "result.json").read_text())
    assert not res["converged"] and res["failure"] is None
    assert res["stopped"] == "stopped by request" and len(res["steps"]) == 1


def test_max_memory_must_be_a_finite_size(tmp_path):
    """--max-memory inf switched the size check off (and a build of 1e-5 m edges was killed by
    the kernel for memory)."""
    assert main(["run", "cantilever", "--max-memory", "inf", "--out", str(tmp_path)]) == 2


def test_the_kernel_cache_follows_the_solver_not_its_apps(tmp_path):
    """numba's cache folder is named by a hash of the solver's sources: an edit of an app (which
    no kernel reaches) keeps it, an edit of the solver starts a new one; the newest three stay,
    so a suite running on the code before an edit keeps its kernels."""
    import os

    from sim import KEEP_CACHES, numba_cache_dir

    src = tmp_path / "sim"
    (src / "apps").mkdir(parents=True)
    (src / "kernel.py").write_text("x = 1\n")
    (src / "apps" / "run.py").write_text("y = 1\n")
    first = numba_cache_dir(src)
    (src / "apps" / "run.py").write_text("y = 2\n")
    assert numba_cache_dir(src) == first
    made = []
    for i in range(5):
        (src / "kernel.py").write_text(f"x = {i + 2}\n")
        d = numba_cache_dir(src)
        os.makedirs(d)
        os.utime(d, (1e9 + i, 1e9 + i))
        made.append(d)
    kept = sorted(str(p) for p in (tmp_path / ".numba-cache").iterdir())
    assert len(made) == 5 and kept == sorted(made[-KEEP_CACHES:])


def test_a_sheet_thicker_than_wide_or_inside_a_tool_is_refused_naming_the_field():
    """A browser review set the cup's thickness to 5000 mm: the run 'converged' with no force,
    the tools inside the sheet. A sheet thicker than its blank is long is refused naming the
    thickness; one that starts inside a tool by more than a tenth of its thickness (50 mm in
    the cup's 1.2 mm clearance) naming the tool, where and how deep."""
    from types import SimpleNamespace

    from sim.model.build import build_model
    from sim.model.sheet import check_sheet

    cup = ROOT / "scenes" / "cup_drawing.toml"
    # refused when read (twice the disk's radius bounds it), and by the build's own rule on
    # the built blank, which also holds where the scene cannot tell (a drawing's outline)
    with pytest.raises(SceneError, match=r"^shell\.thickness: 5000 mm thick, more than the "
                                         r"blank is across \(60 mm at most\): not a sheet"):
        load_scene(cup, {"shell.thickness": 5.0})
    disk = SimpleNamespace(vertices=np.array([[-0.03, 0, 0], [0.03, 0, 0], [0, 0.03, 0]]))
    with pytest.raises(ValueError, match=r"^shell\.thickness: 5000 mm thick, more than the "
                                         r"blank's largest extent \(60 mm\): not a sheet"):
        check_sheet(disk, np.full(3, 5.0), "shell.thickness")
    with pytest.raises(SceneError, match=r"^tools\.0: tool 'punch': the blank starts inside "
                                         r"it, 16\.5 mm deep at \(x, y\) = \(0 mm, 0 mm\)"):
        build_model(load_scene(cup, {"shell.thickness": 0.05}))


def test_tools_whose_paths_run_into_each_other_are_refused_naming_both():
    """A fuzz of the API gave the cup a punch 18 mm in radius, wider than the die's 17.7 mm
    opening: the run stalled in line searches that named no tool. The build follows every
    prescribed path: the punch's rounded shoulder meets the die's 0.3 mm inside its opening,
    within a tenth of the blank's thickness of it from step 17 on (the two 5 mm radii's
    closest approach at 0.5 mm of stroke a step), and the message names both tools and the
    step. A punch that passes with a gap under the thickness irons the wall and is taken, as
    a stroke through the die's ring is; the blank holder, placed by its force, is no path."""
    from sim.model.build import build_model

    cup = ROOT / "scenes" / "cup_drawing.toml"
    with pytest.raises(SceneError, match=r"^tools\.0: tool 'punch' runs into tool 'die' "
                                         r"\(tools\.1\) at step 17 of 50: they come within "
                                         r"0\.0\d+ mm of each other at \(x, y, z\) = "):
        build_model(load_scene(cup, {"tools.0.shape.radius": 0.018}))
    for ironed in ({"tools.1.shape.inner_radius": 0.0170},  # 0.5 mm gap: half the sheet
                   {"tools.0.velocity": [0.0, 0.0, -0.05]},  # through the ring
                   {"tools.2.shape.inner_radius": 0.017}):  # the holder over the punch
        build_model(load_scene(cup, ironed))
    # the same check of a stroke to the floor: two plates 1 mm apart closed by 0.95 mm, within
    # 0.1 mm of each other from step 48 on
    press = {"tools": [{"name": "top", "shape": {"kind": "plane", "point": [0, 0, 0.0005],
                                                 "normal": [0, 0, -1]},
                        "velocity": [0, 0, -0.00095]},
                       {"name": "bottom", "shape": {"kind": "plane", "point": [0, 0, -0.0005],
                                                    "normal": [0, 0, 1]}}], "probes": []}
    with pytest.raises(SceneError, match=r"^tools\.0: tool 'top' runs into tool 'bottom' "
                                         r"\(tools\.1\) at step 48 of 50: they come within "
                                         r"0\.0\d+ mm"):
        build_model(load_scene(cup, press))


def test_an_imperfection_as_high_as_the_sheet_is_wide_is_refused():
    """The fuzz again: mesh.imperfection = 1 (m) on the 60 mm blank ran and "converged": a
    dome 16 times as high as wide, not a seed (1 for 1 mm?)."""
    from sim.model.build import build_model

    cup = ROOT / "scenes" / "cup_drawing.toml"
    with pytest.raises(ValueError, match=r"^mesh\.imperfection: 1000 mm is more than half the "
                                         r"sheet's narrower side \(59\.97 mm\)"):
        build_model(load_scene(cup, {"mesh.imperfection": 1.0}))


def test_a_disk_meshed_coarser_than_its_radius_is_refused_naming_the_edge_length():
    """A browser review set the cup's edge length to 5 m: six triangles ran and "finished"
    with a full summary. An edge up to the radius is taken (a coarse look is the user's)."""
    cup = ROOT / "scenes" / "cup_drawing.toml"
    with pytest.raises(SceneError, match=r"mesh: edge_length: 5000 mm is longer than the disk's "
                                         r"radius \(30 mm\)"):
        load_scene(cup, {"mesh.edge_length": 5.0})
    assert load_scene(cup, {"mesh.edge_length": 0.03}).mesh.edge_length == 0.03


@pytest.mark.parametrize(("mesh", "edge", "said"), [
    ({"kind": "rectangle", "size": [0.7, 0.07]}, 1.0,
     r"1000 mm is longer than the rectangle's longer side \(700 mm\)"),
    ({"kind": "annulus", "r_inner": 0.01, "r_outer": 0.03}, 0.05,
     r"50 mm is longer than the ring's outer radius \(30 mm\)"),
    ({"kind": "cylinder_band", "radius": 0.01, "height": 0.02}, 0.1,
     r"100 mm is longer than the tube's height and circumference \(62\.83 mm\)"),
])
def test_every_generated_sheet_refuses_an_edge_longer_than_it_is_across(mesh, edge, said):
    """A study planned from the page took levels of 1000 and 100 m on the 700 mm cantilever:
    two 'levels' of the same few triangles (90 DoFs each). Every generated sheet refuses an
    edge longer than it is across, as the disk did, and takes one as long."""
    text = (ROOT / "scenes" / "cantilever.toml").read_text()
    scene = tomllib.loads(text)
    across = {"rectangle": 0.7, "annulus": 0.03, "cylinder_band": 2 * math.pi * 0.01}
    for h, ok in ((edge, False), (across[mesh["kind"]], True)):
        scene["mesh"] = {**mesh, "edge_length": h}
        if ok:
            assert scene_from_dict(scene).mesh.edge_length == h
            continue
        with pytest.raises(SceneError, match=r"mesh: edge_length: " + said):
            scene_from_dict(scene)

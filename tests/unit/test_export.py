"""A run's results out (sim.frames.export) read back with the library each format is for - the
csv module, meshio (VTU) and the PVD's XML, trimesh (STL, PLY), json - and compared with the
run's result.json and final.npz; the frames a run saves as it goes (sim.frames.series); and the
bad input an export refuses, naming why."""

import csv
import json
import shutil
from xml.etree import ElementTree

import meshio
import numpy as np
import pytest
import trimesh

from sim.frames import export, series
from sim.frames.units import DISPLAY
from sim.scene.load import scene_from_toml
from sim.stepping.simulation import Simulation
from tests.support.scenes import tiny_cup_toml

# positions and fields of a saved frame are float32: about 7 significant digits
F32 = 1e-6


def _run(folder, steps, every):
    sim = Simulation.from_scene(scene_from_toml(tiny_cup_toml(steps)))
    sim.save_frames(folder / "frames", every)
    assert sim.run()
    sim.write(folder)
    return sim


@pytest.fixture(scope="module")
def cup(tmp_path_factory):
    """The tiny cup drawn in 3 steps (plastic, with a forming limit curve), a frame saved
    every second step: steps 0 and 2, and 3 as the last."""
    folder = tmp_path_factory.mktemp("runs") / "cup-q3t"
    _run(folder, 3, 2)
    with np.load(folder / "final.npz") as z:
        final = dict(z)
    return folder, json.loads((folder / "result.json").read_text()), final


def test_frames_saved_every_nth_step_and_the_last_whole(cup):
    folder, res, _ = cup
    assert [k for k, _ in series.steps(folder / "frames")] == [0, 2, 3]
    assert not [p for p in folder.rglob("*") if ".tmp" in p.name or p.name.startswith(".")]
    with np.load(folder / "frames/step-000002.npz") as z:
        assert int(z["step"]) == 2 and float(z["time"]) == res["steps"][1]["time"]


def test_result_holds_each_fields_range_over_every_frame_made(tmp_path):
    """A viewer's frame of each step (as the service's solver makes one) widens the run's
    field_ranges, which result.json keeps: each field's min and max over all of them; a run
    that made no frame (no viewer) keeps none."""
    sim = Simulation.from_scene(scene_from_toml(tiny_cup_toml(3)))
    seen: dict[str, list] = {}
    for _ in range(3):
        sim.step()
        for k, v in sim.frame().fields.items():
            seen.setdefault(k, []).append(v)
    assert set(sim.field_ranges) == set(seen)
    for k, vs in seen.items():
        assert sim.field_ranges[k] == (min(v.min() for v in vs), max(v.max() for v in vs))
    thinnest = [v.min() for v in seen["thickness_mm"]]
    assert thinnest[0] > thinnest[-1]  # the range is of every step, not the last alone
    assert sim.result()["field_ranges"]["thickness_mm"] == list(sim.field_ranges["thickness_mm"])
    quiet = Simulation.from_scene(scene_from_toml(tiny_cup_toml(1)))
    assert quiet.run() and quiet.result()["field_ranges"] == {}


def test_a_frame_that_is_not_finite_leaves_the_ranges_finite(monkeypatch):
    """A step that ends not finite fails its run (server.worker checks the frame): the ranges
    the earlier frames gave stay, finite (run.json and the colour scale carry them)."""
    from sim.frames import output

    sim = Simulation.from_scene(scene_from_toml(tiny_cup_toml(2)))
    sim.step()
    before = dict(sim.frame() and sim.field_ranges)
    real = output.frame

    def poisoned(s):
        f = real(s)
        f.fields["thickness_mm"] = np.full_like(f.fields["thickness_mm"], np.nan)
        f.fields["von_mises_MPa"][0] = np.inf
        return f

    monkeypatch.setattr(output, "frame", poisoned)
    sim.frame()
    assert sim.field_ranges["thickness_mm"] == before["thickness_mm"]
    assert all(np.isfinite(v).all() for v in sim.field_ranges.values())


def test_the_time_column_says_seconds_only_in_a_dynamic_run(tmp_path):
    steps = [{"step": 1, "time": 0.5, "probes": {}}]
    for kind, head in (("static", "pseudo-time [-]"), ("dynamic", "time [s]"),
                       (None, "time [s]")):  # a result written before it said its kind
        result = {"steps": steps} | ({"stepping": kind} if kind else {})
        assert export.columns(export.RunFolder(tmp_path, result, {}))[1] == (head, [0.5])


def test_csv_a_row_per_step_with_units_in_the_header(cup, tmp_path):
    folder, res, _ = cup
    [path] = export.export(folder, "csv", tmp_path)
    rows = list(csv.reader(path.open()))
    head, body = rows[0], rows[1:]
    # the scene's punch_force probe (the punch's z force) says what "punch force" says: once
    # a static run's time is its pseudo-time (0 to 1), not seconds
    assert head == ["step", "pseudo-time [-]", "punch stroke [mm]", "punch force [kN]",
                    "punch lateral force [kN]", "min_thickness [mm]", "centre_dz [mm]"]
    assert len(body) == len(res["steps"]) == 3
    col = {h: [float(r[i]) for r in body] for i, h in enumerate(head)}
    steps = res["steps"]
    assert col["step"] == [r["step"] for r in steps]
    # written to export.DIGITS significant digits: equal to half a unit of the last one
    digits = 0.5 * 10.0 ** (1 - export.DIGITS)
    np.testing.assert_allclose(col["pseudo-time [-]"], [r["time"] for r in steps], rtol=digits)
    for name, unit in (("min_thickness", "m"), ("centre_dz", "m")):
        factor = DISPLAY[unit][1]
        np.testing.assert_allclose(col[f"{name} [{DISPLAY[unit][0]}]"],
                                   [r["probes"][name] * factor for r in steps], rtol=digits)
    # no float's last bit in the file (24.499999999999993 kN): every cell as DIGITS write it
    cells = [c for row in body for c in row if c]
    assert cells == [f"{float(c):.{export.DIGITS}g}" for c in cells]
    # the punch moves down from its start: the stroke is its travel, the force the sheet's
    # push against it (its z force, as the tool_force probe says)
    z0 = res["punches"]["punch"][2]
    np.testing.assert_allclose(col["punch stroke [mm]"],
                               [1e3 * (z0 - r["tools"]["punch"]["z"]) for r in steps],
                               rtol=digits)
    np.testing.assert_allclose(col["punch force [kN]"],
                               [r["probes"]["punch_force"] * 1e-3 for r in steps], rtol=digits)
    # its side thrust: the force's x and y (the stroke is along z), as the summary's peak says
    side = [1e-3 * np.hypot(r["tools"]["punch"]["fx"], r["tools"]["punch"]["fy"]) for r in steps]
    np.testing.assert_allclose(col["punch lateral force [kN]"], side, rtol=digits, atol=1e-15)


def test_csv_leaves_a_released_punchs_cells_empty(cup, tmp_path):
    """A punch released for springback reports nothing in the release stage."""
    folder, _, _ = cup
    shutil.copytree(folder, tmp_path / "run")
    res = json.loads((folder / "result.json").read_text())
    del res["steps"][-1]["tools"]["punch"]
    (tmp_path / "run/result.json").write_text(json.dumps(res))
    rows = list(csv.DictReader(export.export(tmp_path / "run", "csv", tmp_path)[0].open()))
    assert [r["punch force [kN]"] == "" for r in rows] == [False, False, True]
    assert [r["punch stroke [mm]"] == "" for r in rows] == [False, False, True]
    # there the probe says what the punch column does not: its column stays
    assert all(r["punch_force [kN]"] for r in rows)


def test_summary_json_is_the_results_summary(cup, tmp_path):
    folder, res, _ = cup
    [path] = export.export(folder, "json", tmp_path)
    got = json.loads(path.read_text())
    assert got["summary"] == res["summary"] and got["counts"] == res["counts"]
    assert (got["scene"], got["element"], got["converged"], got["step"]) == \
        ("tiny_cup", "q3t", True, 3)
    assert got["forming_limits"]["zone_counts"] == res["forming_limits"]["zone_counts"]
    assert got["fields"] == res["fields"]


def test_vtu_final_state_is_final_npz_in_mm_and_mpa(cup, tmp_path):
    folder, res, final = cup
    export.export(folder, "vtu", tmp_path)
    m = meshio.read(tmp_path / "cup-q3t_final.vtu")
    top, bot = final["skins"]
    np.testing.assert_array_equal(m.points, 1e3 * final["deformed"][np.r_[top, bot]])
    assert [c.type for c in m.cells] == ["wedge"] and len(m.cells[0].data) == \
        res["counts"]["elements"]
    both = lambda v: np.concatenate([v, v])  # noqa: E731  (a field on both skins' points)
    p, c = m.point_data, m.cell_data_dict
    np.testing.assert_allclose(p["thickness_mm"], both(1e3 * final["thickness"]), rtol=1e-15)
    np.testing.assert_allclose(p["von_mises_MPa"], both(1e-6 * final["von_mises"]), rtol=1e-15)
    np.testing.assert_array_equal(p["thinning_pct"], both(final["thinning_pct"]))
    np.testing.assert_array_equal(p["eq_plastic_strain"], both(final["eq_plastic_strain"]))
    np.testing.assert_array_equal(p["major_strain"], both(final["major_strain"]))
    np.testing.assert_allclose(p["displacement_mm"], 1e3 * (final["deformed"] - final["rest"])[
        np.r_[top, bot]], rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(c["fld_zone"]["wedge"], final["fld_zone_elem"])
    np.testing.assert_allclose(c["von_mises_MPa"]["wedge"], 1e-6 * final["von_mises_elem"],
                               rtol=1e-15)
    # a static run's time is its pseudo-time (0 to 1), named so: "time_s" read as seconds
    assert (m.field_data["step"][0], m.field_data["pseudo_time"][0]) == (
        3, res["steps"][-1]["time"])


def test_vtu_wedges_follow_vtks_orientation(cup, tmp_path):
    """VTK's wedge: the base triangle's right-hand normal points away from the other."""
    folder, _, _ = cup
    export.export(folder, "vtu", tmp_path)
    m = meshio.read(tmp_path / "cup-q3t_final.vtu")
    P = m.points[m.cells[0].data]
    n = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    assert (np.einsum("ij,ij->i", n, P[:, 3] - P[:, 0]) < 0).all()


def test_pvd_lists_the_saved_frames_in_step_order(cup, tmp_path):
    folder, res, final = cup
    export.export(folder, "vtu", tmp_path)
    sets = ElementTree.parse(tmp_path / "cup-q3t.pvd").getroot().iter("DataSet")
    entries = [(int(d.get("timestep")), d.get("file")) for d in sets]
    assert [k for k, _ in entries] == [0, 2, 3]
    times = {0: 0.0, **{r["step"]: r["time"] for r in res["steps"]}}
    for step, file in entries:
        m = meshio.read(tmp_path / file)
        assert (m.field_data["step"][0], m.field_data["pseudo_time"][0]) == (step, times[step])
        assert set(m.point_data) >= {"thickness_mm", "thinning_pct", "von_mises_MPa",
                                     "eq_plastic_strain", "displacement_mm", "major_strain",
                                     "minor_strain", "fld_zone"}
    first, last = meshio.read(tmp_path / entries[0][1]), meshio.read(tmp_path / entries[-1][1])
    assert np.abs(first.point_data["displacement_mm"]).max() == 0.0  # the rest state
    top, bot = final["skins"]
    np.testing.assert_allclose(last.points, 1e3 * final["deformed"][np.r_[top, bot]],
                               rtol=F32, atol=F32 * 12)  # 12 mm: the disk's radius
    np.testing.assert_allclose(last.point_data["thickness_mm"][: len(top)],
                               1e3 * final["thickness"], rtol=F32)


@pytest.mark.parametrize("fmt", ["stl", "ply"])
def test_part_is_the_closed_deformed_shell_in_mm(cup, tmp_path, fmt):
    folder, res, final = cup
    [path] = export.export(folder, fmt, tmp_path)
    part = trimesh.load(path)  # merged: STL keeps a copy of each corner per triangle
    top, bot = final["skins"]
    skins = 1e3 * final["deformed"][np.r_[top, bot]]
    assert part.is_watertight and part.is_winding_consistent
    assert len(part.vertices) == len(skins)
    # each vertex a skin's corner; STL stores float32 (7 digits of the 12 mm radius)
    nearest = np.linalg.norm(part.vertices[:, None] - skins[None], axis=2).min(1)
    assert nearest.max() < 12 * F32
    n_f = res["counts"]["elements"]
    rim = len(part.faces) - 2 * n_f
    assert rim > 0 and rim % 2 == 0  # two triangles per boundary edge
    assert part.volume > 0  # outward normals


def test_part_at_rest_holds_the_sheets_volume(tmp_path):
    """A run written before its first step: the flat disk, area x thickness exactly."""
    sim = Simulation.from_scene(scene_from_toml(tiny_cup_toml(2)))
    sim.write(tmp_path / "rest")
    part = export.part(export.open_run(tmp_path / "rest"))
    mesh = sim.model.shell.mesh
    area = trimesh.Trimesh(mesh.vertices, mesh.faces).area
    assert part.volume == pytest.approx(area * 1e6 * 0.5, rel=1e-9)  # mm^2 x 0.5 mm


def test_stopped_run_saves_its_last_state_as_a_frame(tmp_path):
    sim = Simulation.from_scene(scene_from_toml(tiny_cup_toml(4)))
    sim.save_frames(tmp_path / "frames", 3)
    sim.step()
    sim.end("stopped by request")
    sim.write(tmp_path)
    assert [k for k, _ in series.steps(tmp_path / "frames")] == [0, 1]


def test_a_frame_that_cannot_be_saved_fails_the_run_naming_it(tmp_path):
    sim = Simulation.from_scene(scene_from_toml(tiny_cup_toml(2)))
    sim.save_frames(tmp_path / "frames", 1)
    shutil.rmtree(tmp_path / "frames")
    (tmp_path / "frames").write_text("not a folder")
    assert not sim.run()
    assert sim.failure["reason"].startswith("saving the frame of step 1 failed")
    assert sim.result()["converged"] is False


def test_a_run_without_final_state_exports_its_probes_only(cup, tmp_path):
    folder, _, _ = cup
    run = tmp_path / "failed"
    run.mkdir()
    res = json.loads((folder / "result.json").read_text())
    res["failure"] = {"reason": "build failed: no node in region"}
    (run / "result.json").write_text(json.dumps(res))
    assert export.export(run, "csv", tmp_path / "out")[0].is_file()
    for fmt in export.STATE_FORMATS:
        with pytest.raises(export.ExportError, match="no final state.*build failed"):
            export.export(run, fmt, tmp_path / "out")


@pytest.mark.parametrize("case, match", [
    ("missing", "no such run folder"), ("empty", "no result.json"),
    ("garbled", "result.json: unreadable"), ("format", "format 'obj': unknown; known: csv"),
    ("out_is_file", "not a folder to write into")])
def test_bad_input_is_refused_naming_why(cup, tmp_path, case, match):
    folder, fmt, out = tmp_path / "run", "csv", tmp_path / "out"
    if case != "missing":
        shutil.copytree(cup[0], folder) if case in ("format", "out_is_file") else folder.mkdir()
    if case == "garbled":
        (folder / "result.json").write_text("{not json")
    if case == "format":
        fmt = "obj"
    if case == "out_is_file":
        out.write_text("")
    with pytest.raises(export.ExportError, match=match):
        export.export(folder, fmt, out)

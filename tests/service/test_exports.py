"""A run's downloads over the API (/api/runs/{id}/exports, /api/runs/{id}/export/{format}):
each file read back and compared with the run's result.json and final.npz, and the clear
4xx of an unknown run, a run still going, an unknown format, a run without a final state."""

import csv
import io
import json
import zipfile
from xml.etree import ElementTree

import meshio
import numpy as np
import pytest
import trimesh

from sim.frames import export, series
from tests.support.scenes import tiny_cup_toml
from tests.support.service import wait_state

ENDED = {"finished", "failed", "stopped"}


@pytest.fixture(scope="module")
def cup(env):
    """A finished run of the tiny cup (3 steps), its folder and result.json."""
    client, settings = env
    (settings.scenes_dir / "tiny_cup.toml").write_text(tiny_cup_toml(3))
    r = client.post("/api/runs", json={"scene": "tiny_cup"})
    assert r.status_code == 201, r.text
    run_id = r.json()["id"]
    assert wait_state(client, run_id, ENDED)["state"] == "finished"
    folder = settings.runs_dir / run_id
    return client, run_id, folder, json.loads((folder / "result.json").read_text())


def test_the_list_says_every_format_is_there(cup):
    client, run_id, _, _ = cup
    got = client.get(f"/api/runs/{run_id}/exports").json()
    assert [f["format"] for f in got["formats"]] == [*export.FORMATS, "png"]
    for f in got["formats"]:
        assert f["url"] == f"/api/runs/{run_id}/export/{f['format']}"
        if f["format"] != "png":
            assert f["available"] and f["reason"] is None
    # this server runs without the viewer: no 3-D view to capture
    png = got["formats"][-1]
    assert not png["available"] and png["reason"].startswith("the viewer is off")
    r = client.get(f"/api/runs/{run_id}/export/png")
    assert r.status_code == 409 and r.json()["detail"] == png["reason"]


def test_csv_reads_back_as_the_results_probes(cup):
    client, run_id, _, res = cup
    r = client.get(f"/api/runs/{run_id}/export/csv")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/csv")
    assert f'filename="{run_id}.csv"' in r.headers["content-disposition"]
    rows = list(csv.reader(io.StringIO(r.text)))
    assert len(rows) - 1 == len(res["steps"])
    i = rows[0].index("punch force [kN]")  # the punch_force probe says the same: once
    # export.DIGITS significant digits: within half a unit of the last
    np.testing.assert_allclose([float(row[i]) for row in rows[1:]],
                               [s["probes"]["punch_force"] * 1e-3 for s in res["steps"]],
                               rtol=0.5 * 10.0 ** (1 - export.DIGITS))


def test_vtu_zip_holds_the_pvd_and_every_file_it_names(cup, tmp_path):
    client, run_id, folder, res = cup
    r = client.get(f"/api/runs/{run_id}/export/vtu")
    assert r.status_code == 200 and r.headers["content-type"] == "application/zip"
    zipfile.ZipFile(io.BytesIO(r.content)).extractall(tmp_path)
    sets = ElementTree.parse(tmp_path / f"{run_id}.pvd").getroot().iter("DataSet")
    steps = [int(d.get("timestep")) for d in sets]
    # the server records every 10th step and the last: the rest state and step 3
    assert steps == [0, 3]
    with np.load(folder / "final.npz") as z:
        top, bot = z["skins"]
        points, h = 1e3 * z["deformed"][np.r_[top, bot]], 1e3 * z["thickness"]
    m = meshio.read(tmp_path / f"{run_id}_final.vtu")
    np.testing.assert_array_equal(m.points, points)
    np.testing.assert_allclose(m.point_data["thickness_mm"][: len(top)], h, rtol=1e-15)
    assert m.field_data["step"][0] == res["steps"][-1]["step"]


@pytest.mark.parametrize("fmt", ["stl", "ply"])
def test_part_is_closed(cup, fmt):
    client, run_id, _, res = cup
    r = client.get(f"/api/runs/{run_id}/export/{fmt}")
    assert r.status_code == 200
    part = trimesh.load(io.BytesIO(r.content), file_type=fmt)
    assert part.is_watertight and part.volume > 0
    assert len(part.vertices) == 2 * res["counts"]["vertices"]


def test_summary_json_is_the_results_summary(cup):
    client, run_id, _, res = cup
    got = client.get(f"/api/runs/{run_id}/export/json").json()
    assert got["run"] == run_id and got["summary"] == res["summary"]


def test_unknown_run_and_format_are_named(cup):
    client, run_id, _, _ = cup
    r = client.get("/api/runs/nosuch-run/export/csv")
    assert r.status_code == 404 and r.json()["detail"] == "no run 'nosuch-run'"
    r = client.get(f"/api/runs/{run_id}/export/obj")
    assert r.status_code == 422 and "format" in r.json()["detail"] \
        and "'csv'" in r.json()["detail"]
    assert client.get("/api/runs/..%2Fsecret/export/csv").status_code in (404, 422)


def test_a_run_still_going_is_409_and_lists_why(env):
    client, _ = env
    r = client.post("/api/runs", json={"scene": "tiny", "paused": True})
    run_id = r.json()["id"]
    try:
        # built (a stop while building ends the run without a state: see below)
        wait_state(client, run_id, {"paused"})
        r = client.get(f"/api/runs/{run_id}/export/csv")
        assert r.status_code == 409 and "complete when it ends" in r.json()["detail"]
        formats = client.get(f"/api/runs/{run_id}/exports").json()["formats"][:-1]
        assert [f["format"] for f in formats] == list(export.FORMATS)
        assert not any(f["available"] for f in formats)
        assert all("complete when it ends" in f["reason"] for f in formats)
    finally:
        client.post(f"/api/runs/{run_id}/stop")
    assert wait_state(client, run_id, ENDED)["state"] == "stopped"
    # stopped before its first step: its state is the rest state, and exports
    assert client.get(f"/api/runs/{run_id}/export/stl").status_code == 200


def test_a_run_without_a_final_state_says_so(cup):
    client, run_id, folder, _ = cup
    (folder / "final.npz").rename(folder / "kept.npz")
    try:
        r = client.get(f"/api/runs/{run_id}/export/vtu")
        assert r.status_code == 404 and "no final state (final.npz)" in r.json()["detail"]
        formats = {f["format"]: f for f in
                   client.get(f"/api/runs/{run_id}/exports").json()["formats"]}
        assert formats["csv"]["available"] and not formats["stl"]["available"]
        assert "final.npz" in formats["stl"]["reason"]
        # nor a 3-D view of it: the viewer would draw no sheet (a PNG of an empty view)
        assert formats["png"]["reason"] == formats["stl"]["reason"], formats["png"]
        r = client.get(f"/api/runs/{run_id}/export/png")
        assert r.status_code == 404 and r.json()["detail"] == formats["stl"]["reason"]
    finally:
        (folder / "kept.npz").rename(folder / "final.npz")


def test_a_run_without_steps_has_no_csv(cup):
    """A run that failed before its first step: no table of steps to download (it offered a
    header without rows), and the reason says why."""
    client, run_id, folder, res = cup
    kept = (folder / "result.json").read_text()
    (folder / "result.json").write_text(json.dumps({**res, "steps": [],
                                                    "failure": {"reason": "no contact"}}))
    try:
        r = client.get(f"/api/runs/{run_id}/export/csv")
        assert r.status_code == 404, r.text
        assert r.json()["detail"] == (f"run {run_id!r} has no steps: it ended before its "
                                      "first (no contact)")
    finally:
        (folder / "result.json").write_text(kept)


def test_a_queued_run_has_no_downloads_until_it_has_run(env):
    """A run waiting in the queue is neither going nor ended: its downloads are refused as a
    going run's are (409 saying it is queued), not as a run that lost its files (404)."""
    client, _ = env
    ahead = client.post("/api/runs", json={"scene": "tiny", "paused": True}).json()["id"]
    queued = client.post("/api/runs", json={"scene": "tiny"}).json()
    assert queued["state"] == "queued", queued
    r = client.get(f"/api/runs/{queued['id']}/export/csv")
    assert r.status_code == 409 and "queued" in r.json()["detail"], r.text
    listed = client.get(f"/api/runs/{queued['id']}/exports").json()["formats"]
    assert not any(f["available"] for f in listed)
    # the PNG too: no browser can show a run that has not started
    assert all("queued" in f["reason"] for f in listed), listed
    r = client.get(f"/api/runs/{queued['id']}/export/png")
    assert r.status_code == 409 and "queued" in r.json()["detail"], r.text
    for run in (queued["id"], ahead):
        client.post(f"/api/runs/{run}/stop")
        wait_state(client, run, {"stopped", "cancelled", "finished"})


def test_a_run_deleted_while_exported_is_404(env, monkeypatch):
    """A run deleted while its download is being read (its frames gone under the export):
    404 saying so, where the export's FileNotFoundError had been a 500."""
    client, settings = env
    (settings.scenes_dir / "tiny_cup.toml").write_text(tiny_cup_toml(2))
    run_id = client.post("/api/runs", json={"scene": "tiny_cup"}).json()["id"]
    assert wait_state(client, run_id, ENDED)["state"] == "finished"
    listed = series.steps

    def deleted_meanwhile(folder):  # noqa: ANN001, ANN202
        found = listed(folder)  # the frames listed, then the run deleted before they are read
        assert found and client.delete(f"/api/runs/{run_id}").status_code == 204
        return found

    monkeypatch.setattr(series, "steps", deleted_meanwhile)
    r = client.get(f"/api/runs/{run_id}/export/vtu")
    assert r.status_code == 404, r.text
    assert r.json()["detail"] == f"run {run_id!r} was deleted while it was exported"
    # deleted before the export opened it: the same, not the folder's path on the server
    monkeypatch.undo()
    assert client.get(f"/api/runs/{run_id}/export/vtu").status_code == 404

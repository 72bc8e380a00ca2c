"""/api/runs/{id}/split_ring on a finished cup (tests/support/scenes.py's ring cup, the
coarsest with a wall for a band): the ring the command line cuts, to round-off; its files
downloaded as they are on disk, and only a ring the run lists; a ring being cut listed with
its stage as the child reports it, gone once the cut has ended, well or not; 409 while one is
cut from the run; 422 naming the field for every bad request, the run left as it was; a
failed release answered with the solver's reason and nothing written; the ring's files
deleted with the run."""

from __future__ import annotations

import asyncio
import io
import itertools
import json
import shutil
import threading
import zipfile
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from xml.etree import ElementTree

import meshio
import numpy as np
import pytest

from server.problems import NotFound, Unsolved
from server.rings import READ, SAVE, RingCutter
from sim.frames import rings
from sim.stepping.split_ring import STAGES
from tests.support.scenes import RING_BAND, ring_cup_toml, tiny_cup_toml
from tests.support.service import (
    HANG,
    finished_run,
    hold_ring_at,
    in_process,
    until,
    until_exists,
)


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("rings")
    with in_process(tmp, {"ring_cup": ring_cup_toml(), "tiny_cup": tiny_cup_toml()}) as out:
        yield out


@pytest.fixture(scope="module")
def cup(env):
    """A finished ring cup: its id and folder."""
    client, settings = env
    run = finished_run(client, "ring_cup")
    return run, settings.runs_dir / run


def url(run: str) -> str:
    return f"/api/runs/{run}/split_ring"


def test_the_ring_is_the_command_lines_and_is_listed(env, cup, tmp_path):
    client, _ = env
    run, folder = cup
    before = client.get(url(run)).json()
    assert before["available"] and before["reason"] is None and before["rings"] == []
    low, high = before["wall_mm"]
    # the band is the wall's extent rounded out to 0.1 mm, as the page's default
    assert [round(low - 0.05, 1), round(high + 0.05, 1)] == RING_BAND
    r = client.post(url(run), json={"heights": RING_BAND})
    assert r.status_code == 200, r.text
    got = r.json()
    assert got["run"] == run and got["heights_mm"] == RING_BAND and got["cut_angle_deg"] == 0
    # the command line on a copy of the run, before the server's ring was added
    copy = tmp_path / "copy"
    shutil.copytree(folder, copy)
    data = json.loads((copy / "result.json").read_text())
    del data[rings.KEY]
    (copy / "result.json").write_text(json.dumps(data))
    from sim.apps.cli import main

    assert main(["splitring", str(copy), "--heights", ",".join(map(str, RING_BAND))]) == 0
    (cli,) = rings.of_run(copy)
    summary = {k: v for k, v in got.items() if k not in ("run", "downloads")}
    assert _close(summary, rings.shown(cli)), (summary, rings.shown(cli))
    # the engineer's numbers: mm, %, deg
    assert abs(got["opening_mm"]["at_mid_height"]) < 5 and got["elements"] > 0
    assert 10 < got["diameters_mm"]["formed"]["mean"] < 13  # the 11 mm punch's cup
    assert 0 <= got["reyield_pct"]["closed"] <= 100
    # saved as the command saves it: result.json's entry (SI) and the files
    (saved,) = rings.of_run(folder)
    assert rings.shown(saved) == summary
    with np.load(folder / f"{got['name']}.npz") as z:
        assert z["split"].shape == z["rest"].shape
    assert sorted(p.name for p in (folder / got["name"]).iterdir()) == [
        "ring_formed.vtu", "ring_released.vtu", "ring_split.vtu"]
    listed = client.get(url(run)).json()
    assert listed["rings"] == [{k: v for k, v in got.items() if k != "run"}]
    assert listed["cutting"] is None
    # the same ring again (360 deg is 0: the same meridian) replaces its entry; another cut
    # is another ring (-270 deg is 90)
    again = client.post(url(run), json={"heights": RING_BAND, "cut_angle": 360})
    assert again.status_code == 200 and again.json()["cut_angle_deg"] == 0
    assert again.json()["name"] == got["name"]
    r = client.post(url(run), json={"heights": RING_BAND, "cut_angle": -270})
    assert r.status_code == 200 and r.json()["cut_angle_deg"] == 90
    assert [(r["heights_mm"], r["cut_angle_deg"]) for r in client.get(url(run)).json()[
        "rings"]] == [(RING_BAND, 0.0), (RING_BAND, 90.0)]


def _close(got: dict, want: dict) -> bool:
    """Nested dicts equal, numbers to round-off (pytest.approx compares flat ones only)."""
    if isinstance(want, dict):
        return got.keys() == want.keys() and all(_close(got[k], want[k]) for k in want)
    if isinstance(want, list):
        return len(got) == len(want) and all(map(_close, got, want))
    if isinstance(want, float):
        return got == pytest.approx(want, rel=1e-9, abs=1e-12)
    return got == want


@pytest.fixture(scope="module")
def ring(env, cup) -> dict:
    """The ring at RING_BAND cut at 0 deg from the cup, as listed: the one the first test
    cuts, else cut here (a test run on its own)."""
    client, _ = env
    run, _ = cup
    listed = [r for r in client.get(url(run)).json()["rings"]
              if r["heights_mm"] == RING_BAND and r["cut_angle_deg"] == 0]
    if listed:
        return listed[0]
    r = client.post(url(run), json={"heights": RING_BAND})
    assert r.status_code == 200, r.text
    return r.json()


def download(client, run: str, name: str, fmt: str, media: str) -> bytes:
    """A ring's file, checked to be saved under the run's and the ring's name."""
    r = client.get(f"{url(run)}/{name}/{fmt}")
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == media
    suffix = "_vtu.zip" if fmt == "vtu" else ".npz"
    assert r.headers["content-disposition"] == f'attachment; filename="{run}_{name}{suffix}"'
    return r.content


def test_a_rings_downloads_are_listed_with_their_urls(ring, cup):
    run, _ = cup
    assert [(f["format"], f["url"]) for f in ring["downloads"]] == [
        (fmt, f"/api/runs/{run}/split_ring/{ring['name']}/{fmt}") for fmt in ("vtu", "npz")]
    assert all(f["description"] == rings.DOWNLOADS[f["format"]] for f in ring["downloads"])


def test_a_rings_npz_downloads_as_saved(env, cup, ring):
    client, _ = env
    run, folder = cup
    data = download(client, run, ring["name"], "npz", "application/octet-stream")
    assert data == (folder / f"{ring['name']}.npz").read_bytes()
    with np.load(io.BytesIO(data)) as z:
        assert set(z.files) == {"rest", "conn", "faces", "skins", "elements", "twins",
                                "formed", "released", "split"}
        assert len(z["elements"]) == ring["elements"] == len(z["faces"])
        assert all(z[s].shape == z["rest"].shape for s in rings.STATES)


def test_a_rings_vtu_downloads_as_saved_with_a_pvd_series(env, cup, ring, tmp_path):
    """The zip holds the ring's VTU files byte for byte, and a PVD whose steps are the
    states in the test's order: each VTU's points are its state's skins, in mm."""
    client, _ = env
    run, folder = cup
    name, stem = ring["name"], f"{run}_{ring['name']}"
    z = zipfile.ZipFile(io.BytesIO(download(client, run, name, "vtu", "application/zip")))
    vtus = [f"{stem}/ring_{s}.vtu" for s in rings.STATES]
    assert sorted(z.namelist()) == sorted([*vtus, f"{stem}.pvd"])
    for s, member in zip(rings.STATES, vtus, strict=True):
        assert z.read(member) == (folder / name / f"ring_{s}.vtu").read_bytes()
    z.extractall(tmp_path)
    sets = ElementTree.parse(tmp_path / f"{stem}.pvd").getroot().iter("DataSet")
    assert [(int(d.get("timestep")), d.get("file")) for d in sets] == list(enumerate(vtus))
    with np.load(folder / f"{name}.npz") as saved:
        top_bottom = saved["skins"].ravel()
        for step, (s, member) in enumerate(zip(rings.STATES, vtus, strict=True)):
            m = meshio.read(tmp_path / member)
            np.testing.assert_allclose(m.points, 1e3 * saved[s][top_bottom], rtol=1e-12)
            assert len(m.cells_dict["wedge"]) == ring["elements"]
            assert m.field_data["step"][0] == step


def test_only_a_ring_the_run_lists_is_served_404_naming_the_field(env, cup, ring):
    client, _ = env
    run, _ = cup
    name = ring["name"]
    r = client.get(f"{url('nope')}/{name}/vtu")
    assert r.status_code == 404 and r.json()["detail"] == "run_id: no run 'nope'"
    listed = ", ".join(r["name"] for r in client.get(url(run)).json()["rings"])
    for asked, ring_name in [
        ("split_ring-1-2mm", "split_ring-1-2mm"),  # a ring's name, not cut
        ("..%2Fresult.json", "../result.json"),
        (f"{name}%2F..%2F..%2Fresult.json", f"{name}/../../result.json"),
        ("..%2F..%2F..%2F..%2Fetc%2Fpasswd", "../../../../etc/passwd"),
        (f"{name}%2Fring_split.vtu", f"{name}/ring_split.vtu"),  # a file of the ring
        ("%2E%2E", ".."),
    ]:
        r = client.get(f"{url(run)}/{asked}/npz")
        assert r.status_code == 404, (asked, r.text)
        assert r.json()["detail"] == (f"ring: {ring_name!r}: no such ring cut from run "
                                      f"{run!r} (its rings: {listed})"), asked
    r = client.get(f"{url(run)}/{name}/stl")
    assert r.status_code == 422 and r.json()["detail"].startswith("path.format: "), r.text


def test_a_listed_ring_whose_files_are_gone_is_a_404_naming_it(env, cup, ring, monkeypatch,
                                                               tmp_path):
    """Files removed by hand (the service never lists a ring without them)."""
    client, _ = env
    run, _ = cup
    monkeypatch.setattr(rings, "npz_file", lambda folder, name: tmp_path / "gone.npz")
    r = client.get(f"{url(run)}/{ring['name']}/npz")
    assert r.status_code == 404 and r.json()["detail"] == (
        f"ring: {ring['name']!r}: its files are gone from the run's folder"), r.text


@pytest.mark.parametrize("body, detail", [
    ({"heights": [6.2, 1.6]}, "body.heights: 6.2, 1.6 mm: need 0 <= z1 < z2"),
    ({"heights": [1.6]}, "body.heights: List should have at least 2 items"),
    ('{"heights": [NaN, 6.2]}', "body.heights.0: Input should be a finite number"),
    ('{"heights": [1.6, 1e999]}', "body.heights.1: Input should be a finite number"),
    ('{"heights": [1.6, 6.2], "cut_angle": Infinity}', "body.cut_angle: Input should be a "
                                                        "finite number"),
    ({"heights": [1.6, 6.2], "colour": "red"}, "body.colour: Extra inputs are not permitted"),
    ({"heights": ["1.6", 6.2]}, "body.heights.0: Input should be a valid number"),
    ({"heights": "1.6, 6.2"}, "body.heights: Input should be a valid list"),
    ({"heights": [1.6, 6.2], "cut_angle": "0"}, "body.cut_angle: Input should be a valid "
                                                "number"),
    ({"heights": [1.6, 6.2], "cut_angle": None}, "body.cut_angle: Input should be a valid "
                                                 "number"),
    ({"heights": [8, 13]}, "heights: 13 mm is above the part (its top is"),
    ({"heights": [0, 1]}, "heights: 0-1 mm is not all on the wall"),
    ({"heights": [3, 5]}, "heights: 3-5 mm is not one closed ring around the axis"),
])
def test_bad_requests_are_422_naming_the_field_and_change_nothing(env, cup, body, detail):
    client, _ = env
    run, folder = cup
    before = {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file()}
    if isinstance(body, str):
        r = client.post(url(run), content=body, headers={"Content-Type": "application/json"})
    else:
        r = client.post(url(run), json=body)
    assert r.status_code == 422 and detail in r.json()["detail"], r.text
    assert {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file()} == before


def test_several_bad_fields_are_each_named(env, cup):
    client, _ = env
    run, _ = cup
    r = client.post(url(run), json={"heights": [6.2, 1.6], "cut_angle": "north", "to": 1})
    assert r.status_code == 422, r.text
    parts = r.json()["detail"].split("; ")
    assert sorted(p.partition(":")[0] for p in parts) == [
        "body.cut_angle", "body.heights", "body.to"], parts
    assert any(p.startswith("body.heights: 6.2, 1.6 mm: need 0 <= z1 < z2") for p in parts)


def test_runs_a_ring_cannot_be_cut_from_are_422_naming_the_run(env):
    client, settings = env
    going = client.post("/api/runs", json={"scene": "ring_cup", "paused": True}).json()["id"]
    try:
        r = client.post(url(going), json={"heights": RING_BAND})
        assert r.status_code == 422 and r.json()["detail"].startswith(f"run_id: {going}: "
                                                                      "the run is ")
        assert not client.get(url(going)).json()["available"]
    finally:
        client.post(f"/api/runs/{going}/stop")
    shallow = finished_run(client, "tiny_cup")  # drawn 2 mm: all radius and flange
    r = client.post(url(shallow), json={"heights": [0.5, 1.5]})
    assert r.status_code == 422 and r.json()["detail"].startswith(
        f"run_id: {shallow}: no steep wall: no element of the formed part is inclined more "
        "than 60 deg")
    assert client.get(url(shallow)).json()["wall_mm"] is None
    (settings.runs_dir / shallow / "final.npz").unlink()
    r = client.post(url(shallow), json={"heights": [0.5, 1.5]})
    assert r.status_code == 422 and r.json()["detail"] == (
        f"run_id: {shallow}: the run has no final.npz (its final state)")
    assert client.get(url(shallow)).json()["reason"] == "the run has no final.npz (its final " \
                                                        "state)"


def test_an_unknown_run_is_404_naming_the_run(env):
    client, _ = env
    r = client.get(url("nope"))
    assert r.status_code == 404 and r.json()["detail"] == "run_id: no run 'nope'"
    r = client.post(url("nope"), json={"heights": RING_BAND})
    assert r.status_code == 404 and r.json()["detail"] == "run_id: no run 'nope'"


def test_a_second_ring_while_one_is_cut_is_409_and_the_run_is_not_deleted(env, tmp_path):
    """The ring process is held by a job that waits for a file the test writes: the first
    ring waits behind it, marked as being cut, for as long as the test needs."""
    client, settings = env
    run = finished_run(client, "ring_cup")
    gate = tmp_path / "gate"
    held = client.app.state.rings.executor().submit(until_exists, str(gate))
    first: dict = {}
    t = threading.Thread(target=lambda: first.update(r=client.post(
        url(run), json={"heights": RING_BAND})))
    t.start()
    try:
        cutting = until(lambda: client.get(url(run)).json()["cutting"], "never cutting")
        assert cutting.pop("elapsed_s") >= 0
        assert cutting == {"heights_mm": RING_BAND, "cut_angle_deg": 0.0, "newton": None,
                           "stage": "waiting for the process that cuts rings"}
        r = client.post(url(run), json={"heights": RING_BAND, "cut_angle": 45})
        assert r.status_code == 409 and "is being cut from it" in r.json()["detail"]
        assert client.delete(f"/api/runs/{run}").status_code == 409
    finally:
        gate.touch()
        t.join()
        held.result()
    assert first["r"].status_code == 200, first["r"].text
    # deleting the run takes its rings' files with its folder
    folder = settings.runs_dir / run
    assert (folder / f"{first['r'].json()['name']}.npz").is_file()
    assert client.delete(f"/api/runs/{run}").status_code == 204
    assert not folder.exists()


def _heard(monkeypatch, cutter: RingCutter) -> list[dict]:
    """Every report of its child the server reads from now on, in order, of the rings asked
    for from now on. An earlier ring's last reports may still be on their way: its answer
    comes back on the pool's own pipe, apart from the reports' queue, and the server reads
    those late ones by their cut's number and drops them (RingCutter._heard)."""
    seen: list[dict] = []
    heard = cutter._heard
    first = next(cutter._numbers)
    cutter._numbers = itertools.count(first)  # for good: numbers never given twice

    def hear(msg: dict) -> None:
        if msg["cut"] >= first:
            seen.append(msg)
        heard(msg)

    monkeypatch.setattr(cutter, "_heard", hear)
    return seen


def _cut_held(client, run: str, body: dict, stage: str, gate: Path,
              iteration: int | None = None) -> tuple[threading.Thread, dict]:
    """A ring asked for (``body``) in a thread, its child held once it has reported ``stage``
    (at ``iteration``) until ``gate`` exists; the thread and where its answer goes (``r``)."""
    client.app.state.rings.executor().submit(hold_ring_at, stage, str(gate), iteration).result()
    out: dict = {}
    t = threading.Thread(target=lambda: out.update(r=client.post(url(run), json=body)))
    t.start()
    return t, out


def test_a_ring_being_cut_is_listed_with_its_stage_then_gone(env, cup, tmp_path, monkeypatch):
    """The child held at the closed ring's release, as Newton starts: the ring is listed
    with that stage, the residual it starts from and the time so far; let go, it is cut
    and no longer listed. Every report the server read, in order: each stage once, in the
    test's order, each release's iterates counted up to the iterations its answer gives."""
    client, _ = env
    run, _ = cup
    seen = _heard(monkeypatch, client.app.state.rings)
    gate = tmp_path / "gate"
    t, out = _cut_held(client, run, {"heights": RING_BAND, "cut_angle": 90}, STAGES["closed"],
                       gate, iteration=0)
    try:
        # the stage is reported as it starts, then Newton's first iterate, where it is held
        listed = until(lambda: (c := client.get(url(run)).json()["cutting"]) and
                       c["stage"] == STAGES["closed"] and c["newton"] and c,
                       "the release's first iterate never listed")
        assert listed["heights_mm"] == RING_BAND and listed["cut_angle_deg"] == 90
        newton = listed["newton"]
        assert newton["iteration"] == 0 and 0 < newton["target_N"] < newton["residual_N"]
        later = client.get(url(run)).json()["cutting"]
        assert later["stage"] == listed["stage"] and later["newton"] == newton  # held
        assert later["elapsed_s"] >= listed["elapsed_s"] >= 0
    finally:
        gate.touch()
        t.join()
    assert out["r"].status_code == 200, out["r"].text
    assert client.get(url(run)).json()["cutting"] is None
    until(lambda: seen and seen[-1]["stage"] == SAVE, "the saving never reported")
    assert {(m["kind"], m["run"]) for m in seen} == {("ring", run)}
    assert len({m["cut"] for m in seen}) == 1
    stages = [m["stage"] for m in seen]
    assert list(dict.fromkeys(stages)) == [READ, *STAGES.values(), SAVE]
    solver = out["r"].json()["solver"]
    for key, release in (("closed", "closed"), ("opened", "split")):
        iterations = [m["newton"]["iteration"] for m in seen if m["stage"] == STAGES[key]
                      and m["newton"]]
        assert iterations == list(range(solver[release]["iterations"] + 1)), key
    assert all(m["newton"] is None for m in seen
               if m["stage"] not in (STAGES["closed"], STAGES["opened"]))


def test_a_cut_that_fails_is_a_422_and_no_longer_listed(env, cup, tmp_path, monkeypatch):
    """Heights with no closed ring, the child held as it cuts the band: listed so, then
    refused as before, and not listed any more; nothing written. A late report of a cut that
    has ended moves no ring listed after it."""
    client, _ = env
    run, folder = cup
    cutter = client.app.state.rings
    seen = _heard(monkeypatch, cutter)
    before = {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file()}
    gate = tmp_path / "gate"
    t, out = _cut_held(client, run, {"heights": [3, 5]}, STAGES["band"], gate)
    try:
        listed = until(lambda: (c := client.get(url(run)).json()["cutting"]) and
                       c["stage"] == STAGES["band"] and c, "the band never listed")
        assert listed["heights_mm"] == [3, 5] and listed["newton"] is None
    finally:
        gate.touch()
        t.join()
    r = out["r"]
    assert r.status_code == 422 and r.json()["detail"].startswith(
        "heights: 3-5 mm is not one closed ring"), r.text
    assert client.get(url(run)).json()["cutting"] is None
    assert {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file()} == before
    assert [m["stage"] for m in seen] == [READ, STAGES["band"]]
    # a report of that cut, come after it ended, onto a ring cut from the run since
    gate = tmp_path / "gate2"
    held = cutter.executor().submit(until_exists, str(gate))
    t = threading.Thread(target=lambda: out.update(r=client.post(url(run), json={
        "heights": [3, 5]})))
    t.start()
    try:
        until(lambda: client.get(url(run)).json()["cutting"], "never cutting")
        cutter._heard({**seen[-1], "stage": SAVE})
        assert client.get(url(run)).json()["cutting"]["stage"] == \
            "waiting for the process that cuts rings"
    finally:
        gate.touch()
        t.join()
        held.result()
    assert out["r"].status_code == 422


def test_a_run_is_not_deleted_between_a_rings_request_and_its_cut(env, monkeypatch):
    """The race a DELETE had with a ring: the ring is marked as being cut before the route
    checks the run (the check is held here until the test lets it go), so the DELETE is a
    409 and the ring's answer a 4xx, not a 500 from a folder gone under it; a ring asked for
    while the run is being deleted (the deletion held) is a 409, and once the run is gone a
    404."""
    from server.routers import split_ring as route

    client, settings = env
    run = finished_run(client, "ring_cup")
    checking, go = threading.Event(), threading.Event()
    real = route.cuttable

    def held(*args):
        if not checking.is_set():  # the POST's check; the GETs' pass
            checking.set()
            assert go.wait(HANG)
        return real(*args)

    monkeypatch.setattr(route, "cuttable", held)
    out: dict = {}
    t = threading.Thread(target=lambda: out.update(r=client.post(
        url(run), json={"heights": [3, 5]})))  # refused by the child, quickly
    t.start()
    try:
        assert checking.wait(HANG)
        assert client.get(url(run)).json()["cutting"]["heights_mm"] == [3, 5]
        r = client.delete(f"/api/runs/{run}")
        assert r.status_code == 409 and "is being cut from it" in r.json()["detail"], r.text
    finally:
        go.set()
        t.join()
    assert out["r"].status_code == 422, out["r"].text
    assert out["r"].json()["detail"].startswith("heights: 3-5 mm is not one closed ring")
    monkeypatch.setattr(route, "cuttable", real)
    # the other way round: a DELETE under way (held as it starts)
    manager = client.app.state.manager
    deleting, go = threading.Event(), threading.Event()
    delete = manager.delete

    def held_delete(*args, **kw):
        deleting.set()
        assert go.wait(HANG)
        return delete(*args, **kw)

    monkeypatch.setattr(manager, "delete", held_delete)
    t = threading.Thread(target=lambda: out.update(d=client.delete(f"/api/runs/{run}")))
    t.start()
    try:
        assert deleting.wait(HANG)
        r = client.post(url(run), json={"heights": RING_BAND})
        assert r.status_code == 409 and r.json()["detail"] == f"run {run!r} is being deleted"
    finally:
        go.set()
        t.join()
    assert out["d"].status_code == 204
    assert not (settings.runs_dir / run).exists()
    r = client.post(url(run), json={"heights": RING_BAND})
    assert r.status_code == 404 and run in r.json()["detail"], r.text


def test_a_final_state_without_its_scene_or_a_folder_gone_name_the_run(env, tmp_path):
    """The child's reasons name the request's run_id, not the server's folder; a folder that
    goes (outside the service) while the ring waits for the process is a 404 naming it."""
    client, settings = env
    run = finished_run(client, "ring_cup")
    folder = settings.runs_dir / run
    with np.load(folder / "final.npz") as z:
        data = {k: v for k, v in z.items() if k != "scene"}
    np.savez_compressed(folder / "final.npz", **data)
    r = client.post(url(run), json={"heights": RING_BAND})
    assert r.status_code == 422 and r.json()["detail"].startswith(
        f"run_id: {run}: final.npz: no scene in it"), r.text
    assert str(settings.runs_dir) not in r.json()["detail"]
    gate = tmp_path / "gate"
    held = client.app.state.rings.executor().submit(until_exists, str(gate))
    t = threading.Thread(target=lambda: data.update(r=client.post(
        url(run), json={"heights": RING_BAND})))
    t.start()
    try:
        until(lambda: client.get(url(run)).json()["cutting"], "never cutting")
        shutil.rmtree(folder)
    finally:
        gate.touch()
        t.join()
        held.result()
    r = data["r"]
    assert r.status_code == 404 and r.json()["detail"].startswith(
        f"run_id: {run}: its folder is gone"), r.text
    assert client.get(url(run)).json()["reason"] == "the run has no final.npz (its final state)"


def test_a_process_that_died_forgets_only_its_own_pool():
    """Two rings on one process that dies: the second's failure must not drop the process a
    third ring started meanwhile (it would never be closed)."""
    cutter = RingCutter()
    newer = object()

    class Died:
        def submit(self, *args):
            cutter._pool = newer  # another request replaced the broken pool meanwhile
            raise BrokenProcessPool("the child died")

        def shutdown(self, wait=True):
            self.down = True

    died = cutter._pool = Died()
    with pytest.raises(Unsolved, match="the process cutting the ring died"):
        asyncio.run(cutter.cut("r1", Path("."), [1.0, 2.0], 0.0, lambda: None))
    assert cutter._pool is newer and died.down and cutter.cutting == {}
    cutter._pool = died
    with pytest.raises(Unsolved):
        asyncio.run(cutter.cut("r1", Path("."), [1.0, 2.0], 0.0, lambda: None))
    assert cutter._pool is newer  # set by submit, kept


def test_a_folder_gone_under_the_child_is_a_404_other_os_errors_stay_500(tmp_path):
    cutter = RingCutter()

    async def vanished(*args):
        raise FileNotFoundError(2, "No such file or directory")

    cutter._solve = vanished
    with pytest.raises(NotFound, match="run_id: r1: its folder is gone"):
        asyncio.run(cutter.cut("r1", tmp_path / "gone", [1.0, 2.0], 0.0, lambda: None))
    with pytest.raises(FileNotFoundError):  # the folder is there: not the client's doing
        asyncio.run(cutter.cut("r1", tmp_path, [1.0, 2.0], 0.0, lambda: None))
    assert cutter.cutting == {}


def test_a_release_that_fails_says_why_and_writes_nothing(env):
    """The run's scene, as its final.npz keeps it, allowed one Newton iteration: the closed
    ring's release needs more."""
    client, settings = env
    run = finished_run(client, "ring_cup")
    folder = settings.runs_dir / run
    with np.load(folder / "final.npz") as z:
        data = dict(z)
    scene = json.loads(str(data["scene"]))
    scene["solver"]["max_iterations"] = 1
    data["scene"] = np.array(json.dumps(scene))
    np.savez_compressed(folder / "final.npz", **data)
    before = {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file()}
    r = client.post(url(run), json={"heights": RING_BAND})
    detail = r.json()["detail"]
    assert r.status_code == 422 and detail.startswith(f"heights: ring {RING_BAND[0]:g}-"
                                                      f"{RING_BAND[1]:g} mm, cut at 0 deg: "
                                                      "the ring's release did not converge")
    assert "no convergence in 1 iterations (residual " in detail  # the solver's numbers
    assert detail.endswith("nothing was written")
    assert {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file()} == before
    assert not list(folder.glob("*split_ring*"))
    listed = client.get(url(run)).json()
    assert listed["rings"] == [] and listed["cutting"] is None


def test_the_openapi_schema_declares_the_routes(env):
    client, _ = env
    paths = client.get("/openapi.json").json()["paths"]
    post = paths["/api/runs/{run_id}/split_ring"]["post"]
    assert {"200", "404", "409", "422"} <= set(post["responses"])
    assert "get" in paths["/api/runs/{run_id}/split_ring"]
    files = paths["/api/runs/{run_id}/split_ring/{ring}/{format}"]["get"]["responses"]
    assert {"200", "404", "422"} <= set(files)
    assert set(files["200"]["content"]) == {"application/zip", "application/octet-stream"}

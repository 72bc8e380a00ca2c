"""Runs compared side by side through the API (TestClient, no viewer; the page itself:
tests/service/test_compare_browser.py):

- ``/api/compare``: the curves are each run's own plots (punch force against stroke, probes),
  the summary rows each run's summary with the differences from the first run, the line names
  what differs (a friction override, the element, a live change);
- ``/api/compare/thickness``: each run's final thickness (final.npz, in mm), A - B where the
  meshes are the same, the reason where they are not;
- bad input: unknown run ids (404 naming them), fewer than two (422), a run named twice, a run
  without a final state (409);
- a ``q3t sweep`` written inside the runs folder, listed and opened as runs (each case's curves
  its result.json's steps), again without doubling, and paths that lead out refused.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from server.records import RunFiles
from tests.support import ROOT
from tests.support.scenes import tiny_cup_toml
from tests.support.service import HANG, finished_run, in_process, until, wait_state

ENDED = {"finished", "failed", "stopped"}
# the compared numbers are the runs' own, scaled to kN / mm / %: equal up to that rounding
SCALED = 1e-12
# final.npz's thickness is sent in mm rounded to 1e-5 mm (a hundredth of a micrometre): a
# difference of two such values is within this of the exact one
ROUNDED_MM = 1.1e-5


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("compare")
    with in_process(tmp, {"tiny_cup": tiny_cup_toml()}) as (client, settings):
        yield client, settings


@pytest.fixture(scope="module")
def runs(env):
    """Four finished runs of tiny_cup: A as written (q3t), B with half its friction and a
    live doubling of the load from step 3, C linear, D on a finer mesh."""
    client, _ = env
    a = finished_run(client)
    b = client.post("/api/runs", json={"scene": "tiny_cup", "paused": True, "overrides": {
        "tools.0.friction": 0.05, "tools.1.friction": 0.05}}).json()["id"]
    wait_state(client, b, {"paused"})
    for _ in range(2):
        step = client.get(f"/api/runs/{b}").json()["step"]
        client.post(f"/api/runs/{b}/step")
        until(lambda s=step: client.get(f"/api/runs/{b}").json()["step"] > s, "no step")
    r = client.put(f"/api/runs/{b}/parameters/friction_scale", json={"value": 2.0})
    assert r.status_code == 202 and r.json()["applied"], r.text
    client.post(f"/api/runs/{b}/resume")
    assert wait_state(client, b, ENDED)["state"] == "finished"
    c = finished_run(client, element="linear")
    d = finished_run(client, overrides={"mesh.edge_length": 0.002})
    return a, b, c, d


def _run_plots(client, run: str) -> dict:
    return client.get(f"/api/runs/{run}/plots").json()


def test_curves_are_each_runs_own(env, runs):
    client, _ = env
    a, b, c, _ = runs
    got = client.get(f"/api/compare?runs={a},{b},{c}")
    assert got.status_code == 200, got.text
    cmp = got.json()
    assert [r["letter"] for r in cmp["runs"]] == ["A", "B", "C"]
    assert [r["id"] for r in cmp["runs"]] == [a, b, c]
    for letter, run in zip("ABC", (a, b, c), strict=True):
        own = _run_plots(client, run)
        punch = [p for p in cmp["punches"] if p["run"] == run]
        assert len(punch) == 1 and punch[0]["letter"] == letter and punch[0]["tool"] == "punch"
        mine = own["punches"][0]
        assert punch[0]["steps"] == mine["steps"]
        assert punch[0]["force"] == mine["force"] and punch[0]["force"]["unit"] == "kN"
        assert punch[0]["stroke"] == mine["stroke"] and punch[0]["stroke"]["unit"] == "mm"
        probes = {p["name"]: p for p in cmp["probes"] if p["run"] == run}
        assert set(probes) == {"punch_force", "min_thickness", "centre_dz"}
        for p in own["probes"]:
            assert probes[p["name"]]["values"] == p["values"]
            assert probes[p["name"]]["unit"] == p["unit"]
    # and the records behind them: min_thickness in mm is the records' value in m, scaled
    recs = client.get(f"/api/runs/{b}").json()["records"]
    mm = next(p for p in cmp["probes"] if p["run"] == b and p["name"] == "min_thickness")
    assert mm["unit"] == "mm"
    np.testing.assert_allclose(mm["values"], [1e3 * r["probes"]["min_thickness"]
                                              for r in recs], rtol=SCALED)


def test_summaries_side_by_side_with_differences(env, runs):
    client, settings = env
    a, b, c, _ = runs
    cmp = client.get(f"/api/compare?runs={a},{b},{c}").json()
    results = [json.loads((settings.runs_dir / r / "result.json").read_text())
               for r in (a, b, c)]
    rows = {(r["name"], r["tool"]): r for r in cmp["summary"]}
    for res_i, res in enumerate(results):
        for e in res["summary"]:
            if not isinstance(e["display"]["value"], float):
                continue
            row = rows[(e["name"], e.get("tool"))]
            assert row["unit"] == e["display"]["unit"]
            assert row["values"][res_i] == e["display"]["value"]
            assert row["flags"][res_i] == e.get("flag")  # a thinning's limit, the mesh's earing
    peak = rows[("peak_punch_force", "punch")]
    assert peak["unit"] == "kN" and None not in peak["values"]
    ref = peak["values"][0]
    for i, v in enumerate(peak["values"]):
        assert peak["delta"][i] == pytest.approx(v - ref, rel=SCALED, abs=SCALED)
        assert peak["delta_pct"][i] == pytest.approx(100 * (v - ref) / abs(ref), rel=SCALED,
                                                     abs=SCALED)
    assert peak["delta"][0] == 0 and peak["delta_pct"][0] == 0
    assert peak["values"][1] != ref  # half the friction: another force
    # a quantity in % differs by points, not by a percentage of a percentage
    margin = rows[("max_thinning", None)]
    assert margin["unit"] == "%" and set(margin["delta_pct"]) == {None}
    cost = rows[("dofs", None)]
    assert cost["values"] == [float(r["counts"]["dofs"]) for r in results]


def test_the_summary_table_downloads_as_csv(env, runs):
    """/api/compare/summary.csv: the table the page shows, a row per quantity with its unit,
    each run's value (headed by run and element), each later run's difference from A and in %
    of A, to the CSV export's six digits."""
    import csv
    import io

    from sim.frames.export import DIGITS

    client, _ = env
    a, b, c, _ = runs
    r = client.get(f"/api/compare/summary.csv?runs={a},{b},{c}")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/csv")
    assert f'filename="compare-{a}-and-2-more.csv"' in r.headers["content-disposition"]
    table = list(csv.reader(io.StringIO(r.text)))
    # under the quantities, after a blank line, what the runs differ in: a row per setting,
    # each run's value in the form's unit, and their live changes
    blank = table.index([])
    table, settings = table[:blank], table[blank + 1:]
    assert settings[0] == ["setting", "unit", f"A: {a}", f"B: {b}", f"C: {c}"]
    assert ["shell.element", "", "q3t", "q3t", "linear"] in settings
    assert ["tools.punch.friction", "", "0.1", "0.05", "0.1"] in settings
    assert settings[-1] == ["live changes", "", "", "Friction × 2 from step 3", ""]
    assert len(settings) == 5  # the three settings of test_the_line_says_what_differs
    cmp = client.get(f"/api/compare?runs={a},{b},{c}").json()
    head = table[0]
    assert head[:2] == ["quantity", "unit"] and head[-1] == "flags"
    assert head[2:5] == [f"{x['letter']}: {x['id']} ({x['element']})" for x in cmp["runs"]]
    assert head[5:9] == ["B - A", "C - A", "B - A [% of A]", "C - A [% of A]"]
    assert len(table) - 1 == len(cmp["summary"])
    half = 0.5 * 10.0 ** (1 - DIGITS)  # written to six significant digits
    for line, row in zip(table[1:], cmp["summary"], strict=True):
        assert line[1] == row["unit"]
        for got, want in zip(line[2:9], row["values"] + row["delta"][1:] + row["delta_pct"][1:],
                             strict=True):
            assert got == "" if want is None else float(got) == pytest.approx(want, rel=half,
                                                                             abs=1e-300)
    peak = next(line for line in table[1:] if line[0] == "Peak punch force (punch)")
    assert peak[1] == "kN" and peak[2] and peak[5]
    assert client.get(f"/api/compare/summary.csv?runs={a}").status_code == 422  # one run
    # two runs: named by both
    two = client.get(f"/api/compare/summary.csv?runs={a},{c}")
    assert f'filename="compare-{a}-{c}.csv"' in two.headers["content-disposition"]


def test_the_line_says_what_differs(env, runs):
    client, _ = env
    a, b, c, _ = runs
    d = client.get(f"/api/compare?runs={a},{b},{c}").json()["differs"]
    items = {it["what"]: it["values"] for it in d["items"]}
    assert items["shell.element"] == ["q3t", "q3t", "linear"]
    assert items["tools.punch.friction"] == [0.1, 0.05, 0.1]
    assert items["tools.die.friction"] == [0.1, 0.05, 0.1]
    assert "scene" not in items and len(items) == 3  # nothing else differs
    # a tool's field found by its name (tools.punch: tools.0 in the schema); friction has no unit
    assert {it["what"]: it["unit"] for it in d["items"]}["tools.punch.friction"] == "1"
    assert d["live"]["B"] == [{"step": 3, "name": "friction_scale", "value": 2.0,
                               "label": "Friction ×"}]
    assert d["live"]["A"] == d["live"]["C"] == []
    line = d["line"]
    assert line.startswith("A/B/C differ in: shell.element q3t | q3t | linear")
    assert "tools.punch.friction 0.1 | 0.05 | 0.1" in line
    assert "B: Friction × 2 from step 3" in line
    same = client.get(f"/api/compare?runs={a},{a}")
    assert same.status_code == 422  # a run named twice
    alike = client.get(f"/api/compare?runs={a},{c}").json()["differs"]
    assert [it["what"] for it in alike["items"]] == ["shell.element"]


def test_thickness_difference_on_the_same_mesh(env, runs):
    client, settings = env
    a, _, c, _ = runs
    cmp = client.get(f"/api/compare?runs={a},{c}").json()
    assert cmp["thickness"] == {"a": a, "b": c, "available": True, "reason": None}
    t = client.get(f"/api/compare/thickness?runs={a},{c}")
    assert t.status_code == 200, t.text
    t = t.json()
    fa, fc = (np.load(settings.runs_dir / r / "final.npz") for r in (a, c))
    ha, hc = 1e3 * fa["thickness"], 1e3 * fc["thickness"]
    assert t["unit"] == "mm" and t["difference"]["available"]
    np.testing.assert_allclose(t["a"]["thickness"], ha, atol=ROUNDED_MM / 2)
    np.testing.assert_allclose(t["b"]["thickness"], hc, atol=ROUNDED_MM / 2)
    np.testing.assert_allclose(t["difference"]["values"], ha - hc, atol=ROUNDED_MM)
    assert t["difference"]["max_abs"] > 0  # linear and q3t thin the cup differently
    assert t["a"]["faces"] == fa["faces"].tolist() == t["b"]["faces"]
    # the formed mid-surface: the punch drew the centre down 2 mm (its travel), the rim less
    formed = np.array(t["a"]["formed"])
    rest = np.array(t["a"]["rest"])
    assert np.abs(rest[:, 2]).max() < 1e-9 and formed[:, 2].min() < -1.0
    assert t["range"] == [pytest.approx(min(ha.min(), hc.min()), abs=ROUNDED_MM),
                          pytest.approx(max(ha.max(), hc.max()), abs=ROUNDED_MM)]


def test_no_difference_map_across_meshes(env, runs):
    client, _ = env
    a, _, _, d = runs
    cmp = client.get(f"/api/compare?runs={a},{d}").json()
    assert not cmp["thickness"]["available"]
    assert "the meshes differ" in cmp["thickness"]["reason"]
    t = client.get(f"/api/compare/thickness?runs={a},{d}").json()
    assert t["difference"] == {"available": False, "reason": cmp["thickness"]["reason"],
                               "values": None, "max_abs": None}
    # each run's own thickness still shows (the A/B toggle)
    assert len(t["b"]["thickness"]) > len(t["a"]["thickness"])
    # in the form's units, labelled: the schema's unit by the field's path (tools by name here)
    assert "mesh.edge_length 3 | 2 mm" in cmp["differs"]["line"]
    item = next(it for it in cmp["differs"]["items"] if it["what"] == "mesh.edge_length")
    assert item["unit"] == "m" and item["values"] == [0.003, 0.002]


def test_bad_input(env, runs):
    client, _ = env
    a, b, _, _ = runs
    r = client.get(f"/api/compare?runs={a},nope-1,nope-2")
    assert r.status_code == 404
    assert "'nope-1'" in r.json()["detail"] and "'nope-2'" in r.json()["detail"]
    for q in (f"runs={a}", "runs=", f"runs={a},,"):
        r = client.get(f"/api/compare?{q}")
        assert r.status_code == 422 and "at least two" in r.json()["detail"], q
    assert client.get("/api/compare").status_code == 422  # runs is required
    r = client.get(f"/api/compare?runs={a},{'x' * 300}")
    assert r.status_code == 404
    r = client.get(f"/api/compare?runs={a},../etc")
    assert r.status_code == 404 and "'../etc'" in r.json()["detail"]
    assert client.get(f"/api/compare/thickness?runs={b}").status_code == 422


def test_a_run_still_going_is_compared_in_part(env, runs):
    client, _ = env
    a = runs[0]
    live = client.post("/api/runs", json={"scene": "tiny_cup", "paused": True}).json()["id"]
    try:
        wait_state(client, live, {"paused"})
        client.post(f"/api/runs/{live}/step")
        until(lambda: client.get(f"/api/runs/{live}").json()["step"] >= 1, "no first step")
        cmp = client.get(f"/api/compare?runs={a},{live}")
        assert cmp.status_code == 200, cmp.text
        cmp = cmp.json()
        head = cmp["runs"][1]
        assert not head["result"] and "paused: compared up to step 1" in head["note"]
        assert all(row["values"][1] is None for row in cmp["summary"])
        assert not cmp["thickness"]["available"]
        assert "final state is written when it ends" in cmp["thickness"]["reason"]
        t = client.get(f"/api/compare/thickness?runs={a},{live}")
        assert t.status_code == 409 and live in t.json()["detail"]
        # stopped at step 1, it has the part there: its values, and no difference from a
        # formed part's (a browser review read "punch force at the end +290 %" off a run
        # that failed halfway), except the mesh's size
        client.post(f"/api/runs/{live}/stop")
        wait_state(client, live, ENDED)
        cmp = client.get(f"/api/compare?runs={a},{live}").json()
        assert cmp["runs"][1]["state"] == "stopped" and cmp["runs"][1]["result"]
        assert [h["comparable"] for h in cmp["runs"]] == [True, False]
        rows = {row["name"]: row for row in cmp["summary"] if row["tool"] is None}
        assert rows["min_thickness"]["values"][1] is not None
        for row in cmp["summary"]:
            shown = row["delta"][1] is not None
            assert shown == (row["name"] in ("elements", "dofs")), row
            assert row["delta_pct"][1] is None or shown
        import csv
        import io

        table = list(csv.reader(io.StringIO(
            client.get(f"/api/compare/summary.csv?runs={a},{live}").text)))
        # the file says how B ended, as the page's column head does
        assert table[0][3].endswith(f" (q3t, stopped at step {cmp['runs'][1]['step']} of "
                                    f"{cmp['runs'][1]['n_steps']})"), table[0]
        thinnest = next(row for row in table if row and row[0] == "Minimum thickness")
        assert thinnest[4:6] == ["", ""], thinnest  # B - A, and in % of A
    finally:
        client.post(f"/api/runs/{live}/stop")
        wait_state(client, live, ENDED)


def _sweep(settings, name: str) -> None:
    """``q3t sweep tiny_cup`` over the element into ``runs/<name>``, as a user runs it."""
    out = subprocess.run(
        [sys.executable, "-m", "sim.apps", "sweep", str(settings.scenes_dir / "tiny_cup.toml"),
         "--grid", "shell.element=linear,q3t", "--grid", "mesh.edge_length=0.003,-1",
         "--workers", "1", "--out", str(settings.runs_dir / name)],
        cwd=ROOT, capture_output=True, text=True, timeout=HANG,
        env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert out.returncode == 0, out.stderr


def test_sweep_cases_open_as_runs(env):
    client, settings = env
    _sweep(settings, "sweep-element")
    listed = client.get("/api/sweeps").json()
    sw = next(s for s in listed if s["path"] == "sweep-element")
    assert (sw["scene"], sw["cases"], sw["with_results"], sw["imported"]) == (
        "tiny_cup", 4, 2, 0)  # the negative edge lengths are invalid cases
    r = client.post("/api/sweeps/import", json={"path": "sweep-element"})
    assert r.status_code == 200, r.text
    rep = r.json()
    assert len(rep["imported"]) == 2 and rep["present"] == []
    assert [s["case"] for s in rep["skipped"]] == [1, 3]
    assert all("invalid" in s["reason"] and "mesh.edge_length" in s["reason"]
               for s in rep["skipped"])
    sweep = json.loads((settings.runs_dir / "sweep-element" / "sweep.json").read_text())
    for rid, row in zip(rep["imported"], [sweep["cases"][0], sweep["cases"][2]], strict=True):
        st = client.get(f"/api/runs/{rid}").json()
        assert st["state"] == "finished" and st["overrides"] == row["overrides"]
        res = json.loads((settings.runs_dir / "sweep-element" / row["folder"]
                          / "result.json").read_text())
        assert st["records"] == res["steps"]
        plots = _run_plots(client, rid)
        assert plots["punches"][0]["tool"] == "punch"
        assert plots["punches"][0]["stroke"]["values"][-1] == pytest.approx(2.0, rel=1e-6)
    cmp = client.get("/api/compare?runs=" + ",".join(rep["imported"])).json()
    assert [it["what"] for it in cmp["differs"]["items"]] == ["shell.element"]
    assert cmp["thickness"]["available"]
    again = client.post("/api/sweeps/import", json={"path": "sweep-element"}).json()
    assert again["imported"] == [] and again["present"] == rep["imported"]
    assert next(s for s in client.get("/api/sweeps").json()
                if s["path"] == "sweep-element")["imported"] == 2
    # the next server finds them as runs it made itself
    loaded = RunFiles(settings.runs_dir).load()
    assert all(loaded[rid].state == "finished" for rid in rep["imported"])


def test_sweep_import_refuses_paths_out_of_the_runs_folder(env):
    client, settings = env
    (settings.runs_dir.parent / "outside").mkdir(exist_ok=True)
    (settings.runs_dir.parent / "outside" / "sweep.json").write_text('{"cases": []}')
    for path in ("../outside", "/etc", "a\\b", "sweep-element/../../outside", "0" * 300,
                 "a/b/c"):
        r = client.post("/api/sweeps/import", json={"path": path})
        assert r.status_code == 422 and "runs folder" in r.json()["detail"], path
    os.symlink(settings.runs_dir.parent / "outside", settings.runs_dir / "link")
    r = client.post("/api/sweeps/import", json={"path": "link"})
    assert r.status_code == 422 and "leads out" in r.json()["detail"]
    r = client.post("/api/sweeps/import", json={"path": "no-such-sweep"})
    assert r.status_code == 404 and "no sweep" in r.json()["detail"]
    r = client.post("/api/sweeps/import", json={"path": 3})
    assert r.status_code == 422
    assert not list(settings.runs_dir.glob(".import-*"))  # nothing half-made


def test_a_damaged_final_state_is_a_conflict_not_a_crash(env, runs):
    client, settings = env
    a, _, c, _ = runs
    path = settings.runs_dir / c / "final.npz"
    kept = path.read_bytes()
    try:
        path.write_bytes(kept[: len(kept) // 2])  # a copy cut short
        t = client.get(f"/api/compare/thickness?runs={a},{c}")
        assert t.status_code == 409 and "final.npz cannot be read" in t.json()["detail"]
        cmp = client.get(f"/api/compare?runs={a},{c}")
        assert cmp.status_code == 200 and not cmp.json()["thickness"]["available"]
        assert c in cmp.json()["thickness"]["reason"]
    finally:
        path.write_bytes(kept)

"""Two runs at the same punch stroke through the API (``/api/compare/frames``; the page:
tests/service/test_compare3d_browser.py), on a server that saves every step's frame:

- frames are matched by stroke, not step: A (tool speed 1, 0.5 mm a step) and B (tool speed
  0.5, 0.25 mm a step) show their frames at 1 mm of stroke, steps 2 and 4; the shapes and
  thicknesses are the frames' own (frames/step-NNNNNN.npz, in mm), A - B their difference;
- between two frames each run shows its nearest and says its stroke; no stroke: the deepest;
- bad input: an unknown run (404), a stroke out of range or not a number (422 naming
  stroke_mm and the range), a queued run and a run without saved frames (409 saying why);
- the cases of a ``q3t sweep`` save their frames too, and compare at a stroke once imported.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from tests.support import ROOT
from tests.support.scenes import tiny_cup_toml
from tests.support.service import HANG, finished_run, in_process, wait_state

ENDED = {"finished", "failed", "stopped", "cancelled"}
# strokes are sent rounded to 1e-4 mm
STROKE_MM = 1e-4
# thicknesses are sent in mm rounded to 1e-5 mm, positions to 1e-4 mm (of float32 frames:
# about 1e-7 relative, far below either rounding)
THICK_MM, POS_MM = 1.1e-5, 1.1e-4


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("compare-frames")
    with in_process(tmp, {"tiny_cup": tiny_cup_toml()}, record_every=1) as (client, settings):
        yield client, settings


@pytest.fixture(scope="module")
def runs(env):
    """A as written (4 steps of 0.5 mm), B at half the tool speed (8 steps of 0.25 mm)."""
    client, _ = env
    return finished_run(client), finished_run(client, parameters={"tool_speed": 0.5})


def _frames(client, a: str, b: str, stroke: float | None = None):
    q = "" if stroke is None else f"&stroke_mm={stroke}"
    return client.get(f"/api/compare/frames?runs={a},{b}{q}")


def _frame(settings, run: str, step: int) -> dict:
    with np.load(settings.runs_dir / run / "frames" / f"step-{step:06d}.npz") as z:
        return {k: z[k] for k in ("positions", "thickness")}


def test_frames_are_matched_by_stroke_not_step(env, runs):
    client, settings = env
    a, b = runs
    got = _frames(client, a, b, 1.0)
    assert got.status_code == 200, got.text
    t = got.json()
    assert (t["a"]["id"], t["a"]["letter"], t["b"]["id"], t["b"]["letter"]) == (a, "A", b, "B")
    assert (t["a"]["step"], t["b"]["step"]) == (2, 4)
    assert t["a"]["stroke"] == pytest.approx(1.0, abs=STROKE_MM)
    assert t["b"]["stroke"] == pytest.approx(1.0, abs=STROKE_MM)
    assert t["range"] == pytest.approx([0.0, 2.0], abs=STROKE_MM)
    # each run's list of frames: every step saved, its stroke the run's own force-stroke curve's
    listed = {r["id"]: r for r in t["runs"]}
    assert [f["step"] for f in listed[a]["frames"]] == [0, 1, 2, 3, 4]
    assert [f["step"] for f in listed[b]["frames"]] == list(range(9))
    for run in (a, b):
        curve = client.get(f"/api/runs/{run}/plots").json()["punches"][0]
        strokes = {f["step"]: f["stroke"] for f in listed[run]["frames"]}
        for step, s in zip(curve["steps"], curve["stroke"]["values"], strict=True):
            assert strokes[step] == pytest.approx(s, abs=STROKE_MM)
    # the shapes and thicknesses are the saved frames', mid-surface in mm
    for part, run, step in ((t["a"], a, 2), (t["b"], b, 4)):
        f = _frame(settings, run, step)
        np.testing.assert_allclose(part["thickness"], 1e3 * f["thickness"], atol=THICK_MM)
        mid = 1e3 * f["positions"].reshape(2, -1, 3).astype(float).mean(0)  # the two skins
        np.testing.assert_allclose(part["formed"], mid, atol=POS_MM)
        assert min(p[2] for p in part["formed"]) < -0.5  # drawn down into the die: not at rest
    # one box holds every frame of both (the rest state is the widest, the deepest the lowest)
    (x0, x1), (y0, y1), (z0, z1) = t["box"]
    for run in (a, b):
        for f in (settings.runs_dir / run / "frames").glob("step-*.npz"):
            with np.load(f) as z:
                p = 1e3 * z["positions"].reshape(-1, 3)
            assert x0 <= p[:, 0].min() + POS_MM and p[:, 0].max() <= x1 + POS_MM
            assert y0 <= p[:, 1].min() + POS_MM and p[:, 1].max() <= y1 + POS_MM
            assert z0 <= p[:, 2].min() + POS_MM and p[:, 2].max() <= z1 + POS_MM
    both = t["a"]["thickness"] + t["b"]["thickness"]
    assert t["thickness_range"] == pytest.approx([min(both), max(both)], abs=THICK_MM)
    d = t["difference"]
    assert d["available"] and d["reason"] is None
    np.testing.assert_allclose(d["values"], np.subtract(t["a"]["thickness"],
                                                        t["b"]["thickness"]), atol=2 * THICK_MM)
    # the values are sent rounded to 1e-6 mm, max_abs is not
    assert d["max_abs"] == pytest.approx(np.abs(d["values"]).max(), abs=1e-6)


def test_between_frames_each_run_shows_its_nearest(env, runs):
    client, _ = env
    a, b = runs
    t = _frames(client, a, b, 1.2).json()  # A saved 1.0 and 1.5 mm, B 1.0 and 1.25
    assert t["stroke"] == 1.2
    assert (t["a"]["step"], t["b"]["step"]) == (2, 5)
    assert t["a"]["stroke"] == pytest.approx(1.0, abs=STROKE_MM)
    assert t["b"]["stroke"] == pytest.approx(1.25, abs=STROKE_MM)
    deepest = _frames(client, a, b).json()
    assert deepest["stroke"] == pytest.approx(2.0, abs=STROKE_MM)
    assert (deepest["a"]["step"], deepest["b"]["step"]) == (4, 8)
    # deeper, thinner: the thinnest point at 2 mm is thinner than at 0 mm
    start = _frames(client, a, b, 0).json()
    assert (start["a"]["step"], start["b"]["step"]) == (0, 0)
    assert min(deepest["a"]["thickness"]) < min(start["a"]["thickness"])


def test_bad_input(env, runs):
    client, _ = env
    a, b = runs
    r = client.get(f"/api/compare/frames?runs={a},nope")
    assert r.status_code == 404 and "nope" in r.json()["detail"]
    for bad in (2.5, -1, "nan", "inf"):
        r = _frames(client, a, b, bad)
        assert r.status_code == 422, (bad, r.text)
        assert "stroke_mm" in r.json()["detail"] and "0.0000 to 2.0000 mm" in r.json()["detail"]
    r = _frames(client, a, b, "deep")
    assert r.status_code == 422 and "stroke_mm" in r.text
    r = client.get(f"/api/compare/frames?runs={a}")
    assert r.status_code == 422 and "runs" in r.json()["detail"]


def test_queued_run_and_run_without_frames(env, runs):
    client, settings = env
    a, b = runs
    held = client.post("/api/runs", json={"scene": "tiny_cup", "paused": True}).json()["id"]
    queued = client.post("/api/runs", json={"scene": "tiny_cup"}).json()["id"]
    try:
        wait_state(client, held, {"paused"})
        assert client.get(f"/api/runs/{queued}").json()["state"] == "queued"
        r = _frames(client, a, queued)
        assert r.status_code == 409, r.text
        assert queued in r.json()["detail"] and "queued" in r.json()["detail"]
        # a paused run is compared as far as it has got: its first frame, at rest
        t = _frames(client, a, held).json()
        assert t["range"] == [0.0, 0.0] and t["b"]["step"] == 0
    finally:
        for run in (queued, held):
            client.post(f"/api/runs/{run}/stop")
            wait_state(client, run, ENDED)
    # a run whose frames are gone (as an imported sweep case written without them)
    shutil.rmtree(settings.runs_dir / b / "frames")
    r = _frames(client, a, b)
    assert r.status_code == 409 and b in r.json()["detail"]
    assert "no saved frames" in r.json()["detail"]


def test_sweep_cases_compare_at_a_stroke(env):
    client, settings = env
    out = subprocess.run(
        [sys.executable, "-m", "sim.apps", "sweep", str(settings.scenes_dir / "tiny_cup.toml"),
         "--grid", "shell.element=linear,q3t", "--workers", "1",
         "--out", str(settings.runs_dir / "sweep-frames")],
        cwd=ROOT, capture_output=True, text=True, timeout=HANG,
        env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert out.returncode == 0, out.stderr
    for case in ("000", "001"):
        saved = sorted(p.name for p in (settings.runs_dir / "sweep-frames" / "cases" / case
                                        / "frames").iterdir())
        assert saved[0] == "mesh.npz" and "step-000000.npz" in saved
        assert saved[-1] == "step-000004.npz"  # the last state
    rep = client.post("/api/sweeps/import", json={"path": "sweep-frames"}).json()
    a, b = rep["imported"]
    t = _frames(client, a, b)
    assert t.status_code == 200, t.text
    t = t.json()
    assert t["range"] == pytest.approx([0.0, 2.0], abs=STROKE_MM)
    assert (t["a"]["step"], t["b"]["step"]) == (4, 4) and t["difference"]["available"]

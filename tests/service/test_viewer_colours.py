"""The viewer's colours, tools and section plane, on hand-made frames (no solver): a value keeps
its colour across the frames of a run and, with a fixed range, across runs; thinning is coloured
in bands at the user's limits; the FLD zones in one colour each; the legend names what it shows;
the tools' opacity and the section plane act on what is drawn.

The viewer is driven as the bridge drives it (``new_run``, ``show``, ``show_run``) and the GUI
of one connected browser (its own ``ClientView``) as a user sets it (a handle's ``.value``,
which runs its callbacks as a browser's change does).
"""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest

pytest.importorskip("viser")
from server.canvas import FIXED_RANGE, RUN_RANGE, surface_glb  # noqa: E402
from server.clientview import ClientView  # noqa: E402
from server.colormap import THINNING_COLOURS, ZONE_COLOURS, Continuous  # noqa: E402
from server.replay import Replay  # noqa: E402
from server.viewer import Viewer  # noqa: E402
from sim.frames.forming_limits import ZONES  # noqa: E402
from tests.support.service import free_port, until  # noqa: E402
from tests.support.viewer import attached  # noqa: E402

# a strip of 6 vertices along x (2 triangles a square), each vertex its own value
X = np.array([[x, y, 0.0] for x in (0.0, 1e-3, 2e-3) for y in (0.0, 1e-3)], np.float32)
FACES = np.array([[0, 2, 1], [1, 2, 3], [2, 4, 3], [3, 4, 5]], np.uint32)
BOX = np.array([[x, y, z] for x in (-2e-3, 4e-3) for y in (-2e-3, 3e-3) for z in (1e-3, 2e-3)],
               np.float32)
BOX_FACES = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]],
                     np.uint32)


class Stub:
    """The run manager's side of the controls: a recording to replay, nothing else."""

    def __init__(self) -> None:
        self.replays: dict[str, Replay] = {}

    def command(self, view: str, run_id: str | None, cmd: str) -> str:
        return cmd

    def select(self, view: str, run_id: str) -> str:
        return ""

    def set_parameter(self, view: str, run_id: str | None, name: str, value: float) -> str:
        return name

    def scrub(self, run_id: str | None, step: int) -> tuple[dict | None, str]:
        return None, "no frames"

    def recording(self, run_id: str) -> tuple[Replay | None, str]:
        return self.replays.get(run_id), "recording"

    def scaled(self, run_id: str | None) -> dict:
        return {}

    def shows_step(self, view: str, run_id: str | None, step: int | None) -> None:
        pass

    def connected(self, view: str) -> None:
        pass


def frame(run: str, step: int, **fields: list[float]) -> dict:
    return {"run": run, "step": step, "positions": X,
            "fields": {k: np.asarray(v, np.float32) for k, v in fields.items()},
            "tools": {"punch": np.zeros(3, np.float32)}, "probes": {}, "iterations": 0}


@pytest.fixture
def viewer():
    """One browser's view of a viewer (``.v``: the viewer)."""
    v = Viewer("127.0.0.1", free_port(), Stub())
    with attached(v) as cv:
        yield cv
    v.stop()


def live(v: ClientView, run: str, *frames: dict, active: bool = False) -> None:
    """Show ``run`` as the latest run and push ``frames`` to it."""
    v.show_run(run, {}, active=True, controls=("pause", "step", "stop"), line=run)
    v.v.new_run(run, FACES, [{"name": "punch", "vertices": BOX, "faces": BOX_FACES}], run, {})
    for f in frames:
        v.v.show(f, run, final=True)
    v.v.run_status(run, run, active=active, controls=())


def colour_of(v: ClientView, vertex: int) -> tuple[int, ...]:
    key, rgb, _ = v.canvas.painted
    return tuple(int(c) for c in rgb[vertex])


def choose(v: ClientView, label_start: str) -> None:
    v.canvas.field.value = next(o for o in v.canvas.field.options if o.startswith(label_start))


def test_a_value_keeps_its_colour_across_the_frames_of_a_recording(viewer):
    """Vertex 0 holds 1.0 mm in both recorded frames, while the frames' own ranges differ (the
    sheet thins elsewhere): it shows one colour in both, the run's range in the legend."""
    rep = Replay(steps=[0, 5], positions=[X, X], colors=[np.zeros((6, 3), np.uint8)] * 2,
                 fields=[{"thickness_mm": np.array([1.0, 1.0, 1.0, 1.1, 1.2, 1.2], np.float32)},
                         {"thickness_mm": np.array([1.0, 0.9, 0.8, 0.7, 1.2, 1.2], np.float32)}],
                 faces=FACES, tools={"punch": (BOX, BOX_FACES)},
                 poses={"punch": {0: np.zeros(3), 5: np.array([0, 0, -1e-3])}})
    viewer.actions.replays["old"] = rep
    viewer.show_run("old", {}, active=False, controls=(), line="old")
    until(lambda: viewer.mode == "replay", "the recording was not shown")
    last = colour_of(viewer, 0)
    viewer.gui.time.value = 0  # a user scrubbing back
    assert viewer.canvas.frame["step"] == 0
    assert colour_of(viewer, 0) == last
    # each frame over its own min..max (as before) would have painted vertex 0 of step 0 with
    # the colour map's start and of step 5 part way up
    assert colour_of(viewer, 0) != colour_of(viewer, 4)
    legend = viewer.canvas.legend.content
    assert "0.7" in legend and "range of this run" in legend


def test_a_finished_run_colours_over_every_step_its_record_holds(viewer):
    """The recording keeps every N-th step; the run's record holds each field's range over
    every step the solver framed (a step between, thinner than any kept): the view of the
    finished run colours over that, as it was watched live, and its legend says so."""
    rep = Replay(steps=[0, 5], positions=[X, X], colors=[np.zeros((6, 3), np.uint8)] * 2,
                 fields=[{"thickness_mm": np.full(6, 1.0, np.float32)},
                         {"thickness_mm": np.array([1.0, 0.9, 0.8, 0.8, 1.1, 1.1], np.float32)}],
                 faces=FACES, ranges={"thickness_mm": (0.6, 1.2)})
    viewer.actions.replays["every"] = rep
    viewer.show_run("every", {}, active=False, controls=(), line="every")
    until(lambda: viewer.mode == "replay", "the recording was not shown")
    assert viewer.canvas.palette.ranges.of("thickness_mm")[:2] == pytest.approx((0.6, 1.2))
    assert "range of this run, every step" in viewer.canvas.legend.content


def test_a_fixed_range_is_kept_across_runs(viewer):
    live(viewer, "a", frame("a", 1, thickness_mm=[0.5, 0.6, 0.7, 0.8, 0.9, 1.0]))
    assert viewer.canvas.colour["min"].disabled  # the run's own range: nothing to type
    viewer.canvas.colour["range"].value = FIXED_RANGE  # keep run a's range
    assert not viewer.canvas.colour["min"].disabled
    assert (viewer.canvas.colour["min"].value, viewer.canvas.colour["max"].value) == \
        pytest.approx((0.5, 1.0))
    in_a = colour_of(viewer, 2)  # 0.7 mm
    live(viewer, "b", frame("b", 1, thickness_mm=[0.7, 0.7, 0.7, 0.7, 0.75, 2.0]))
    assert colour_of(viewer, 0) == in_a  # 0.7 mm in run b: the colour it had in run a
    assert "fixed" in viewer.canvas.legend.content
    viewer.canvas.colour["max"].value = 2.0  # the user widens it: both ends typed hold
    assert viewer.canvas.palette.ranges.fixed["thickness_mm"] == (0.5, 2.0)
    viewer.canvas.colour["range"].value = RUN_RANGE  # back to run b's own range
    assert colour_of(viewer, 0) == colour_of(viewer, 1) != in_a
    assert "fixed" not in viewer.canvas.legend.content


def test_the_sheet_is_sent_matte_two_sided_with_its_colours_and_normals():
    """three.js gives a glTF primitive without a material a fully metallic one, which without
    reflections to show drew a drawn cup's wall black: the surface carries its own."""
    rgb = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [9, 9, 9]], np.uint8)
    glb = surface_glb(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]),
                      np.array([[0, 1, 2], [0, 1, 3]]), rgb)
    n = struct.unpack("<I", glb[12:16])[0]
    tree = json.loads(glb[20:20 + n])
    (material,) = tree["materials"]
    assert material["pbrMetallicRoughness"]["metallicFactor"] == 0.0
    assert material["doubleSided"]
    (primitive,) = tree["meshes"][0]["primitives"]
    assert primitive["material"] == 0 and {"COLOR_0", "NORMAL"} <= set(primitive["attributes"])
    assert tree["accessors"][primitive["attributes"]["COLOR_0"]]["count"] == len(rgb)


def test_the_range_boxes_show_and_take_a_thickness_to_its_digits(viewer):
    """Around 1 mm a range's ends differ in the first decimals: the boxes' step follows the
    span, so they show 0.934 and 1.233 mm, not 1 and 1 (viser rounds a box to its step)."""
    live(viewer, "a", frame("a", 1, thickness_mm=[0.934, 1.0, 1.1, 1.2, 1.233, 1.233]))
    lo, hi = viewer.canvas.colour["min"], viewer.canvas.colour["max"]
    for box, want in ((lo, 0.934), (hi, 1.233)):
        assert box.value == pytest.approx(want, abs=1e-6)
        assert box.step <= 1e-3 and round(want, box.precision) == pytest.approx(want)
    viewer.canvas.colour["range"].value = FIXED_RANGE
    lo.value = 0.85  # typed
    assert viewer.canvas.palette.ranges.fixed["thickness_mm"] == pytest.approx((0.85, 1.233))


def test_a_bad_fixed_range_is_refused_with_the_reason(viewer):
    live(viewer, "a", frame("a", 1, thickness_mm=[0.5, 0.6, 0.7, 0.8, 0.9, 1.0]))
    viewer.canvas.colour["range"].value = FIXED_RANGE
    before = viewer.canvas.painted[1].copy()
    viewer.canvas.colour["min"].value = 3.0  # above max
    assert "need min < max" in viewer.gui.status.content
    np.testing.assert_array_equal(viewer.canvas.painted[1], before)
    viewer.canvas.colour["max"].value = 5.0  # the other end follows: both typed now hold
    assert viewer.canvas.palette.ranges.fixed["thickness_mm"] == (3.0, 5.0)


def test_thinning_is_coloured_in_bands_at_the_users_limits(viewer):
    values = [-1.0, 5.0, 10.0, 15.0, 20.0, 25.0]
    live(viewer, "a", frame("a", 1, thickness_mm=[1.0] * 6, thinning_pct=values))
    choose(viewer, "Thinning")
    c = THINNING_COLOURS
    # defaults: marginal from 10 %, failure from 20 %; a value on a limit is the worse band
    want = ["thickened", "safe", "marginal", "marginal", "failure", "failure"]
    assert [colour_of(viewer, i) for i in range(6)] == [c[b] for b in want]
    legend = viewer.canvas.legend.content
    assert "marginal 10–20 %" in legend and "failure ≥ 20 %" in legend
    assert viewer.canvas.colour["range"].disabled  # bands, not a range
    viewer.canvas.colour["marginal"].value = 5.0
    viewer.canvas.colour["failure"].value = 15.0
    want = ["thickened", "marginal", "marginal", "failure", "failure", "failure"]
    assert [colour_of(viewer, i) for i in range(6)] == [c[b] for b in want]
    assert "marginal 5–15 %" in viewer.canvas.legend.content
    live(viewer, "b", frame("b", 1, thickness_mm=[1.0] * 6, thinning_pct=values))
    assert colour_of(viewer, 1) == c["marginal"]  # the limits hold for the next run too
    viewer.canvas.colour["marginal"].value = 30.0  # above failure: refused, naming both
    assert "marginal (30.0) < failure (15.0)" in viewer.gui.status.content
    assert colour_of(viewer, 1) == c["marginal"]


def test_fld_zones_have_one_colour_each_and_a_legend(viewer):
    codes = [0, 1, 2, 3, 4, 4]
    live(viewer, "a", frame("a", 1, thickness_mm=[1.0] * 6, fld_zone=codes))
    choose(viewer, "FLD zone")
    assert [colour_of(viewer, i) for i in range(6)] == [ZONE_COLOURS[z] for z in codes]
    legend = viewer.canvas.legend.content
    for name in ZONES.values():
        assert name in legend
    assert legend.index("failure") < legend.index("marginal") < legend.index("safe")


def test_the_legend_says_a_live_runs_range_grows(viewer):
    live(viewer, "a", frame("a", 1, thickness_mm=[1.0, 1.0, 1.0, 1.0, 1.0, 0.9]), active=True)
    assert "range of this run, steps shown so far" in viewer.canvas.legend.content
    viewer.v.show(frame("a", 2, thickness_mm=[1.0, 1.0, 1.0, 1.0, 1.0, 0.8]), "a", final=True)
    assert "0.8" in viewer.canvas.legend.content  # the range grew to hold the new frame
    viewer.v.run_status("a", "a finished", active=False, controls=())
    assert "so far" not in viewer.canvas.legend.content


def test_tool_opacity_and_the_section_plane(viewer):
    live(viewer, "a", frame("a", 1, thickness_mm=[1.0] * 6))
    punch = viewer.canvas.tools["punch"]
    viewer.canvas.view["opacity"].value = 0.8
    assert punch.opacity == pytest.approx(0.8) and punch.visible
    viewer.canvas.view["opacity"].value = 0.0
    assert not punch.visible
    viewer.canvas.view["opacity"].value = 0.35
    assert viewer.canvas.view["at"].min <= 1.0 <= viewer.canvas.view["at"].max  # spans the part, mm
    viewer.canvas.view["section"].value = next(o for o in viewer.canvas.view["section"].options
                                            if o.startswith("x"))
    viewer.canvas.view["at"].value = 1.0  # mm: keep x >= 1 mm
    _, _, faces = viewer.canvas.painted
    assert 0 < len(faces) < len(FACES)
    assert np.all(X[faces, 0].mean(1) >= 1e-3)  # no triangle of the cut half is drawn
    assert 0 < len(punch.faces) < len(BOX_FACES)  # the punch is cut too
    np.testing.assert_array_equal(viewer.canvas.wire.faces, faces)
    viewer.canvas.view["section"].value = "off"
    assert len(viewer.canvas.painted[2]) == len(FACES) and len(punch.faces) == len(BOX_FACES)


def test_a_narrow_scale_tells_its_ends_apart():
    """A uniform 1 mm blank's thickness scale spans its least span, 1 um: four digits read
    '≤ 0.9995 mm | 1 | ≥ 1 mm', the end as the middle; now to the digits that tell them apart."""
    html = Continuous("Thickness", "mm", 0.9995, 1.0005).legend()
    assert "&le; 0.9995 mm" in html and "<span>1 mm</span>" in html and "&ge; 1.0005 mm" in html
    wide = Continuous("Thickness", "mm", 0.8035, 1.529).legend()
    assert "&le; 0.8035 mm" in wide and "<span>1.166 mm</span>" in wide and "&ge; 1.529 mm" in wide
    # round-off about zero beside the others is zero, and no number has an exponent
    noise = Continuous("Major true strain", "%", -1.85e-15, 12.5).legend()
    assert "&le; 0 %" in noise and "<span>6.25 %</span>" in noise, noise
    small = Continuous("Thickness", "mm", 1e-5, 3e-5).legend()
    assert "&le; 0.00001 mm" in small and "<span>0.00002 mm</span>" in small, small

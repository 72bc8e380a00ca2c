"""Two runs at the same punch stroke: each run's deformed mid-surface and thickness (mm) from
the frames it saved as it went (sim.frames.series), and A - B where the meshes are the same.

Runs with another tool_speed or number of steps reach a stroke at other steps, so frames are
matched by the punch's stroke (mm, from the run's step records), never by step: each run shows
its saved frame nearest the stroke asked for, and says which stroke that frame is at. Only the
loading is matched (the frames up to the deepest stroke): a release stage brings the punch
back through strokes it passed, and its last state is the comparison's final one."""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from server.compare import Loaded, same_mesh
from server.problems import Conflict, Invalid
from server.records import ACTIVE, QUEUED
from sim.frames import results, series
from sim.frames.punch import punch_history

MM = 1e3
# the frames' positions are float32: the same blank saved twice rounds alike, but two blanks
# built apart by the same scene may differ in the last bit, about 6e-8 m for a coordinate
# under a metre; far below any element size
FRAME_MESH_TOL = 1e-7
# strokes are sent rounded to 1e-4 mm; a stroke sent back is out of range only past that
STROKE_TOL = 1e-4


@dataclass
class Frames:
    """The frames a run saved during its loading, by stroke: ``steps``, ``strokes`` (mm)
    and ``paths``, shapes ``(k,)``, in step order; ``tool``, the punch whose stroke it is."""

    run: Loaded
    tool: str
    steps: np.ndarray
    strokes: np.ndarray
    paths: list[Path]

    def nearest(self, stroke: float) -> int:
        """The index of the frame nearest ``stroke`` (mm); of two as near, the earlier."""
        return int(np.argmin(np.abs(self.strokes - stroke)))

    def listed(self) -> dict:
        return {"id": self.run.id, "letter": self.run.letter, "tool": self.tool,
                "frames": [{"step": int(k), "stroke": round(float(s), 4)}
                           for k, s in zip(self.steps, self.strokes, strict=True)]}


def no_frames(r: Loaded) -> Conflict:
    state = r.status["state"]
    if state == QUEUED:
        why = "it is queued: it saves frames once it runs"
    elif state in ACTIVE:
        why = "it has saved none yet"
    else:
        why = ("it ended without saving any (a run from before frames were saved, a sweep case "
               "written without them, or a run that failed while it was built)")
    return Conflict(f"runs: run {r.id!r} ({state}) has no saved frames to compare at a "
                    f"stroke: {why}")


def stroke_by_step(r: Loaded) -> tuple[str, dict[int, float]]:
    """The first punch that moves and its stroke (mm) at each step it reports; step 0 is its
    start. Conflict when no punch of the run moves: its frames have no stroke to match."""
    records = r.status.get("records") or []
    waiting = None  # a punch with no step yet: at its start
    for tool, start in (r.status.get("punches") or {}).items():
        rows = [(x["step"], x["tools"][tool]) for x in records if tool in (x.get("tools") or {})]
        if not rows:
            waiting = waiting or tool
            continue
        h = punch_history(rows, np.asarray(start, float))
        if h["stroke"] is not None:
            return tool, {0: 0.0} | dict(zip(h["steps"].tolist(), (MM * h["stroke"]).tolist(),
                                             strict=True))
    if waiting and not records:
        return waiting, {0: 0.0}
    raise Conflict(f"runs: run {r.id!r} has no punch that moves: its frames cannot be "
                   "matched by stroke")


def frames(r: Loaded) -> Frames:
    """The run's saved frames of its loading (up to its deepest stroke), by stroke."""
    found = series.steps(r.folder / series.FOLDER)
    if not found or not (r.folder / series.FOLDER / series.MESH).is_file():
        raise no_frames(r)
    tool, at = stroke_by_step(r)
    kept = [(k, at[k], p) for k, p in found if k in at]
    if not kept:
        raise Conflict(f"runs: run {r.id!r}: none of its saved frames (steps "
                       f"{', '.join(str(k) for k, _ in found[:5])}, ...) is of a step its punch "
                       "reports a stroke for")
    deepest = int(np.argmax([s for _, s, _ in kept]))
    kept = kept[:deepest + 1]
    return Frames(r, tool, np.array([k for k, _, _ in kept]), np.array([s for _, s, _ in kept]),
                  [p for _, _, p in kept])


def common_range(a: Frames, b: Frames) -> tuple[float, float]:
    """The strokes (mm) both runs have saved frames over."""
    lo = max(float(a.strokes.min()), float(b.strokes.min()))
    hi = min(float(a.strokes.max()), float(b.strokes.max()))
    if lo > hi:
        raise Conflict(f"runs: {a.run.id!r} saved frames from {a.strokes.min():.4g} to "
                       f"{a.strokes.max():.4g} mm of stroke, {b.run.id!r} from "
                       f"{b.strokes.min():.4g} to {b.strokes.max():.4g} mm: no stroke in common")
    return lo, hi


def check_stroke(stroke: float | None, lo: float, hi: float) -> float:
    """The stroke asked for (mm), the deepest in common when none; Invalid (422) outside."""
    if stroke is None:
        return hi
    if not np.isfinite(stroke) or not lo - STROKE_TOL <= stroke <= hi + STROKE_TOL:
        raise Invalid(f"stroke_mm: {stroke:g} mm is outside the strokes both runs saved frames "
                      f"for, {lo:.4f} to {hi:.4f} mm")
    return stroke


def state(f: Frames, i: int) -> dict:
    """Frame ``i`` of ``f``: the mid-surface at rest and deformed (m, ``(n_v, 3)``), its
    triangles and its thickness (m, ``(n_v,)``), as compare.final_state gives the last."""
    folder = f.paths[i].parent
    try:
        with np.load(folder / series.MESH) as m, np.load(f.paths[i]) as z:
            rest, faces = m["rest"].astype(float), m["faces"]
            pos, h, t = z["positions"].astype(float), z["thickness"].astype(float), z["time"]
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:  # damaged
        raise Conflict(f"runs: run {f.run.id!r}: its frame of step {f.steps[i]} cannot be read "
                       f"({exc})") from None
    # both skins, ``(2, n_v, 3)``: the mid-surface is their mean
    return {"rest": rest.reshape(2, -1, 3).mean(0), "formed": pos.reshape(2, -1, 3).mean(0),
            "faces": faces, "thickness": h, "time": float(t)}


@lru_cache(maxsize=4096)
def _extent(path: Path, mtime_ns: int) -> np.ndarray:
    """The corner positions' extent of one saved frame, ``(3, 2)`` (m): a frame file is never
    rewritten in place (``mtime_ns`` keys the cache all the same)."""
    with np.load(path) as z:
        p = z["positions"].reshape(-1, 3)
    return np.stack([p.min(0), p.max(0)], axis=1).astype(float)


def box(*runs: Frames) -> list[list[float]]:
    """The extent (mm, ``[[x0, x1], [y0, y1], [z0, z1]]``) of every frame of ``runs``: one
    box that holds the parts at every stroke, so a page can keep its scale as it slides."""
    try:
        ext = [_extent(p, p.stat().st_mtime_ns) for f in runs for p in f.paths]
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:  # damaged
        raise Conflict(f"runs: a saved frame of {', '.join(f.run.id for f in runs)} cannot "
                       f"be read ({exc})") from None
    e = np.stack(ext)
    return np.round(MM * np.stack([e[:, :, 0].min(0), e[:, :, 1].max(0)], axis=1), 4).tolist()


def at_stroke(a: Loaded, b: Loaded, stroke: float | None) -> dict:
    """A and B at the stroke ``stroke`` (mm; None: the deepest both reached): see the
    module's doc. Conflict (409) for a run without frames, Invalid (422) for a stroke out of
    the range both saved frames for."""
    fa, fb = frames(a), frames(b)
    lo, hi = common_range(fa, fb)
    stroke = check_stroke(stroke, lo, hi)
    ia, ib = fa.nearest(stroke), fb.nearest(stroke)
    sa, sb = state(fa, ia), state(fb, ib)
    why = same_mesh(sa, sb, FRAME_MESH_TOL)
    both = np.concatenate([sa["thickness"], sb["thickness"]])
    diff = None if why else MM * (sa["thickness"] - sb["thickness"])
    out = {"unit": "mm", "stroke": stroke, "range": [round(lo, 4), round(hi, 4)],
           "runs": [fa.listed(), fb.listed()], "box": box(fa, fb),
           "a": _part(fa, ia, sa), "b": _part(fb, ib, sb),
           "thickness_range": [round(MM * float(both.min()), 5),
                               round(MM * float(both.max()), 5)],
           "difference": {"available": why is None, "reason": why,
                          "values": None if diff is None else np.round(diff, 6).tolist(),
                          "max_abs": None if diff is None else float(np.abs(diff).max())}}
    return results.finite(out)[0]


def _part(f: Frames, i: int, s: dict) -> dict:
    return {"id": f.run.id, "letter": f.run.letter, "step": int(f.steps[i]),
            "stroke": round(float(f.strokes[i]), 4), "time": s["time"],
            "faces": s["faces"].tolist(), "formed": np.round(MM * s["formed"], 4).tolist(),
            "thickness": np.round(MM * s["thickness"], 5).tolist()}

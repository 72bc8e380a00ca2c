"""Named colour scales for the per-vertex fields, and their legends.

A scale fixes what a value looks like: the same value gets the same colour in every frame it is
drawn with, whatever else the frame holds (replay used to stretch each frame over its own
min..max). Three kinds:

- a continuous field (thickness, plastic strain, von Mises stress, strains) on a named colour map
  over a range the viewer holds (:class:`Ranges`: the run's own range, or one the user set, kept
  across runs);
- thinning in bands at user-set limits: safe, marginal and failure, with thickening shown apart
  (:func:`thinning_scale`);
- the FLD zone of sim.frames.forming_limits, one colour per zone (:data:`ZONE_COLOURS`).

Legends are HTML (emoji swatches need a font that headless browsers lack).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from html import escape

import numpy as np

from sim.frames.forming_limits import FAILURE, INSUFFICIENT, MARGINAL, SAFE, WRINKLING, ZONES
from sim.frames.output import grow
from sim.frames.summary import MARGINAL_SHARE, THINNING_LIMIT
from sim.text import figure

# viridis sampled at 9 evenly spaced points (matplotlib's values, rounded to 8 bits)
VIRIDIS = np.array([[68, 1, 84], [71, 44, 122], [59, 81, 139], [44, 113, 142], [33, 144, 141],
                    [39, 173, 129], [92, 200, 99], [170, 220, 50], [253, 231, 37]], np.float64)
COLORMAPS = {"viridis": VIRIDIS}
# smallest colour span per field: a (nearly) uniform field shows one colour, not its noise
MIN_SPAN = {"thickness_mm": 1e-3, "thinning_pct": 1e-2, "eq_plastic_strain_pct": 1e-3,
            "von_mises_MPa": 1e-2, "major_strain_pct": 1e-3, "minor_strain_pct": 1e-3}
# tools: muted greys with a tint each (never colour-map hues), drawn semi-transparent
TOOL_COLOURS = [(150, 155, 170), (170, 150, 130), (150, 150, 150), (160, 140, 160),
                (140, 150, 120)]
TOOL_OPACITY = 0.2

# Thinning limits (% of the rest thickness) until the user sets others: the summary's rule of
# thumb (sim.frames.summary.THINNING_LIMIT, marginal from half of it), so the bands and the
# summary's flag agree. Set them for the material and part (its forming limit curve, in the
# FLD-zone colours, is the material's own criterion).
FAILURE_PCT = 100.0 * THINNING_LIMIT
MARGINAL_PCT = MARGINAL_SHARE * FAILURE_PCT
THINNING_COLOURS = {"thickened": (90, 140, 215), "safe": (60, 165, 85),
                    "marginal": (240, 185, 30), "failure": (210, 35, 35)}
# the FLD zones in the colours forming simulation packages use for them: failure red, marginal
# amber, safe green, insufficient stretch grey, wrinkling tendency (thickening) purple
ZONE_COLOURS = {FAILURE: (210, 35, 35), MARGINAL: (240, 185, 30), SAFE: (60, 165, 85),
                INSUFFICIENT: (170, 170, 170), WRINKLING: (140, 90, 190)}


def tool_colour(i: int) -> tuple[tuple[int, int, int], float]:
    """RGB and opacity of the i-th tool of a scene."""
    return TOOL_COLOURS[i % len(TOOL_COLOURS)], TOOL_OPACITY


def value_range(values: np.ndarray, min_span: float = 1e-6) -> tuple[float, float]:
    lo, hi = float(np.min(values)), float(np.max(values))
    return widened(lo, hi, min_span)


def widened(lo: float, hi: float, min_span: float) -> tuple[float, float]:
    """``lo..hi``, widened about its middle to ``min_span`` at least: a uniform field would
    otherwise colour its noise. A field that is zero (plastic strain) stays >= 0."""
    if hi - lo >= min_span:
        return lo, hi
    mid = 0.5 * (lo + hi)
    if lo >= 0 and mid < min_span / 2:
        return 0.0, min_span
    return mid - min_span / 2, mid + min_span / 2


def colorize(values: np.ndarray, lo: float, hi: float, name: str = "viridis") -> np.ndarray:
    """Shape: values (n,) -> RGB (n, 3) uint8; values outside lo..hi take the end colours."""
    table = COLORMAPS[name]
    s = np.clip((np.asarray(values, np.float64) - lo) / (hi - lo), 0.0, 1.0) * (len(table) - 1)
    i = np.minimum(s.astype(np.int64), len(table) - 2)
    w = (s - i)[:, None]
    return np.round(table[i] * (1 - w) + table[i + 1] * w).astype(np.uint8)


def _fmt(v: float, digits: int = 4) -> str:
    return figure(v, digits)


def scale_ends(lo: float, mid: float, hi: float) -> list[str]:
    """A scale's ends and middle, to the digits that tell them apart: a uniform 1 mm blank's
    scale (its least span, 1 um) read "0.9995 | 1 | 1" at four. A value within round-off of
    zero beside the others is zero (a strain field at rest read "-1.85e-15 %")."""
    size = max(abs(lo), abs(hi))
    ends = [0.0 if abs(v) <= 1e-9 * size else v for v in (lo, mid, hi)]
    for digits in range(4, 9):
        out = [_fmt(v, digits) for v in ends]
        if len(set(out)) == 3:
            break
    return out


def _title(label: str, unit: str, note: str) -> str:
    u = f" [{escape(unit)}]" if unit and unit != "-" else ""
    n = f'<div style="color:#555">{escape(note)}</div>' if note else ""
    return f"<div><b>{escape(label)}</b>{u}</div>{n}"


def _swatches(rows: list[tuple[tuple[int, int, int], str]]) -> str:
    return "".join(
        f'<div style="display:flex;align-items:center;gap:6px;line-height:1.25">'
        f'<span style="width:14px;height:11px;border:1px solid #777;flex:none;'
        f'background:rgb{rgb}"></span><span>{escape(text)}</span></div>' for rgb, text in rows)


@dataclass(frozen=True)
class Continuous:
    """A colour map over ``lo..hi``; values beyond take the end colours (the legend says so)."""

    label: str
    unit: str
    lo: float
    hi: float
    note: str = ""  # where the range comes from
    cmap: str = "viridis"

    def colours(self, values: np.ndarray) -> np.ndarray:
        return colorize(values, self.lo, self.hi, self.cmap)

    def legend(self) -> str:
        stops = ", ".join(f"rgb({r:.0f},{g:.0f},{b:.0f})" for r, g, b in COLORMAPS[self.cmap])
        u = f" {self.unit}" if self.unit and self.unit != "-" else ""
        lo, mid, hi = scale_ends(self.lo, 0.5 * (self.lo + self.hi), self.hi)
        return (f'<div class="q3t-legend" data-scale="continuous" style="font-size:0.85em">'
                f"{_title(self.label, self.unit, self.note)}"
                f'<div style="height:12px;border-radius:2px;margin:3px 0;border:1px solid #777;'
                f'background:linear-gradient(to right, {stops})"></div>'
                f'<div style="display:flex;justify-content:space-between">'
                f"<span>&le; {lo}{u}</span><span>{mid}{u}</span>"
                f"<span>&ge; {hi}{u}</span></div></div>")


@dataclass(frozen=True)
class Categories:
    """One colour per code; ``names``: code -> (legend text, RGB), listed in that order."""

    label: str
    names: dict[int, tuple[str, tuple[int, int, int]]]
    note: str = ""
    bounds: tuple[float, ...] = field(default=())  # banded scales: the codes' upper bounds

    def codes(self, values: np.ndarray) -> np.ndarray:
        v = np.asarray(values, np.float64)
        if self.bounds:
            return np.searchsorted(np.asarray(self.bounds), v, side="right")
        return np.rint(v).astype(np.int64)

    def colours(self, values: np.ndarray) -> np.ndarray:
        codes = self.codes(values)
        table = np.full((max(self.names) + 1, 3), 128, np.uint8)  # an unknown code: grey
        for code, (_, rgb) in self.names.items():
            table[code] = rgb
        return table[np.clip(codes, 0, len(table) - 1)]

    def legend(self) -> str:
        rows = [(rgb, text) for _, (text, rgb) in self.names.items()]
        return (f'<div class="q3t-legend" data-scale="categories" style="font-size:0.85em">'
                f"{_title(self.label, '', self.note)}{_swatches(rows)}</div>")


def thinning_scale(marginal: float = MARGINAL_PCT, failure: float = FAILURE_PCT) -> Categories:
    """Thinning (%) in bands: thickened (< 0), safe (< ``marginal``), marginal (< ``failure``),
    failure. A value on a limit belongs to the worse band."""
    if not 0.0 < marginal < failure:
        raise ValueError(f"thinning limits: need 0 < marginal ({marginal}) < failure "
                         f"({failure})")
    c = THINNING_COLOURS
    return Categories("Thinning", {
        3: (f"failure ≥ {_fmt(failure)} %", c["failure"]),
        2: (f"marginal {_fmt(marginal)}–{_fmt(failure)} %", c["marginal"]),
        1: (f"safe 0–{_fmt(marginal)} %", c["safe"]),
        0: ("thickened < 0 %", c["thickened"])},
        note="% of the rest thickness", bounds=(0.0, marginal, failure))


def zone_scale() -> Categories:
    """The FLD zones (sim.frames.forming_limits.ZONES), worst first."""
    order = (FAILURE, MARGINAL, SAFE, INSUFFICIENT, WRINKLING)
    return Categories("FLD zone", {z: (ZONES[z], ZONE_COLOURS[z]) for z in order},
                      note="by the material's forming limit curve")


RUN_SUBJECT = "this run, steps shown"
EVERY_STEP = "this run, every step"  # a finished run whose record holds its ranges


class Ranges:
    """The range each continuous field is coloured over: the shown run's own (the smallest that
    holds every frame of it seen so far: it only grows, and a finished run's stays put) or one
    the user fixed (kept for every run until changed)."""

    def __init__(self) -> None:
        # the shown run's min..max per field; the viewer swaps it when it shows another run
        self.seen: dict[str, tuple[float, float]] = {}
        self.fixed: dict[str, tuple[float, float]] = {}
        # what ``seen`` is the range of, as the legend names it: the frames shown, which a
        # summary's final value (the formed part's least thickness) need not reach
        self.subject = RUN_SUBJECT

    def show(self, seen: dict[str, tuple[float, float]], subject: str = RUN_SUBJECT) -> None:
        """Colour over ``seen`` (a run's ranges, shared with it so they grow with it), the range
        of ``subject``: a run, or a scene's blank previewed at rest before any run."""
        self.seen, self.subject = seen, subject

    def add(self, fields: dict[str, np.ndarray]) -> None:
        grow(self.seen, fields)

    def fix(self, key: str, lo: float, hi: float) -> None:
        if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
            raise ValueError(f"colour range of {key}: need min < max, got {lo} and {hi}")
        self.fixed[key] = (float(lo), float(hi))

    def release(self, key: str) -> None:
        self.fixed.pop(key, None)

    def of(self, key: str) -> tuple[float, float, str]:
        """lo, hi and where they come from, for the legend."""
        if key in self.fixed:
            return (*self.fixed[key], "range fixed (kept across runs)")
        lo, hi = self.seen.get(key, (0.0, 1.0))
        return (*widened(lo, hi, MIN_SPAN.get(key, 1e-6)), f"range of {self.subject}")

"""Named colour maps for per-vertex fields, and the legend text."""

from __future__ import annotations

import numpy as np

# viridis sampled at 9 evenly spaced points (matplotlib's values, rounded to 8 bits)
VIRIDIS = np.array([[68, 1, 84], [71, 44, 122], [59, 81, 139], [44, 113, 142], [33, 144, 141],
                    [39, 173, 129], [92, 200, 99], [170, 220, 50], [253, 231, 37]], np.float64)
COLORMAPS = {"viridis": VIRIDIS}
# smallest colour span per field: a (nearly) uniform field shows one colour, not its noise
MIN_SPAN = {"thickness_mm": 1e-3, "thinning_pct": 1e-2, "eq_plastic_strain": 1e-5,
            "von_mises_MPa": 1e-2}
# tools: muted greys with a tint each (never colour-map hues), drawn semi-transparent
TOOL_COLOURS = [(150, 155, 170), (170, 150, 130), (150, 150, 150), (160, 140, 160),
                (140, 150, 120)]
TOOL_OPACITY = 0.35


def tool_colour(i: int) -> tuple[tuple[int, int, int], float]:
    """RGB and opacity of the i-th tool of a scene."""
    return TOOL_COLOURS[i % len(TOOL_COLOURS)], TOOL_OPACITY


def value_range(values: np.ndarray, min_span: float = 1e-6) -> tuple[float, float]:
    lo, hi = float(np.min(values)), float(np.max(values))
    if hi - lo < min_span:  # a uniform field would otherwise colour noise
        mid = 0.5 * (lo + hi)
        if lo >= 0 and mid < min_span / 2:  # a field that is zero (plastic strain) stays >= 0
            return 0.0, min_span
        lo, hi = mid - min_span / 2, mid + min_span / 2
    return lo, hi


def colorize(values: np.ndarray, lo: float, hi: float, name: str = "viridis") -> np.ndarray:
    """Shape: values (n,) -> RGB (n, 3) uint8."""
    table = COLORMAPS[name]
    s = np.clip((np.asarray(values, np.float64) - lo) / (hi - lo), 0.0, 1.0) * (len(table) - 1)
    i = np.minimum(s.astype(np.int64), len(table) - 2)
    w = (s - i)[:, None]
    return np.round(table[i] * (1 - w) + table[i + 1] * w).astype(np.uint8)


def legend_html(label: str, unit: str, lo: float, hi: float, name: str = "viridis") -> str:
    """A colour bar naming the field, its unit and the range the colours span (this frame's
    min to max). HTML, since emoji swatches need a font that headless browsers lack."""
    stops = ", ".join(f"rgb({r:.0f},{g:.0f},{b:.0f})" for r, g, b in COLORMAPS[name])
    u = f" {unit}" if unit and unit != "-" else ""
    return (f'<div class="q3t-legend" style="font-size:0.85em">'
            f"<div><b>{label}</b> [{unit or '-'}]</div>"
            f'<div style="height:10px;border-radius:2px;margin:2px 0;'
            f'background:linear-gradient(to right, {stops})"></div>'
            f'<div style="display:flex;justify-content:space-between">'
            f"<span>{lo:.4g}{u}</span><span>{hi:.4g}{u}</span></div></div>")

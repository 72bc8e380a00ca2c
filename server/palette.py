"""What colours the viewer's sheet: the field catalogue (label and unit of each frame field) and
the viewer's colour settings, the ranges of the continuous fields and the thinning limits, which
together give each field's scale (server.colormap). No GUI here: the viewer's controls set these
and the tests read them."""

from __future__ import annotations

from collections.abc import Collection

import numpy as np

from server import colormap
from server.colormap import Categories, Continuous, Ranges

# field key -> (label, unit); the dropdown shows "label (unit)", in this order
FIELDS = {"thickness_mm": ("Thickness", "mm"), "thinning_pct": ("Thinning", "%"),
          "fld_zone": ("FLD zone", ""),
          "eq_plastic_strain_pct": ("Equivalent plastic strain", "%"),
          "von_mises_MPa": ("von Mises stress", "MPa"),
          "major_strain_pct": ("Major true strain", "%"),
          "minor_strain_pct": ("Minor true strain", "%"),
          # recordings made before the strains were shown in %
          "eq_plastic_strain": ("Equivalent plastic strain", "-"),
          "major_strain": ("Major true strain", "-"), "minor_strain": ("Minor true strain", "-")}
DEFAULT_FIELD = "thickness_mm"
Scale = Continuous | Categories


def field_label(key: str) -> str:
    label, unit = FIELDS.get(key, (key, ""))
    return f"{label} ({unit})" if unit else label


def field_options(keys: Collection[str]) -> dict[str, str]:
    """Dropdown label -> field key for the fields a frame carries, known fields first."""
    ordered = [k for k in FIELDS if k in keys] + sorted(k for k in keys if k not in FIELDS)
    return {field_label(k): k for k in ordered}


class Palette:
    """The colour settings: kept for every run until the user changes them."""

    def __init__(self) -> None:
        self.ranges = Ranges()
        self.thinning = colormap.thinning_scale(colormap.MARGINAL_PCT, colormap.FAILURE_PCT)

    def set_thinning(self, marginal: float, failure: float) -> None:
        """The thinning limits (%); refused (ValueError, naming them) unless 0 < marginal <
        failure."""
        self.thinning = colormap.thinning_scale(marginal, failure)

    def scale(self, key: str, growing: bool = False) -> Scale:
        """The scale of field ``key``; ``growing``: the shown run is still running (its own
        range is the range so far)."""
        if key == "thinning_pct":
            return self.thinning
        if key == "fld_zone":
            return colormap.zone_scale()
        label, unit = FIELDS.get(key, (key, ""))
        lo, hi, note = self.ranges.of(key)
        if growing and key not in self.ranges.fixed:
            # every frame is coloured on the range so far, the same for all while it holds;
            # the legend says it may still widen (a fixed range keeps the colours put)
            note += " so far (widens while it runs; Colour scale › fixed keeps it)"
        return Continuous(label, unit, lo, hi, note)

    def colours(self, key: str, values: np.ndarray) -> np.ndarray:
        """RGB (n, 3) uint8 of ``values (n,)`` of field ``key``."""
        return self.scale(key).colours(values)

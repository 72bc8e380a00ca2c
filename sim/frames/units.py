"""The units a number is shown in: SI inside, the customary unit of a forming engineer outside
(kN, mm, MPa, %). One table for the run summary, the probes and the page's plots."""

from __future__ import annotations

import numpy as np

# SI unit -> (the unit shown, factor); "" is a count
DISPLAY = {"N": ("kN", 1e-3), "m": ("mm", 1e3), "1": ("%", 100.0), "deg": ("deg", 1.0),
           "Pa": ("MPa", 1e-6), "m3": ("cm³", 1e6), "1/m": ("1/m", 1.0), "": ("", 1.0)}


def measure(value: float | np.ndarray | list, unit: str) -> dict:
    """``{"value", "unit", "display": {"value", "unit"}}`` of an SI number or list of them."""
    shown, factor = DISPLAY[unit]
    scaled = (np.asarray(value, float) * factor).tolist()
    value = np.asarray(value, float).tolist()
    return {"value": value, "unit": unit, "display": {"value": scaled, "unit": shown}}

"""Result files: strict JSON (``NaN`` and ``Infinity`` are not JSON; Python's json writes them
unless told not to, and strict readers then refuse the whole file), and the result of a run
whose solver could not write one. Light on purpose: the server writes results without importing
the solver."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np


def finite(obj: object, path: str = "") -> tuple[object, list[str]]:
    """``obj`` with every non-finite number replaced by None, and the dotted paths of those."""
    if isinstance(obj, dict):
        pairs = [(k, finite(v, f"{path}.{k}" if path else str(k))) for k, v in obj.items()]
        return {k: v for k, (v, _) in pairs}, [p for _, (_, ps) in pairs for p in ps]
    if isinstance(obj, (list, tuple)):
        items = [finite(v, f"{path}.{i}" if path else str(i)) for i, v in enumerate(obj)]
        return [v for v, _ in items], [p for _, ps in items for p in ps]
    if isinstance(obj, (float, np.floating)) and not math.isfinite(obj):
        return None, [path]
    return obj, []


def dumps(obj: object, nulls: bool = False, **kw: Any) -> str:
    """JSON text of ``obj``; a non-finite number is an error naming where it is, or with
    ``nulls`` (reports, where it means "not measured") written as null."""
    if nulls:
        obj = finite(obj)[0]
    try:
        return json.dumps(obj, allow_nan=False, **kw)
    except ValueError:
        bad = finite(obj)[1]
        if not bad:
            raise
        raise ValueError(f"not JSON: non-finite numbers at {', '.join(bad[:5])}"
                         f"{' ...' if len(bad) > 5 else ''}") from None


def write(path: Path, obj: object, indent: int = 1) -> None:
    """``dumps(obj)`` to a temporary name first, then renamed: never a half-written file."""
    text = dumps(obj, indent=indent)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def interrupted(scene: str | None, element: str | None, reason: str,
                steps: list[dict] = ()) -> dict:
    """result.json of a run whose solver could not write one (its build failed or was
    stopped, or its process died): the keys of ``Simulation.result`` that mean something
    without a model, and the ``steps`` records known of it."""
    steps = list(steps)
    return {"scene": scene, "element": element, "built": None, "parameters": [],
            "converged": False, "steps": steps,
            "failure": {"step": steps[-1]["step"] + 1 if steps else 0,
                        "t": steps[-1]["time"] if steps else 0.0, "cutbacks": 0,
                        "reason": reason, "iterations": 0, "residuals": []}}

"""A scene's settings as dotted keys (``tools.punch.friction``) and their values in the units
the page's form shows: what the comparison of runs and a run of unsaved edits say differs."""

from __future__ import annotations

import textwrap
import tomllib

import numpy as np

from sim.frames.units import DISPLAY
from sim.scene.load import scene_from_toml, unit_of
from sim.scene.sheet import ShellSpec


def flatten(node: object, prefix: str = "", paths: dict | None = None,
            path: str = "") -> dict[str, object]:
    """Dotted keys to leaf values; a list of named tables is keyed by the names. ``paths``,
    when given, gets each key's schema path (the list's index in place of the name), which
    ``unit_of`` reads."""
    if isinstance(node, dict):
        items = ((k, k, v) for k, v in node.items())
    elif isinstance(node, list) and node and all(isinstance(x, dict) for x in node):
        items = ((x.get("name") or str(i), str(i), x) for i, x in enumerate(node))
    else:
        if paths is not None:
            paths[prefix] = path
        return {prefix: node}
    out: dict[str, object] = {}
    for k, index, v in items:
        out.update(flatten(v, f"{prefix}.{k}" if prefix else str(k), paths,
                           f"{path}.{index}" if path else str(index)))
    return out


def flat_scene(tree: dict) -> tuple[dict[str, object], dict[str, str]]:
    """``flatten`` of a scene's tree with its paths, the name and description left out (a
    run's scene is compared by the run's name)."""
    for k in ("name", "description"):
        tree.pop(k, None)
    paths: dict[str, str] = {}
    return flatten(tree, paths=paths), paths


def collapsed(flats: list[dict[str, object]], paths: dict[str, str]) -> list[dict[str, object]]:
    """The flattened scenes with a table or a list of named tables set in some and unset or
    empty in others as one setting each: a table's set fields in one text (``material.hill48``
    'r0 0.663, ..., rolling_angle 0 deg'), a list's names (``sections`` 'radial'). Turning a
    sheet anisotropic, or removing a section, is one change, not one per field."""
    tables = {k for f in flats for k, v in f.items()
              if v in (None, [], {}) and any(j.startswith(k + ".") for g in flats for j in g)}
    out = []
    for f in flats:
        g = dict(f)
        for t in tables:
            sub = {k: g.pop(k) for k in list(g) if k.startswith(t + ".")}
            if not sub:
                continue
            depth = len(paths[t].split("."))
            if all(paths[k].split(".")[depth].isdigit() for k in sub):  # a list's items
                g[t] = ", ".join(dict.fromkeys(k[len(t) + 1:].split(".")[0] for k in sub))
            else:
                g[t] = ", ".join(shown({"what": k[len(t) + 1:], "values": [v],
                                        "unit": unit_of(paths[k])})
                                 for k, v in sub.items() if v is not None)
        out.append(g)
    return out


# the edits of a scene the Runs table lists, the rest counted
EDITS_SHOWN = 6


def edits(saved: str, edited: str) -> list[str]:
    """What the page's unsaved edits (``edited``, a valid scene) changed of the saved scene
    ``saved``, each setting as 'tools.blank_holder.force 3 → 6 kN' in the form's units: the
    Runs table tells runs of one scene apart by them. [] when the saved scene no longer
    validates (the run then says only that it ran edits)."""
    try:
        a, paths_a = flat_scene(scene_from_toml(saved, {}).model_dump(mode="json"))
    except ValueError:
        return []
    b, paths = flat_scene(scene_from_toml(edited, {}).model_dump(mode="json"))
    paths = paths_a | paths
    a, b = collapsed([a, b], paths)
    keys = [k for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]
    out = [shown({"what": k, "values": [a.get(k), b.get(k)], "unit": unit_of(paths[k])},
                  " → ") for k in keys[:EDITS_SHOWN]]
    if len(keys) > EDITS_SHOWN:
        out.append(f"and {len(keys) - EDITS_SHOWN} more edits")
    return out


# a scene field's SI unit and the unit the page's form shows it in (web/units.js SCENE): the
# results' (mm, MPa, kN), but a scene's plain number (friction, Poisson's ratio) stays one
# rather than a %, and angles are in deg; other units as they are
SHOWN = {**DISPLAY, "1": ("", 1.0), "rad": ("deg", 180 / np.pi), "N/m": ("N/mm", 1e-3),
         "m/s": ("mm/s", 1e3)}


# a list value longer than this (an outline's points) is shown by its length
LIST_SHOWN = 6


def value_text(v: object, factor: float = 1.0, digits: int = 4,
               longest: int | None = LIST_SHOWN) -> str:
    """A value in the shown unit (``factor``) to ``digits``; a list longer than ``longest``
    by its length."""
    if v is None or v == []:  # as the form says a field left out, or a list emptied
        return "unset" if v is None else "none"
    if isinstance(v, float) or (isinstance(v, int) and not isinstance(v, bool) and factor != 1):
        return f"{v * factor:.{digits}g}"
    if isinstance(v, list) and longest is not None and len(v) > longest:
        return f"[{len(v)} values]"
    if isinstance(v, list):
        return "[" + ", ".join(value_text(x, factor, digits, longest) for x in v) + "]"
    return str(v)


def _labelled(text: str, label: str | None) -> str:
    return f"{text} {label}" if label else text


def override_text(key: str, value: object) -> str:
    """An override (``mesh.edge_length`` = 0.004) as the form shows the field: "4 mm", to
    twelve digits (the value given, not a rounding of it), every item of a list."""
    unit = unit_of(key)
    label, factor = SHOWN.get(unit or "", (unit, 1.0))
    return _labelled(value_text(value, factor, 12, None), label)


def shown(item: dict, between: str = " | ") -> str:
    """A setting's values side by side in the unit the page shows, labelled."""
    unit = item.get("unit")
    label, factor = SHOWN.get(unit or "", (unit, 1.0))
    values = item["values"]
    texts = [value_text(v, factor) for v in values]
    if label and any(v is None or v == [] for v in values):
        # each number with its unit: "1 → unset mm" read as an unset of mm (a review)
        return f"{item['what']} " + between.join(
            t if v is None or v == [] else f"{t} {label}" for t, v in zip(texts, values,
                                                                          strict=True))
    return _labelled(f"{item['what']} " + between.join(texts), label)


def element_of(text: str, element: str) -> str | None:
    """The element the scene ``text`` names when a run takes another (``element``); None when
    the run takes the scene's own."""
    own = tomllib.loads(text).get("shell", {}).get(
        "element", ShellSpec.model_fields["element"].default)
    return None if own == element else own


def ran_head(run_id: str, scene: str, text: str, edits: list[str] | None,
             overrides: dict, parameters: dict | None = None,
             scene_element: str | None = None) -> str:
    """The comment lines that head a run's scene.toml (``text``, a valid scene, as the page or
    the file had it; the copy below them takes the run's element) when what ran
    is not that text as it stands: the page's unsaved edits (``edits``, None: none; the
    comments below are the saved file's and may describe its values), overrides on top of
    it, an element other than its own (``scene_element``, :func:`element_of`, the text's when
    the run took ``overrides["shell.element"]`` instead), live parameters given at the start
    (``parameters``;
    those changed while it ran are in run.json's parameter log); '' otherwise (the file is the
    saved one, comments true)."""
    parts = []
    if edits is not None:
        parts.append(f"It ran the page's unsaved edits of {scene}: {'; '.join(edits)}. The "
                     "comments below are the saved file's: they may describe its values."
                     if edits else f"It ran the page's text of {scene}, not a saved file "
                     "(none saved, or the saved one no longer validates).")
    given = {k: v for k, v in overrides.items() if k != "shell.element"}
    if given:
        parts.append("Overrides on top of this file (run.json): " +
                     "; ".join(f"{k} = {override_text(k, v)}" for k, v in given.items()) + ".")
    if scene_element:
        parts.append(f"It ran element {overrides['shell.element']}, not the file's "
                     f"{scene_element}: [shell] below says what ran.")
    live = {k: v for k, v in (parameters or {}).items() if v != 1.0}  # 1: as written
    if live:
        parts.append("Live parameters from its start: " +
                     "; ".join(f"{k} ×{v:g}" for k, v in live.items()) +
                     " (changes while it ran: run.json's parameter log).")
    if not parts:
        return ""
    lines = textwrap.wrap(f"Run {run_id}, the scene as it ran. " + " ".join(parts), 96,
                          break_long_words=False, break_on_hyphens=False)
    return "".join(f"# {line}\n" for line in lines) + "\n"

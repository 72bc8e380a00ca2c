"""What every ``q3t`` command shares: finding a scene by name, ``--set`` overrides, exit codes."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from sim.scene.load import Scene

SCENES = Path(__file__).resolve().parents[2] / "scenes"

# Exit codes of every command, as argparse has it for a bad option: 2 is bad input
OK = 0
FAILED = 1  # a run (a case, a reference, a check) that failed; the output says why
BAD_INPUT = 2


def resolve_scene(name: str) -> Path:
    """A TOML path or a scene name in scenes/; SceneError (exit 2) otherwise."""
    from sim.scene.load import SceneError

    p = Path(name)
    if p.is_file():
        return p
    q = SCENES / f"{name}.toml"
    if q.is_file():
        return q
    raise SceneError(f"no scene {name!r} (not a file, not in {SCENES})")


def parse_sets(items: list[str]) -> dict:
    """``["key.path=value", ...]`` (``--set``) -> ``{key.path: value}``, values parsed as TOML."""
    from sim.scene.load import SceneError, parse_value

    out = {}
    for it in items:
        if "=" not in it:
            raise SceneError(f"--set needs key.path=value, got {it!r}")
        k, v = it.split("=", 1)
        out[k.strip()] = parse_value(v.strip())
    return out


def load(name: str, overrides: dict | None = None) -> Scene:
    """The validated scene ``name`` (``resolve_scene``) with ``overrides``; SceneError (a
    ValueError naming the field) on bad input."""
    from sim.scene.load import load_scene

    return load_scene(resolve_scene(name), overrides)

"""The live parameters of a run: multipliers of the scene's values (1 = as written), changed
while it runs and applied from the next step on; their ranges, and the words the page and the
viewer show for them (this module imports nothing heavy: the server reads it).

Two kinds: the run-wide multipliers (RANGES), and per-tool ones named ``<name>.<tool>``
(PER_TOOL: ``friction_scale.die``), one for each tool of the scene that has the value they
multiply; a tool's value is then scaled by both (friction 0.1 x 2 x 1.5 = 0.3)."""

from __future__ import annotations

from collections.abc import Iterable

# name -> (lowest, highest). tool_speed is the rate of the stroke (Simulation.set_parameter):
# never 0, a stroke that would never end
RANGES = {"load_scale": (0.0, 100.0), "tool_speed": (0.1, 10.0),
          "friction_scale": (0.0, 10.0), "holder_force_scale": (0.0, 10.0)}

# name -> the tool field (sim.scene.shapes.ToolSpec) it multiplies per tool, as ``<name>.<tool>``
# for each tool whose field is not 0; its range is the run-wide one's
PER_TOOL = {"friction_scale": "friction"}

# name -> (label, what it multiplies)
LABELS = {
    "load_scale": ("Load ×", "multiplies the scene's loads (gravity, pressure, tractions, "
                   "point forces)"),
    "tool_speed": ("Tool speed ×", "the stroke per step: the tools (and prescribed motions) "
                   "cover this many planned steps' travel per step; the planned stroke is "
                   "kept, the run ends when it is done (in fewer or more steps)"),
    "friction_scale": ("Friction ×", "multiplies every tool's friction coefficient"),
    "holder_force_scale": ("Holder force ×", "multiplies the force of force-controlled tools "
                           "(blank holders)"),
}

# name -> (label, what it multiplies) of the per-tool multipliers; the page adds the tool's name
TOOL_LABELS = {
    "friction_scale": ("Friction ×", "multiplies this tool's friction coefficient, on top of "
                       "the run-wide Friction ×"),
}


def label(name: str) -> tuple[str, str]:
    """A live parameter's label and hint as the page shows them: a per-tool one's label ends
    in its tool's name (``Friction × die``)."""
    base, dot, tool = name.partition(".")
    if dot and base in TOOL_LABELS:
        return f"{TOOL_LABELS[base][0]} {tool}", TOOL_LABELS[base][1]
    return LABELS.get(name, (name, ""))


def log_change(log: list[dict], entry: dict) -> None:
    """Add a change ``{step, name, value}`` to a run's parameter log: a second change of the
    same parameter before the step it applies from replaces the first (only the last applies:
    a slider's values while paused are one change)."""
    if log and log[-1]["step"] == entry["step"] and log[-1]["name"] == entry["name"]:
        log[-1] = entry
    else:
        log.append(entry)


def per_tool(tools: Iterable) -> dict[str, tuple[float, float]]:
    """The per-tool multipliers of a scene's ``tools`` (ToolSpec-like: ``name`` and the fields
    of PER_TOOL) and their ranges: ``{"friction_scale.die": (0.0, 10.0), ...}``."""
    return {f"{name}.{t.name}": RANGES[name] for name, fld in PER_TOOL.items()
            for t in tools if getattr(t, fld)}


def per_tool_of(names: Iterable[str]) -> dict[str, tuple[float, float]]:
    """The per-tool multipliers among a run's parameter ``names`` and their ranges."""
    return {k: RANGES[k.partition(".")[0]] for k in names if k.partition(".")[0] in PER_TOOL
            and k.partition(".")[2]}


def check_name(name: str, ranges: dict) -> tuple[float, float]:
    """The range of the live parameter ``name`` among a run's ``ranges`` (RANGES and its
    per-tool ones); ValueError naming it, and for a per-tool one its tool, when it is unknown."""
    if name in ranges:
        return ranges[name]
    base, dot, tool = name.partition(".")
    if dot and base in PER_TOOL:
        tools = sorted(k.partition(".")[2] for k in ranges if k.startswith(base + "."))
        have = f"those with one: {', '.join(tools)}" if tools else "none has one"
        raise ValueError(f"{name}: unknown tool {tool!r}: {base} multiplies a tool's "
                         f"{PER_TOOL[base]}; of the scene's tools {have}")
    raise ValueError(f"{name}: unknown parameter; known: {sorted(ranges)}")


def check(name: str, value: object, ranges: dict) -> float:
    """``value`` of the live parameter ``name`` as a float, in its range; ValueError naming
    the parameter and the reason otherwise."""
    lo, hi = check_name(name, ranges)
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not lo <= value <= hi:  # NaN fails the comparison too
        raise ValueError(f"{name}: {value!r} out of range [{lo}, {hi}]")
    return float(value)

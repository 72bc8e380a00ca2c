"""The live parameters of a run: multipliers of the scene's values (1 = as written), changed
while it runs and applied from the next step on; their ranges, and the words the page and the
viewer show for them (this module imports nothing heavy: the server reads it)."""

# name -> (lowest, highest). tool_speed is the rate of the stroke (Simulation.set_parameter):
# never 0, a stroke that would never end
RANGES = {"load_scale": (0.0, 100.0), "tool_speed": (0.1, 10.0),
          "friction_scale": (0.0, 10.0), "holder_force_scale": (0.0, 10.0)}

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

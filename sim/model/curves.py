"""The time curves of a scene (sim.scene.run.SteppingSpec): how far its loads and its
prescribed motions are applied at scene time t, as a factor of their full value."""

from __future__ import annotations

from sim.scene.run import SteppingSpec


def load_factor(st: SteppingSpec, t: float) -> float:
    """The loads': linear over the run in static stepping (t goes 0 -> 1), over
    ``load_ramp`` seconds in dynamic stepping, at once when that is 0."""
    if st.kind == "static":
        return t
    return min(1.0, t / st.load_ramp) if st.load_ramp > 0 else 1.0


def motion_factor(st: SteppingSpec, t: float) -> float:
    """Prescribed displacements' and bends' (sim.scene.boundary.BCSpec): as the loads', but
    over 1 s in dynamic stepping without ``load_ramp`` (a prescribed position cannot jump)."""
    length = 1.0 if st.kind == "static" or st.load_ramp == 0 else st.load_ramp
    return min(1.0, t / length)

"""Probes: named scalar outputs of a state, recorded every step. One registry knows the probe
kinds: each registers what its spec must name (a point, a region, a tool; a plastic material)
and how its value is read. The scene validates probe specs against it (sim.scene.run)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

from sim.frames.fields import (
    Discretised,
    curvature_xz,
    fibre_tilt,
    mid_surface,
    thickness,
    volume,
)

if TYPE_CHECKING:  # the scene's validation imports this module: it loads no solver
    from sim.solve.problem import Problem


class Spec(Protocol):
    """A probe's spec (sim.scene.run.ProbeSpec, which validates against PROBES): its kind, the
    point, region or tool it names and how a field is reduced to a number."""

    name: str
    kind: str
    tool: str | None
    point: tuple[float, float, float] | None
    component: str  # x, y, z or norm
    stat: str  # min, max or mean
    region: str | None


class _Scene(Protocol):
    probes: Sequence[Spec]


class Probed(Discretised, Protocol):
    """What the probes read of a model (sim.model.build.Model, built from the scene that
    imports this module)."""

    scene: _Scene
    problem: Problem
    regions: dict[str, np.ndarray]

    def column_nodes(self, plane_mask: np.ndarray, layers: str = "all") -> np.ndarray: ...


@dataclass
class State:
    """What a probe reads: the model, the state x, the total energy gradient (the support
    reactions, computed when a probe first needs it) and the mid-surface (n_v, 3) formed in the
    closed tools (the springback reference; None before the release stage)."""

    model: Probed
    x: np.ndarray
    gradient_: np.ndarray | None = None
    formed: np.ndarray | None = None

    @property
    def gradient(self) -> np.ndarray:
        if self.gradient_ is None:
            self.gradient_ = self.model.problem.gradient(self.x)
        return self.gradient_

    def vertices(self, region: str | None) -> np.ndarray:
        """The mid-surface vertex mask of ``region`` (every vertex when None)."""
        sh = self.model.shell
        if region is None:
            return np.ones(sh.n_vertices, bool)
        return self.model.regions[region][: sh.n_vertices]


# a probe kind's reading of a state
Value = Callable[[State, Spec], float]


@dataclass(frozen=True)
class ProbeKind:
    value: Value
    needs: tuple[str, ...] = ()  # the spec's fields it reads: "point", "region", "tool"
    plastic: bool = False  # reads the plastic state: a plastic material only
    unit: str = "m"  # SI (sim.frames.units.DISPLAY): the page shows it in mm, kN, MPa, ...


PROBES: dict[str, ProbeKind] = {}


def probe(kind: str, needs: tuple[str, ...] = (), plastic: bool = False,
          unit: str = "m") -> Callable[[Value], Value]:
    """Register the decorated ``value(state, spec)`` as probe kind ``kind``, whose values are
    in ``unit``."""
    def register(value: Value) -> Value:
        PROBES[kind] = ProbeKind(value, needs, plastic, unit)
        return value
    return register


def evaluate(model: Probed, x: np.ndarray, gradient: np.ndarray | None = None,
             formed: np.ndarray | None = None) -> dict[str, float]:
    """Every probe of the scene at state ``x``; ``gradient`` is the total energy gradient (the
    support reactions), computed here when a reaction probe needs it; ``formed`` the
    mid-surface (n_v, 3) at the end of the stroke, the reference of springback probes (they
    read 0 before the release stage)."""
    state = State(model, x, gradient, formed)
    return {p.name: PROBES[p.kind].value(state, p) for p in model.scene.probes}


def _stat(values: np.ndarray, p: Spec) -> float:
    return float(getattr(np, p.stat)(values))


def _component(v: np.ndarray, p: Spec) -> float:
    return float(np.linalg.norm(v) if p.component == "norm" else v["xyz".index(p.component)])


@probe("displacement", needs=("point",))
def _displacement(s: State, p: Spec) -> float:
    sh = s.model.shell
    v = int(np.argmin(np.linalg.norm(sh.mesh.vertices - np.array(p.point), axis=1)))
    mid0 = mid_surface(s.model, sh.rest)[v]
    return _component(mid_surface(s.model, s.x)[v] - mid0, p)


@probe("thickness")
def _thickness(s: State, p: Spec) -> float:
    return _stat(thickness(s.model, s.x), p)


@probe("reaction", needs=("region",), unit="N")
def _reaction(s: State, p: Spec) -> float:
    nodes = s.model.column_nodes(s.model.regions[p.region])
    return _component(s.gradient[nodes].sum(0), p)


@probe("volume", unit="m3")
def _volume(s: State, p: Spec) -> float:
    return volume(s.model, s.x)


@probe("curvature", needs=("region",), unit="1/m")
def _curvature(s: State, p: Spec) -> float:
    return curvature_xz(mid_surface(s.model, s.x)[s.vertices(p.region)])


@probe("plastic_strain", plastic=True, unit="1")
def _plastic_strain(s: State, p: Spec) -> float:
    ep = s.model.elasticity.ep
    return _stat(ep, p) if ep.size else 0.0


@probe("von_mises", unit="Pa")
def _von_mises(s: State, p: Spec) -> float:
    return _stat(s.model.elasticity.von_mises(s.x), p)


def _tool_report(s: State, p: Spec) -> dict | None:
    """The report of the probe's tool, None once it is retracted (it then carries nothing)."""
    term = next((t for t in s.model.problem.terms if getattr(t, "tool", None) == p.tool), None)
    return None if term is None else term.report(s.x)


@probe("tool_force", needs=("tool",), unit="N")
def _tool_force(s: State, p: Spec) -> float:
    rep = _tool_report(s, p)
    return 0.0 if rep is None else _component(np.array([rep["fx"], rep["fy"], rep["fz"]]), p)


@probe("penetration", needs=("tool",))
def _penetration(s: State, p: Spec) -> float:
    rep = _tool_report(s, p)
    return 0.0 if rep is None else float(rep["penetration"])


@probe("contact_nodes", needs=("tool",), unit="")
def _contact_nodes(s: State, p: Spec) -> float:
    rep = _tool_report(s, p)
    return 0.0 if rep is None else float(rep["contact_nodes"])


@probe("fibre_tilt", unit="deg")
def _fibre_tilt(s: State, p: Spec) -> float:
    tilt = fibre_tilt(s.model, s.x)
    return _stat(tilt[s.vertices(p.region)] if p.region else tilt, p)


@probe("height_range")
def _height_range(s: State, p: Spec) -> float:
    """Out-of-plane amplitude (the spread of z) of the region's mid-surface, e.g. of flange
    wrinkles; of the whole mid-surface without a region (a plate that buckles)."""
    z = mid_surface(s.model, s.x)[s.vertices(p.region), 2]
    return float(z.max() - z.min())


@probe("tool_position", needs=("tool",))
def _tool_position(s: State, p: Spec) -> float:
    rep = _tool_report(s, p)
    return 0.0 if rep is None else rep["z"]


@probe("springback")
def _springback(s: State, p: Spec) -> float:
    """Deviation from the shape in the closed tools."""
    if s.formed is None:
        return 0.0
    v = s.vertices(p.region)
    return _stat(np.linalg.norm(mid_surface(s.model, s.x)[v] - s.formed[v], axis=1), p)


@probe("cup_height", needs=("region",))
def _cup_height(s: State, p: Spec) -> float:
    """The rim (the region, mean) above the lowest point."""
    z = mid_surface(s.model, s.x)[:, 2]
    return float(z[s.vertices(p.region)].mean() - z.min())


@probe("draw_in", needs=("point",))
def _draw_in(s: State, p: Spec) -> float:
    """How far the sheet at ``point`` (its nearest mid-surface vertex, at rest) has moved in
    the plane toward the z axis, along its rest direction from the axis: a flange's edge drawn
    into the die, as deep-drawing benchmarks measure it (NUMISHEET'93: DX, DY on the axes, DD
    on the diagonal)."""
    sh = s.model.shell
    v = int(np.argmin(np.linalg.norm(sh.mesh.vertices - np.array(p.point), axis=1)))
    rest = mid_surface(s.model, sh.rest)[v]
    radial = np.array([rest[0], rest[1], 0.0])
    if not np.linalg.norm(radial):
        return 0.0  # on the axis: no inward direction
    moved = mid_surface(s.model, s.x)[v] - rest
    return -float(moved @ radial) / float(np.linalg.norm(radial))

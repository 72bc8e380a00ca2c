"""How a scene runs and what it records: ``[stepping]``, ``[solver]``, ``[[probes]]``,
``[[sections]]`` and ``[study]``."""

from __future__ import annotations

from typing import Annotated, Literal, Self

from pydantic import Field, model_validator

from sim.frames.probes import PROBES
from sim.scene.fields import (
    MAX_TIME,
    MIN_TIME_STEP,
    Direction2,
    Length,
    Point,
    Strict,
    bounded,
    doc,
    positive,
)


class SteppingSpec(Strict):
    """How the run steps through the scene's time, and the springback after it."""

    kind: Literal["static", "dynamic"] = doc(
        "static: equilibrium at each step, scene time t from 0 to 1 over the run; dynamic: "
        "implicit Euler in time", default="static")
    steps: Annotated[int, Field(ge=1, le=100000)] = doc("the number of steps", "1", 1)
    dt: positive(MIN_TIME_STEP, MAX_TIME, "s") | None = doc(
        "dynamic: the time step; the run lasts steps * dt", "s", None)
    load_ramp: bounded(0.0, MAX_TIME, lo_open=False) = doc(
        "dynamic: loads ramp over this time, 0 = applied at once; also the default ramp of "
        "prescribed displacements (bcs), which take 1 s when it is 0", "s", 0.0)
    max_cutbacks: Annotated[int, Field(ge=0, le=30)] = doc(
        "how often a failing step may be halved: 10 goes down to 1/1024 of a step", "1", 10)
    release: bool = doc(
        "after the last step: remove loads, released tools and BCs, solve static equilibrium "
        "(springback)", default=False)

    @model_validator(mode="after")
    def _dt(self) -> Self:
        if self.kind == "dynamic" and self.dt is None:
            raise ValueError("dynamic stepping needs dt")
        return self


class SolverSpec(Strict):
    """Newton's method on the incremental potential (sim.solve.newton)."""

    rtol: Annotated[float, Field(gt=0, lt=1)] = doc(
        "converged when the residual falls below rtol times the force level", "1", 1e-8)
    xtol: Annotated[float, Field(gt=0, lt=1)] = doc(
        "a Newton correction below xtol * thickness ends the iteration (at the residual's "
        "floor)", "1", 1e-6)
    max_iterations: Annotated[int, Field(ge=1, le=1000)] = doc(
        "Newton's cap per attempt; one that stops progressing ends sooner", "1", 200)
    linear_solver: Literal["auto", "pardiso", "scipy"] = doc(
        "auto: MKL PARDISO when installed, else SciPy", default="auto")
    hessian_projection: Literal["auto", "exact_near", "qp", "element", "none"] = doc(
        "auto: the exact Hessian where it is positive definite, else projected per "
        "quadrature point (q3t_ans: its points' material tangents and its initial-stress "
        "term apart); exact_near: projected so while the residual is above a tenth of the "
        "force level, then as auto; element: each element's whole Hessian", default="auto")


class ProbeSpec(Strict):
    """A number recorded at every step (sim.frames.probes): its kind says what, and which of
    tool, point and region it needs."""

    name: str = doc("the probe's name (plots, studies)")
    kind: Literal[tuple(PROBES)] = doc("what it measures (sim.frames.probes)")
    tool: str | None = doc("the tool it measures (tool_force, tool_position, penetration, "
                           "...)", default=None)
    point: Point | None = doc("where: the nearest mid-surface vertex (displacement, ...)",
                              "m", None)
    component: Literal["x", "y", "z", "norm"] = doc("which component of a vector",
                                                    default="norm")
    stat: Literal["min", "max", "mean"] = doc("how a field over the sheet becomes one number",
                                              default="mean")
    region: str | None = doc("the region it measures over", default=None)

    @model_validator(mode="after")
    def _fields(self) -> Self:
        for need in PROBES[self.kind].needs:
            if getattr(self, need) is None:
                raise ValueError(f"a {self.kind} probe needs {need}")
        return self


class PublishedSpec(Strict):
    """A benchmark's published value of the studied probe, with where it is published."""

    value: bounded(-1e15, 1e15, lo_open=False) = doc(
        "the probe's published value, signed as the probe measures it", "the probe's")
    source: Annotated[str, Field(min_length=10)] = doc(
        "where it is published: authors, year, title, table or figure")


class StudySpec(Strict):
    """A refinement study (``q3t study``): mesh edge lengths, elements, what is measured and the
    reference it is measured against.

    measure: ``final`` - the probe after the last step; ``curve`` - the probe over the run
    against ``over`` (``time`` or another probe, e.g. the punch's position), compared on the
    common range of the two curves; ``profile`` - a section's ``field`` along its rest radius
    at recorded ``step`` (default: the last recorded). ``norm``: relative L2 or max difference
    (curves and profiles). ``analytic``: a closed-form value for the probe (``final`` only)
    instead of a numerical reference run; the scene must satisfy the formula's assumptions.
    """

    probe: str | None = doc("the probe studied; unset: the scene's first", default=None)
    measure: Literal["final", "curve", "profile"] = doc("what is compared (above)",
                                                        default="final")
    over: str = doc("curve: time or a probe's name, the curve's abscissa", default="time")
    section: str | None = doc("profile: the section", default=None)
    field: Literal["thickness", "radius", "z"] = doc("profile: the field along the section",
                                                     default="thickness")
    step: Annotated[int, Field(ge=0)] | None = doc(
        "profile: the recorded step; unset: the last recorded", "1", None)
    norm: Literal["l2", "max"] = doc("relative L2 or max difference", default="l2")
    edge_lengths: list[Length] | None = doc("unset: 4x, 2x, 1x the mesh's own", "m", None)
    elements: list[str] = doc("the elements compared", default=["linear", "q3t", "quadratic"])
    reference_element: str = doc("the reference run's element", default="quadratic")
    reference_edge_length: Length | None = doc(
        "the reference run's edge length; unset: half the finest studied", "m", None)
    analytic: Literal["euler_bernoulli", "springback", "fibre"] | None = doc(
        "a closed-form (or fibre-model) reference instead of a reference run", default=None)
    cells: list[Annotated[int, Field(ge=1, le=4096)]] | None = doc(
        "the levels of a mesh refined by cells per side (cylinder_patch, sphere_patch) or "
        "along its length (strip), "
        "coarse to fine", "1", None)
    published: PublishedSpec | None = doc(
        "a published reference value of the probe (a benchmark's), instead of a reference "
        "run", default=None)

    @model_validator(mode="after")
    def _what(self) -> Self:
        if self.measure == "profile" and self.section is None:
            raise ValueError("a profile study needs section")
        if self.published and (self.analytic or self.measure != "final"):
            raise ValueError("published: a published value is one final value: measure must "
                             "be 'final', without analytic")
        if self.analytic and self.measure != "final":
            raise ValueError("analytic: a closed-form reference is one value: measure must be "
                             "'final'")
        return self



class SectionSpec(Strict):
    """A radial section: where the ray from the origin along ``direction`` crosses the blank at
    rest (its vertices within ``width`` of the ray, and the points where it cuts an edge, values
    linear along the edge), sorted by rest radius; their current radius and thickness are
    recorded at every step listed (all steps when empty)."""

    name: str = doc("the section's name (plots, studies)")
    direction: Direction2 = doc("the ray's (x, y) direction (any length)", "1", (1.0, 0.0))
    width: Length = doc("how far from the ray a vertex may be and count as on it", "m", 1e-4)
    steps: list[Annotated[int, Field(ge=0)]] = doc("the steps recorded; empty: every step. "
                                                   "The run's last step is recorded too "
                                                   "(a run stopped early, or steps changed)",
                                                   "1", [])



"""How a scene runs and what it records: ``[stepping]``, ``[solver]``, ``[[probes]]``,
``[[sections]]`` and ``[study]``."""

from __future__ import annotations

from typing import Annotated, Literal, Self

from pydantic import Field, model_validator

from sim.frames.probes import PROBES
from sim.scene.fields import MAX_TIME, MIN_TIME_STEP, Direction2, Length, Point, Strict, bounded


class SteppingSpec(Strict):
    kind: Literal["static", "dynamic"] = "static"
    steps: Annotated[int, Field(ge=1, le=100000)] = 1
    # dynamic: time step (s); duration = steps * dt
    dt: bounded(MIN_TIME_STEP, MAX_TIME, lo_open=False) | None = None
    # dynamic: loads ramp over this time (s), 0 = applied at once; also the default ramp of
    # prescribed displacements (BCSpec), which take 1 s when it is 0
    load_ramp: bounded(0.0, MAX_TIME, lo_open=False) = 0.0
    max_cutbacks: Annotated[int, Field(ge=0, le=30)] = 10  # down to 1/1024 of a step
    # after the last step: remove loads and the BCs marked release, solve static equilibrium
    release: bool = False

    @model_validator(mode="after")
    def _dt(self) -> Self:
        if self.kind == "dynamic" and self.dt is None:
            raise ValueError("dynamic stepping needs dt")
        return self


class SolverSpec(Strict):
    rtol: Annotated[float, Field(gt=0, lt=1)] = 1e-8
    # a Newton correction below xtol * thickness ends the iteration (at the residual's floor)
    xtol: Annotated[float, Field(gt=0, lt=1)] = 1e-6
    # Newton's cap per attempt; one that stops progressing ends sooner (sim.solve.newton)
    max_iterations: Annotated[int, Field(ge=1, le=1000)] = 200
    linear_solver: Literal["auto", "pardiso", "scipy"] = "auto"
    # auto: the exact Hessian where it is positive definite, else projected per quadrature point
    hessian_projection: Literal["auto", "qp", "element", "none"] = "auto"


class ProbeSpec(Strict):
    name: str
    kind: Literal[tuple(PROBES)]
    tool: str | None = None
    point: Point | None = None
    component: Literal["x", "y", "z", "norm"] = "norm"
    stat: Literal["min", "max", "mean"] = "mean"
    region: str | None = None

    @model_validator(mode="after")
    def _fields(self) -> Self:
        for need in PROBES[self.kind].needs:
            if getattr(self, need) is None:
                raise ValueError(f"a {self.kind} probe needs {need}")
        return self


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

    probe: str | None = None  # default: the scene's first probe
    measure: Literal["final", "curve", "profile"] = "final"
    over: str = "time"
    section: str | None = None
    field: Literal["thickness", "radius", "z"] = "thickness"
    step: Annotated[int, Field(ge=0)] | None = None
    norm: Literal["l2", "max"] = "l2"
    edge_lengths: list[Length] | None = None  # default: 4x, 2x, 1x the mesh's own
    elements: list[str] = ["linear", "q3t", "quadratic"]
    reference_element: str = "quadratic"
    reference_edge_length: Length | None = None
    analytic: Literal["euler_bernoulli", "springback"] | None = None

    @model_validator(mode="after")
    def _what(self) -> Self:
        if self.measure == "profile" and self.section is None:
            raise ValueError("a profile study needs section")
        if self.analytic and self.measure != "final":
            raise ValueError("analytic: a closed-form reference is one value: measure must be "
                             "'final'")
        return self



class SectionSpec(Strict):
    """A radial section: the mid-surface vertices within ``width`` of the ray from the origin
    along ``direction`` (rest state), sorted by rest radius; their current radius and
    thickness are recorded at every step listed (all steps when empty)."""

    name: str
    direction: Direction2 = (1.0, 0.0)
    width: Length = 1e-4
    steps: list[Annotated[int, Field(ge=0)]] = []



"""The scene schema's building blocks: bounds on every magnitude, the bounded number types
and the strict base model of every table. Units SI (m, Pa, kg, s, N)."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Annotated, Any

from pydantic import AfterValidator, BaseModel, ConfigDict, Field
from pydantic_core import PydanticUndefined

# Every float of a scene is finite (Strict's allow_inf_nan=False). Magnitudes the model
# multiplies into others are bounded too, far beyond any forming process in any consistent unit
# system the solver is run in (SI, or mm-N-s-tonne as in tests/apps/test_check.py), so that no real
# scene meets a bound while products such as E h^3, rho g V or m / dt^2 stay many orders of
# magnitude inside float range: a value past a bound is a typo or an attack, never physics.
MAX_LENGTH = 1e6  # a kilometre in mm: lengths, coordinates, displacements
# and from below, so that no positive magnitude is a denormal or underflows in a product
# (h^3, E h^3): a picometre is below any atom, a micropascal softer than any solid (gels
# have 1e2 Pa); in mm-N-s-tonne both bounds are a thousand or a million times further out
MIN_LENGTH = 1e-12
MIN_STRESS = 1e-6
MAX_STRESS = 1e13  # Pa: ten times diamond's modulus; moduli, flow stresses, tractions
MAX_DENSITY = 1e5  # kg/m^3: four times osmium (tonne/mm^3 are 1e-12 of these)
MAX_ACCELERATION = 1e10  # a million g in mm/s^2
MAX_SPEED = 1e7  # 10 km/s in mm/s: faster than sound in steel, so faster than any tool
MAX_FORCE = 1e15  # N: a million times the largest press
MAX_STIFFNESS = MAX_STRESS * MAX_LENGTH  # N/m: a penalty spring's stress per unit length
# s: a picosecond, below any continuum time scale (sound in steel crosses 6 nm in it); with it
# and the bounds above, the inertia term's m / dt^2 stays representable
MIN_TIME_STEP = 1e-12
MAX_TIME = 1e6  # s: eleven days of process time
MAX_STRAIN = 10.0  # hardening strain offsets; (e0 + ep)^n must not overflow
# rad: 160 turns, more than any tool or bent end turns in a run, while sin and cos of it keep
# 13 digits (a rotation vector of 1e308 made math.sin fail)
MAX_ANGLE = 1e3
MAX_SLOPE = 1e6  # a thickness gradient: a kilometre of thickness per millimetre


def bounded(lo: float, hi: float, lo_open: bool = True) -> type[float]:
    """A float in ``(lo, hi]`` (``[lo, hi]`` when not ``lo_open``): an ``Annotated`` float,
    typed as pydantic types its own constrained floats (``confloat``)."""
    return Annotated[float, Field(le=hi, **({"gt": lo} if lo_open else {"ge": lo}))]


def positive(floor: float, hi: float, unit: str) -> type[float]:
    """A float in ``(0, hi]`` whose schema bound is 0, as the engineer thinks of it (a
    thickness is positive: "greater than 0 mm", not "at least 1e-9 mm"); values between 0 and
    the underflow guard ``floor`` are refused by a check of their own, naming the guard."""
    def above(v: float) -> float:
        if v < floor:
            raise ValueError(f"{v:.3g} {unit} is below {floor:g} {unit}, under which the "
                             "model's products of it underflow (a slipped exponent?)")
        return v
    return Annotated[float, Field(gt=0.0, le=hi), AfterValidator(above)]


Length = positive(MIN_LENGTH, MAX_LENGTH, "m")
Extent = bounded(0.0, MAX_LENGTH, lo_open=False)  # m, zero allowed (radii, fillets)
Coord = bounded(-MAX_LENGTH, MAX_LENGTH, lo_open=False)  # m: positions, displacements
Stress = positive(MIN_STRESS, MAX_STRESS, "Pa")
Point = tuple[Coord, Coord, Coord]
Vec3 = tuple[float, float, float]  # finite; bounded by the field that uses it
Angle = bounded(-MAX_ANGLE, MAX_ANGLE, lo_open=False)  # rad
Rotation = tuple[Angle, Angle, Angle]  # a rotation vector: axis times angle (rad)
Slope = bounded(-MAX_SLOPE, MAX_SLOPE, lo_open=False)
Speed = bounded(-MAX_SPEED, MAX_SPEED, lo_open=False)


def _nonzero(v: tuple[float, ...]) -> tuple[float, ...]:
    # a direction is normalised by its length: its square must be a normal, finite float
    if not 1e-300 <= sum(c * c for c in v) <= 1e300:
        raise ValueError(f"a direction needs a length between 1e-150 and 1e150 (got {list(v)})")
    return v


Direction = Annotated[Vec3, AfterValidator(_nonzero)]


def _named_file(text: str) -> str:
    # an empty name is the form's file field before a file is chosen: said at the field, not
    # as a path that leads nowhere when the scene is saved or run
    if not text.strip():
        raise ValueError("no file chosen: choose or upload one (or leave the field unset)")
    return text


FileName = Annotated[str, AfterValidator(_named_file)]  # a file the scene reads
Direction2 = Annotated[tuple[float, float], AfterValidator(_nonzero)]


def check_magnitude(values: Iterable[float], bound: float, unit: str) -> None:
    """Each of ``values`` (finite already) within ``bound`` in size."""
    big = max((abs(v) for v in values), default=0.0)
    if big > bound:
        raise ValueError(f"{big:.3g} {unit} is beyond the bound {bound:.0e} {unit} "
                         "(see sim.scene: far beyond any forming process)")


def check_keyframes(rows: list[list[float]], lengths_end: int) -> None:
    """Keyframe rows ``[t, ...]``: times within MAX_TIME, columns 1 .. lengths_end - 1 lengths
    (displacements, offsets) within MAX_LENGTH; the rest (rotations) within MAX_ANGLE."""
    for i, row in enumerate(rows):
        try:
            check_magnitude(row[:1], MAX_TIME, "s")
            check_magnitude(row[1:lengths_end], MAX_LENGTH, "m")
            check_magnitude(row[lengths_end:], MAX_ANGLE, "rad")
        except ValueError as exc:
            raise ValueError(f"keyframes.{i}: {exc}") from None


def doc(text: str, unit: str | None = None, default: Any = PydanticUndefined) -> Any:
    """A field's description and, for a number (or numbers), its SI unit ("1": dimensionless),
    in the schema (``"unit"``): the form, /docs and docs/scene-reference.md read them there."""
    extra = {"unit": unit} if unit is not None else None
    return Field(default, description=text, json_schema_extra=extra)


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)



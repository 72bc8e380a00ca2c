"""Forming limits: the in-plane principal true strains of the mid-surface per element, the
forming limit curve (FLC) of the material card and each element's zone of the forming limit
diagram (FLD).

Strains are those of the **mid-surface**: the FLC is a limit of in-plane stretching (necking),
measured in tests (Nakajima, Marciniak) whose bending strains are negligible, while a skin's
strain adds the bending of every die shoulder the sheet is drawn over; that bending is
self-limiting and does not neck the sheet, so a skin strain would flag every bent radius as
failure. Element e sits on mid-surface triangle e; its strain is that of the triangle through
its three corner columns at w = 0 (sim.frames.fields.mid_surface): exact for the elements whose
mid-surface is linear in-plane (linear, Q3T), the chord triangle's for higher ones. Major and
minor are ln of the principal stretches of that triangle, total (elastic and plastic) strain,
major >= minor.

Zones, as integer codes ordered by severity (a display vertex shows the worst of its elements):

==== ===================== =========================================================
code zone                  where (e1 major, e2 minor, FLC e1*(e2), in true strain)
==== ===================== =========================================================
0    safe                  none of the below
1    insufficient stretch  |e1| and |e2| below ``insufficient_stretch`` (hardly formed)
2    wrinkling tendency    e2 < 0 and e1 < -e2: the sheet thickens (e3 = -(e1 + e2) > 0),
                           left of the pure-shear line e1 = -e2 of constant thickness, the
                           compressive region where flanges wrinkle (Marciniak, Duncan and
                           Hu, Mechanics of Sheet Metal Forming, 2002, Sec. 2.2.1, Fig. 2.6)
3    marginal              e1* - margin <= e1 < e1*: within the safety margin below the FLC
4    failure               e1 >= e1*: on or above the FLC
==== ===================== =========================================================

A failure or marginal point is never called anything else; an insufficiently stretched one is
not a wrinkling tendency (tiny compressions are no wrinkles).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from sim.scene.sheet import MaterialSpec, ShellSpec

SAFE, INSUFFICIENT, WRINKLING, MARGINAL, FAILURE = range(5)
ZONES = {SAFE: "safe", INSUFFICIENT: "insufficient stretch", WRINKLING: "wrinkling tendency",
         MARGINAL: "marginal", FAILURE: "failure"}


def membrane_strains(rest: np.ndarray, cur: np.ndarray, faces: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Major and minor true (log) strain of each triangle ``faces (n_f, 3)`` between its rest
    corners ``rest (n_v, 3)`` and current ones ``cur (n_v, 3)``: ln of the principal stretches
    of the in-plane deformation, the eigenvalues of C = A^-T g A^-1 (A the rest edges in an
    orthonormal basis of the rest triangle, g the Gram matrix of the current edges). Any rigid
    motion of a triangle leaves them unchanged. Shape: (n_f,), (n_f,), major >= minor."""
    E1, E2 = rest[faces[:, 1]] - rest[faces[:, 0]], rest[faces[:, 2]] - rest[faces[:, 0]]
    e1, e2 = cur[faces[:, 1]] - cur[faces[:, 0]], cur[faces[:, 2]] - cur[faces[:, 0]]
    L = np.linalg.norm(E1, axis=1)
    t1 = E1 / L[:, None]
    n = np.cross(E1, E2)
    t2 = np.cross(n / np.linalg.norm(n, axis=1)[:, None], t1)
    a, b, d = L, np.einsum("ij,ij->i", E2, t1), np.einsum("ij,ij->i", E2, t2)  # A = [[a b] [0 d]]
    g11, g12, g22 = (np.einsum("ij,ij->i", u, v) for u, v in ((e1, e1), (e1, e2), (e2, e2)))
    # C = A^-T g A^-1 with A^-1 = [[1/a, -b/(a d)], [0, 1/d]]
    c11 = g11 / a**2
    c12 = (g12 - b / a * g11) / (a * d)
    c22 = (g22 - 2 * b / a * g12 + (b / a) ** 2 * g11) / d**2
    mean, half = 0.5 * (c11 + c22), np.hypot(0.5 * (c11 - c22), c12)
    return 0.5 * np.log(mean + half), 0.5 * np.log(mean - half)


@dataclass(frozen=True)
class FormingLimitCurve:
    """The FLC as major limit strain over minor strain, both true (log) strains, and the zone
    thresholds. ``minor``, ``major``: points of a curve given as points (minor increasing),
    interpolated linearly and held constant beyond its ends (conservative where the curve rises
    away from plane strain, as FLCs do); or, with ``fld0`` set, the Keeler-Brazier curve
    (:func:`keeler_brazier_fld0`, :meth:`keeler_brazier`)."""

    kind: str
    margin: float
    insufficient_stretch: float
    minor: tuple[float, ...] = ()
    major: tuple[float, ...] = ()
    fld0: float | None = None  # Keeler-Brazier: engineering major strain at plane strain
    # why the curve may not hold for this card (a correlation used outside its data)
    warnings: tuple[str, ...] = ()

    def __call__(self, minor: np.ndarray) -> np.ndarray:
        """The limit major strain at each ``minor`` strain (true). Shape as ``minor``."""
        minor = np.asarray(minor, float)
        if self.fld0 is None:
            return np.interp(minor, self.minor, self.major)
        return self.keeler_brazier(minor, self.fld0)

    @staticmethod
    def keeler_brazier(minor: np.ndarray, fld0: float) -> np.ndarray:
        """The Keeler-Brazier curve in true strains through FLC0 = ln(1 + fld0): left of plane
        strain a line of constant thinning, e1 = FLC0 - e2 (slope -1 in true strain); right of
        it a slope of +0.6 in engineering strain, 1 + E1 = 1 + fld0 + 0.6 (exp(e2) - 1), which
        the source states through minor engineering strains of 20 % and which is extended
        beyond. Source: the AHSS Application Guidelines (WorldAutoSteel), "Forming Limit
        Curves" (the shape Keeler, Brazier and Goodwin found)."""
        minor = np.asarray(minor, float)
        left = np.log1p(fld0) - minor
        right = np.log1p(fld0 + 0.6 * np.expm1(np.maximum(minor, 0.0)))
        return np.where(minor <= 0.0, left, right)

    def sample(self, lo: float, hi: float, n: int = 61) -> dict[str, list[float]]:
        """The curve at ``n`` minor strains over [lo, hi] and at its own points (for a plot)."""
        minor = np.union1d(np.linspace(lo, hi, n), [m for m in self.minor if lo <= m <= hi]
                           + ([0.0] if lo < 0.0 < hi else []))
        return {"minor": minor.tolist(), "major": self(minor).tolist()}


def keeler_brazier_fld0(thickness: float, n: float) -> float:
    """Keeler and Brazier's plane-strain limit, engineering major strain (a fraction):
    FLD0 [%] = (23.3 + 14.13 t [mm]) n / 0.21 (S. P. Keeler and W. G. Brazier, "Relationship
    between laboratory material characterization and press-shop formability", Microalloying
    75, 1977, pp. 517-530; as given in the AHSS Application Guidelines). A correlation fitted on
    low-carbon and high-strength steel sheet: it overestimates the limits of aluminium alloys,
    whose measured curve is better given as points. ``thickness`` in m."""
    return (23.3 + 14.13 * thickness * 1e3) * n / 0.21 / 100.0


# the range of the sheets of Keeler and Brazier's original correlation (1977, the reference of
# keeler_brazier_fld0): hardening exponents up to 0.21 (the formula's n / 0.21) and
# thicknesses up to about 3 mm; beyond them the formula is extrapolated
KB_MAX_N, KB_MAX_THICKNESS = 0.21, 3e-3


def keeler_brazier_warnings(thickness: float, n: float, t_field: str, n_field: str
                            ) -> tuple[str, ...]:
    """Why the Keeler-Brazier curve of ``thickness`` (m) and ``n`` is an extrapolation, each
    naming the scene field the value came from; empty inside the correlation's range."""
    out = []
    if n > KB_MAX_N:
        out.append(f"{n_field} = {n:g} is above {KB_MAX_N}, the largest hardening exponent of "
                   "the sheets Keeler and Brazier's correlation was fitted on: its FLD0 is "
                   "extrapolated (give the measured curve as points)")
    if thickness > KB_MAX_THICKNESS:
        out.append(f"{t_field} = {thickness * 1e3:g} mm is above about "
                   f"{KB_MAX_THICKNESS * 1e3:g} mm, the thickest sheets Keeler and Brazier's "
                   "correlation was fitted on: its FLD0 is extrapolated (give the measured "
                   "curve as points)")
    return tuple(out)


def curve_of(material: MaterialSpec, shell: ShellSpec) -> FormingLimitCurve | None:
    """The FLC of a scene's ``[material]`` (``flc``), its defaults resolved: the hardening
    exponent of a Swift law, the shell's constant thickness; None without one."""
    spec = material.flc
    if spec is None:
        return None
    common = {"kind": spec.kind, "margin": spec.margin,
              "insufficient_stretch": spec.insufficient_stretch}
    if spec.kind == "points":
        minor, major = zip(*spec.points, strict=True)
        return FormingLimitCurve(minor=minor, major=major, **common)
    n, n_field = ((spec.n, "material.flc.n") if spec.n is not None
                  else (material.hardening.n, "material.hardening.n"))
    t, t_field = ((spec.thickness, "material.flc.thickness") if spec.thickness is not None
                  else (shell.thickness, "shell.thickness"))
    return FormingLimitCurve(fld0=keeler_brazier_fld0(t, n),
                             warnings=keeler_brazier_warnings(t, n, t_field, n_field), **common)


def zones(major: np.ndarray, minor: np.ndarray, flc: FormingLimitCurve) -> np.ndarray:
    """The zone code (module docstring) of each point. Shape: as ``major``, int8."""
    limit = flc(minor)
    small = flc.insufficient_stretch
    z = np.full(np.shape(major), SAFE, np.int8)
    z[(minor < 0.0) & (major < -minor)] = WRINKLING
    z[(np.abs(major) < small) & (np.abs(minor) < small)] = INSUFFICIENT
    z[major >= limit - flc.margin] = MARGINAL
    z[major >= limit] = FAILURE
    return z


def worst_per_vertex(elem: np.ndarray, faces: np.ndarray, n_v: int) -> np.ndarray:
    """The largest (worst) code of the elements around each vertex. Shape: (n_v,), int8."""
    out = np.zeros(n_v, np.int8)
    for c in range(3):
        np.maximum.at(out, faces[:, c], elem.astype(np.int8))
    return out

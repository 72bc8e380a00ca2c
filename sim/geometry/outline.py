"""Blanks from 2-D outlines: a closed outline with optional holes, given as points or a circle
or read from an SVG or DXF drawing, meshed into isotropic triangles of a target edge length.

The mesher is gmsh's Frontal-Delaunay (``Mesh.Algorithm = 6``): on a disk at 2 mm it gave a
smallest angle of 42 degrees and an edge-length spread (standard deviation over mean) of 6 %,
against 30 degrees and 19 % for Shewchuk's Triangle with an area bound, whose licence also
forbids commercial distribution without an arrangement. Its regularity has a price: inside
the blank its triangles form one lattice, so a scene may ask for gmsh's MeshAdapt instead
(``MESHERS``), whose edges point every way. Geometry checks (self-intersection,
holes outside the outline or inside each other) are shapely's polygon validity, which names
the point where a check fails. All lengths in metres; outlines lie in the plane z = 0.
"""

from __future__ import annotations

import ctypes
import functools
import math
import re
import signal
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim.geometry.trimesh import TriMesh
from sim.text import figure, mm

# a turn sharper than this at an outline's vertex is a corner the mesh keeps; gentler turns
# are a flattened curve, resampled through
CORNER = np.radians(25.0)
# the fewest segments of a circle: a polygon of n segments turns by 360 / n degrees at each
# vertex, and with fewer than 360 / 25 = 14.4 every vertex would be a corner (a turn above
# CORNER) the mesh keeps, the circle meshed as that polygon instead of resampled as a
# flattened curve; 15 segments turn by 24 degrees
MIN_SEGMENTS = math.floor(2 * math.pi / CORNER) + 1
MAX_SEGMENTS = 100_000
# a circle's points are rounded to a nanometre: gmsh's Frontal-Delaunay mesh changes when its
# input moves by the last bits of a float, so the mesh must not hinge on how sin and cos round
# on one machine; nine decimals of a metre are also how a scene lists points
DECIMALS = 9
# the largest mesh an outline may ask for: beyond it the edge length is a slip, and gmsh would
# take minutes and gigabytes before the model's memory check could say so
MAX_TRIANGLES = 2_000_000
# a blank's extent, m: larger than a press bed or smaller than a tenth of a millimetre is a
# drawing read in other units than its scale says (a drawing in mm at scale = 1 is 1000x)
EXTENT = (1e-4, 5.0)
# the longest chord, over the edge length, that gmsh meshes as one segment (its 1-D mesher
# takes int(L / lc + 1.99) points on a line: two up to L = 1.01 lc), with a margin for the
# rounding of L
WHOLE = 1.009
COARSE = 1e300  # a flattening step longer than any curve: its ends and a midpoint
# curves of a drawing are flattened to chords this fine against the edge length, so that the
# resampling at the edge length sees the curve, not the chords
FLATTEN = 0.1
SUFFIXES = (".svg", ".dxf")
# gmsh's 2-D algorithms a scene may choose (``Mesh.Algorithm``). Frontal-Delaunay's triangles
# are the more regular, but inside a blank they line up in one 60-degree lattice, whose three
# edge directions a drawn disk's rim takes as six waves; MeshAdapt's edges point every way.
MESHERS = {"frontal_delaunay": 6, "meshadapt": 1}
_GMSH = threading.Lock()  # gmsh is one global state per process


class OutlineError(ValueError):
    """An outline that cannot be meshed; ``field`` is the mesh table's field to blame."""

    def __init__(self, field: str, message: str):
        super().__init__(message)
        self.field = field


@dataclass(frozen=True)
class Band:
    """A ring around the z axis, ``r_min <= r <= r_max`` (m), meshed at the finer edge length
    ``h``; beyond it the edge length grows back by ``growth`` per unit of distance from it
    (a smooth grading: neighbouring triangles differ in size by about that fraction)."""

    r_min: float
    r_max: float
    h: float
    growth: float = 0.25

    def size(self, r: np.ndarray) -> np.ndarray:
        """The edge length this band asks for at distance ``r`` from the z axis."""
        return self.h + self.growth * np.maximum(0.0, np.maximum(self.r_min - r, r - self.r_max))

    def triangles(self, h: float) -> float:
        """About how many triangles the band and its grading add to a mesh of edge length
        ``h``: the integral of 1 / (area of an equilateral triangle of the local size) over the
        plane, less the mesh's own, where the band is the finer (an upper bound for an outline
        that does not cover the whole graded ring)."""
        r = np.linspace(0.0, self.r_max + (h - self.h) / self.growth, 4001)
        hs = np.minimum(h, self.size(r))
        density = 1.0 / (np.sqrt(3.0) / 4.0 * hs**2) - 1.0 / (np.sqrt(3.0) / 4.0 * h**2)
        return float(np.sum(2 * np.pi * r * density) * (r[1] - r[0]))


@dataclass(frozen=True)
class Outline:
    """The outer loop ``(n, 2)`` and the holes (each ``(m, 2)``), counter-clockwise, closed
    implicitly (the first point is not repeated)."""

    outer: np.ndarray
    holes: tuple[np.ndarray, ...] = ()

    @property
    def area(self) -> float:
        return _area(self.outer) - sum(_area(h) for h in self.holes)

    @property
    def perimeter(self) -> float:
        return sum(_length(p) for p in (self.outer, *self.holes))


def _area(p: np.ndarray) -> float:
    x, y = p[:, 0], p[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def _length(p: np.ndarray) -> float:
    return float(np.linalg.norm(np.roll(p, -1, axis=0) - p, axis=1).sum())


def loop(points: object, field: str) -> np.ndarray:
    """``points`` as a closed loop ``(n, 2)``: finite, at least 3 distinct points, repeated
    neighbours (and a repeated first point at the end) dropped."""
    p = np.asarray(points, float)
    if p.ndim != 2 or p.shape[1] != 2 or not np.isfinite(p).all():
        raise OutlineError(field, "a loop is a list of finite [x, y] points")
    if len(p):
        p = p[np.linalg.norm(p - np.roll(p, 1, axis=0), axis=1) > 0]
    if len(p) < 3:
        raise OutlineError(field, f"a closed outline needs at least 3 distinct points (got "
                                  f"{len(p)})")
    return p


def circle(radius: float, center: tuple[float, float] = (0.0, 0.0),
           segments: int = 360) -> np.ndarray:
    """The loop ``(segments, 2)`` of a circle: the corners of the regular polygon inscribed
    in it, counter-clockwise from the one on the +x side of ``center``, rounded to DECIMALS.
    OutlineError naming ``circle.radius`` or ``circle.segments`` out of bounds."""
    if not radius > 0.0:
        raise OutlineError("circle.radius", f"a circle's radius must be positive (got {radius})")
    if not MIN_SEGMENTS <= segments <= MAX_SEGMENTS:
        raise OutlineError("circle.segments", f"a circle takes {MIN_SEGMENTS} to {MAX_SEGMENTS} "
                                              f"segments (got {segments})")
    t = 2.0 * np.pi * np.arange(segments) / segments
    xy = np.column_stack([center[0] + radius * np.cos(t), center[1] + radius * np.sin(t)])
    return np.round(xy, DECIMALS)


def checked(outer: np.ndarray, holes: list[np.ndarray], field: str = "points",
            holes_field: str = "holes") -> Outline:
    """The outline of ``outer`` and ``holes`` after shapely's validity checks, oriented; an
    OutlineError names the field and, for a crossing, where it is."""
    import shapely

    shell = shapely.Polygon(outer)
    if why := _not_simple(shell):
        raise OutlineError(field, f"the outline is not a simple closed curve: {why}")
    for i, h in enumerate(holes):
        hole = shapely.Polygon(h)
        if why := _not_simple(hole):
            raise OutlineError(f"{holes_field}.{i}", f"hole {i} is not a simple closed curve: "
                                                     f"{why}")
        if not shell.contains(hole):
            raise OutlineError(f"{holes_field}.{i}", f"hole {i} does not lie inside the outline")
    whole = shapely.Polygon(outer, holes)
    if not whole.is_valid:
        raise OutlineError(holes_field, f"the holes touch or overlap each other: "
                                        f"{shapely.is_valid_reason(whole)}")
    return Outline(_ccw(outer, True), tuple(_ccw(h, False) for h in holes))


def _not_simple(polygon: object) -> str | None:
    """Why a shapely polygon is not a simple closed curve enclosing an area, or None."""
    import shapely

    if not polygon.is_valid:
        return shapely.is_valid_reason(polygon)
    return "it encloses no area" if polygon.area == 0.0 else None


def _ccw(p: np.ndarray, ccw: bool) -> np.ndarray:
    x, y = p[:, 0], p[:, 1]
    signed = float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
    return p if (signed > 0) == ccw else p[::-1].copy()


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]


def resample(p: np.ndarray, h: float) -> np.ndarray:
    """The loop ``p`` with points about ``h`` apart along it, keeping its corners (turns
    sharper than CORNER): each stretch between corners divided evenly."""
    d_in, d_out = p - np.roll(p, 1, axis=0), np.roll(p, -1, axis=0) - p
    turn = np.abs(np.arctan2(_cross(d_in, d_out), (d_in * d_out).sum(1)))
    corners = np.flatnonzero(turn > CORNER)
    start = int(corners[0]) if len(corners) else 0
    q = np.roll(p, -start, axis=0)
    q = np.vstack([q, q[:1]])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(q, axis=0), axis=1))])
    cuts = np.append(np.sort((corners - start) % len(p)), len(p)) if len(corners) else \
        np.array([0, len(p)])
    out = []
    for a, b in zip(cuts[:-1], cuts[1:], strict=True):
        # as many chords as the stretch holds at h, and no chord longer than gmsh leaves whole:
        # it divides a line above 1.01 lc in two, so a 6 mm blank once took 3 mm triangles
        n = max(1 if len(corners) > 1 else 3, int(round((s[b] - s[a]) / h)),
                math.ceil((s[b] - s[a]) / (WHOLE * h)))
        t = np.linspace(s[a], s[b], n + 1)[:-1]
        out.append(np.column_stack([np.interp(t, s, q[:, 0]), np.interp(t, s, q[:, 1])]))
    return np.concatenate(out)


def meshed_loops(outline: Outline, h: float) -> list[np.ndarray]:
    """The loops that :func:`mesh` gives gmsh, the outer one first: resampled at ``h``. Every
    boundary node of the mesh lies on their chords (a band only divides them again) and every
    other node inside the outer loop and outside the holes."""
    return [resample(p, h) for p in (outline.outer, *outline.holes)]


def check_extent(loops: list[np.ndarray], scale: float, what: str = "drawing") -> None:
    """OutlineError naming ``scale`` when a drawing's paths (or a mesh file's vertices: its
    units) read at ``scale`` are no blank's size."""
    ext = scale * float(np.ptp(np.concatenate(loops), axis=0).max())
    if not EXTENT[0] <= ext <= EXTENT[1]:
        raise OutlineError("scale", f"absurd size: the {what} is {mm(ext)} across "
                                    f"with scale = {scale:g} (a blank is {1e3 * EXTENT[0]:g}-"
                                    f"{1e3 * EXTENT[1]:g} mm across; a {what} in mm needs "
                                    "scale = 0.001)")


def check_size(outline: Outline, h: float, bands: tuple[Band, ...] = ()) -> None:
    """OutlineError naming ``edge_length`` when ``h`` is too coarse to resolve the outline
    (fewer than about four triangles across it), or naming ``refine`` when a band is not finer
    than ``h``, or either when the mesh would pass MAX_TRIANGLES."""
    width = np.sqrt(outline.area)
    if h > 0.5 * width:
        raise OutlineError("edge_length", f"{mm(h)} is too coarse for an outline of "
                                          f"area {figure(1e6 * outline.area)} mm² (at most "
                                          f"{mm(0.5 * width)})")
    for i, b in enumerate(bands):
        if b.h >= h:
            raise OutlineError(f"refine.{i}.edge_length", f"{mm(b.h)} is not finer "
                                                          f"than the mesh's edge_length "
                                                          f"{mm(h)}")
    n = estimate(outline, h)[1]
    if n > MAX_TRIANGLES:
        raise OutlineError("edge_length", f"{mm(h)} would give about {figure(n)} "
                                          f"triangles, above {figure(MAX_TRIANGLES)}; use a "
                                          "coarser mesh")
    n += sum(b.triangles(h) for b in bands)
    if n > MAX_TRIANGLES:
        raise OutlineError("refine", f"the refined rings would give about {figure(n)} triangles, "
                                     f"above {figure(MAX_TRIANGLES)}; refine less")


def estimate(outline: Outline, h: float) -> tuple[int, int]:
    """Vertices and triangles of the mesh at edge length ``h``, from area and perimeter
    (equilateral triangles of side h; Euler's formula for the vertices)."""
    n_f = outline.area / (np.sqrt(3.0) / 4.0 * h * h)
    n_b = outline.perimeter / h
    return int(n_f / 2 + n_b / 2 + 1), int(n_f)


def mesh(outline: Outline, h: float, bands: tuple[Band, ...] = (),
         mesher: str = "frontal_delaunay") -> TriMesh:
    """Isotropic triangles of edge length about ``h`` filling the outline, finer in the
    ``bands``, counter-clockwise about +z: gmsh's ``mesher`` (MESHERS) on the loops resampled
    at ``h`` (their chords divided again where a band asks for less)."""
    check_size(outline, h, bands)
    loops = meshed_loops(outline, h)
    checked(loops[0], loops[1:], "edge_length", "edge_length")  # still simple at this h
    with _GMSH:
        V, F = _gmsh(loops, h, bands, MESHERS[mesher])
    a = _cross(V[F[:, 1], :2] - V[F[:, 0], :2], V[F[:, 2], :2] - V[F[:, 0], :2])
    F = np.where((a < 0)[:, None], F[:, [0, 2, 1]], F)
    return TriMesh(V, F)


def _keep_broken_pipes_ignored() -> None:
    """gmsh's initialize sets SIGPIPE back to its default, which ends the process: after that
    a write to a closed socket or pipe (a browser tab closed on the server, a solver's queue
    after its server ended) killed the whole process without a trace, where Python raises
    BrokenPipeError. Python ignores SIGPIPE from its start; where it still believes so, say it
    again through libc, since signal.signal may be called from the main thread only."""
    if not hasattr(signal, "SIGPIPE") or signal.getsignal(signal.SIGPIPE) != signal.SIG_IGN:
        return
    libc = ctypes.CDLL(None)
    libc.signal.restype = ctypes.c_void_p
    libc.signal.argtypes = (ctypes.c_int, ctypes.c_void_p)
    libc.signal(int(signal.SIGPIPE), 1)  # 1: SIG_IGN


def _gmsh(loops: list[np.ndarray], h: float, bands: tuple[Band, ...],
          algorithm: int) -> tuple[np.ndarray, np.ndarray]:
    import gmsh

    def size(dim: int, tag: int, x: float, y: float, z: float, lc: float) -> float:
        r = np.hypot(x, y)
        return min([lc, *(float(b.size(r)) for b in bands)])

    # not interruptible: gmsh would install a SIGINT handler, which only the main thread may
    gmsh.initialize(readConfigFiles=False, interruptible=False)
    _keep_broken_pipes_ignored()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("Mesh.Algorithm", algorithm)
        gmsh.option.setNumber("Mesh.MeshSizeMax", h)
        if bands:
            # the sizes come from the bands and h alone: a boundary's fine chords near a band
            # must not spread over the whole interior
            gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
            gmsh.model.mesh.setSizeCallback(size)
        geo = gmsh.model.geo
        curves = []
        for p in loops:
            pts = [geo.addPoint(x, y, 0.0, h) for x, y in p]
            lines = [geo.addLine(pts[i], pts[(i + 1) % len(pts)]) for i in range(len(pts))]
            curves.append(geo.addCurveLoop(lines))
        geo.addPlaneSurface(curves)
        geo.synchronize()
        gmsh.model.mesh.generate(2)
        tags, X, _ = gmsh.model.mesh.getNodes()
        types, _, nodes = gmsh.model.mesh.getElements(2)
    except Exception as exc:  # gmsh raises a bare Exception with its log's last line
        raise OutlineError("edge_length", f"gmsh could not mesh the outline ({exc})") from None
    finally:
        gmsh.finalize()
    tri = nodes[list(types).index(2)].reshape(-1, 3) if 2 in types else np.zeros((0, 3))
    index = np.full(int(tags.max()) + 1, -1)
    index[tags.astype(np.int64)] = np.arange(len(tags))
    F = index[tri.astype(np.int64)]
    used = np.unique(F)
    renumber = np.full(len(tags), -1)
    renumber[used] = np.arange(len(used))
    V = X.reshape(-1, 3)[used]
    V[:, 2] = 0.0
    return V, renumber[F].astype(np.int64)


def read_drawing(path: str | Path, scale: float | None, h: float, extent: bool = True,
                 centre: bool = False) -> Outline:
    """The outline of an SVG or DXF drawing: its closed paths, the one of largest area the
    outline and the others its holes; coordinates (an SVG's user units, those of its viewBox,
    with y turned up) times ``scale`` are metres, ``scale`` None the units the drawing says
    (:func:`drawing_units`; OutlineError naming ``scale`` if it says none). Curves are
    flattened to chords FLATTEN h long. OutlineError naming ``path`` when it cannot be read.

    Read once per version of the file (its path, modification time and size): a scene's
    ring check reads it, then the build, and the page's form checks it again at every edit.
    The outline's arrays are read-only, being shared. ``extent``: refuse (naming ``scale``) a
    drawing that is no blank's size at ``scale``. ``centre``: moved so that its bounding box
    is centred on the origin."""
    path = Path(path)
    try:
        st = path.stat()
    except OSError:
        st = None
    if st is None or not path.is_file():
        raise OutlineError("path", f"no drawing {str(path)!r}")
    if scale is None:
        units = drawing_units(path)
        if units is None:
            raise OutlineError("scale", f"{path.name} does not say its units (an SVG's width "
                                        "in mm, cm, in, pt or pc over its viewBox; a DXF's "
                                        "$INSUNITS): give scale, 0.001 for a drawing in mm")
        scale = units[0]
    return _read_drawing(path.resolve(), st.st_mtime_ns, st.st_size, scale, h, extent, centre)


def _unreadable(exc: Exception, path: Path) -> str:
    """Why a parser gave up, as the drawing's author can act on it (the parsers' own words
    are Python's: "float division by zero", "cannot convert float NaN to integer"), without
    the folder the file is in (an upload's is the server's temporary one)."""
    if isinstance(exc, ZeroDivisionError):
        return "a size of 0 in it: a viewBox, width or height of 0?"
    text = str(exc).replace(str(path), path.name)
    if isinstance(exc, OverflowError) or "NaN" in text or "inf" in text.split():
        return "numbers too large to compute with: an arc or a coordinate near 1e308?"
    return text


@functools.lru_cache(maxsize=8)
def _read_drawing(path: Path, mtime_ns: int, size: int, scale: float, h: float,
                  extent: bool, centre: bool) -> Outline:
    reader = {".svg": _svg_loops, ".dxf": _dxf_loops}.get(path.suffix.lower())
    if reader is None:
        raise OutlineError("path", f"{path.name}: an outline is an SVG or DXF drawing "
                                   f"({', '.join(SUFFIXES)})")
    try:
        if extent:  # first its size, from the paths' ends and a chord or two per curve: a
            # drawing in mm read at scale = 1 would be flattened into a thousand times as
            # many chords (a minute) before it could be refused
            coarse = reader(path, COARSE)
            if coarse:
                check_extent(coarse, scale)
        raw = reader(path, FLATTEN * h / scale)
    except OutlineError:
        raise
    except Exception as exc:  # the parsers raise anything on a malformed file
        raise OutlineError("path", f"{path.name}: not a readable drawing "
                                   f"({_unreadable(exc, path)})") from None
    shift = 0.0
    if centre and raw:
        every = np.concatenate(raw) * scale
        shift = 0.5 * (every.min(0) + every.max(0))
    loops = [loop(p * scale - shift, "path") for p in raw]
    if not loops:
        raise OutlineError("path", f"{path.name}: no closed path")
    loops.sort(key=_area, reverse=True)
    shape = checked(loops[0], loops[1:], "path", "path")
    for a in (shape.outer, *shape.holes):
        a.setflags(write=False)
    return shape


# an SVG length's units in metres: the absolute ones of CSS. A px, or a length without a unit,
# is 1/96 in to a browser but 1/72 in to some drawing programs: no declaration of units
SVG_UNITS = {"mm": 1e-3, "cm": 1e-2, "q": 2.5e-4, "in": 0.0254, "pt": 0.0254 / 72,
             "pc": 0.0254 / 6}
# CSS's px, the user unit of an SVG without a viewBox
PX = 0.0254 / 96


def drawing_units(path: str | Path) -> tuple[float, str] | None:
    """Metres per unit of the drawing's coordinates as the file declares them, and where it
    does: an SVG's width (and height) in absolute units over its viewBox's, a DXF's
    $INSUNITS. None when it declares none (an SVG in px or without a size, $INSUNITS 0) or
    when an SVG's width and height give different units (a drawing stretched to its page).
    Read once per version of the file, as the drawing is (a DXF is parsed whole for it)."""
    path = Path(path)
    try:
        st = path.stat()
    except OSError:  # no file: read_drawing says so
        return None
    return _drawing_units(path.resolve(), st.st_mtime_ns, st.st_size)


@functools.lru_cache(maxsize=8)
def _drawing_units(path: Path, mtime_ns: int, size: int) -> tuple[float, str] | None:
    try:
        if path.suffix.lower() == ".dxf":
            return _dxf_units(path)
        if path.suffix.lower() == ".svg":
            return _svg_units(path)
    except Exception:  # unreadable: read_drawing says why
        return None
    return None


def _svg_units(path: Path) -> tuple[float, str] | None:
    import xml.etree.ElementTree as ET

    root = next(ET.iterparse(path, events=("start",)))[1]  # the <svg>, not the whole tree
    box = re.split(r"[\s,]+", root.get("viewBox", "").strip())
    box = [float(v) for v in box] if len(box) == 4 else None
    per_unit, said = [], []
    for i, side in ((0, "width"), (1, "height")):
        length = re.fullmatch(r"\s*([-+0-9.eE]+)\s*([a-zA-Z]+)\s*", root.get(side, ""))
        unit = SVG_UNITS.get(length[2].lower()) if length else None
        if unit is None or not float(length[1]) > 0:  # no size, or none a drawing can have
            continue
        size = float(length[1]) * unit
        if box is None:  # user units are CSS px, absolute once the size is
            per_unit.append(PX)
            said.append(f'{side}="{root.get(side).strip()}" (no viewBox: px)')
        elif box[2 + i] > 0:
            per_unit.append(size / box[2 + i])
            said.append(f'{side}="{root.get(side).strip()}" over a viewBox '
                        f"{box[2 + i]:g} {('wide', 'high')[i]}")
    if not per_unit or abs(per_unit[0] - per_unit[-1]) > 1e-6 * per_unit[0]:
        return None
    return per_unit[0], said[0]


def _dxf_units(path: Path) -> tuple[float, str] | None:
    import ezdxf
    from ezdxf import units

    code = int(ezdxf.readfile(path).header.get("$INSUNITS", 0))
    per_metre = units.METER_FACTOR[code] if 0 < code < len(units.METER_FACTOR) else None
    if not per_metre:
        return None
    # ezdxf's factors have ten digits: an inch is 1 / 39.37007874 = 0.0254000000001 m
    return float(f"{1.0 / per_metre:.10g}"), f"$INSUNITS = {code} ({units.unit_name(code)})"


# a shape without these attributes of its own is not drawn (SVG: they default to 0), but
# svgelements fills a rect's width and height from the root <svg>'s: an empty <rect/> read as
# the whole page
OWN_SIZE = {"rect": ("width", "height"), "circle": ("r",), "ellipse": ("rx", "ry")}


def _undrawn(shape: object) -> bool:
    own = shape.values.get("attributes") or {}
    return not all(own.get(k) for k in OWN_SIZE.get(own.get("tag"), ()))


def _svg_loops(path: Path, step: float) -> list[np.ndarray]:
    import svgelements as se

    svg = se.SVG.parse(str(path))
    # svgelements maps the drawing into its viewport (pixels); undone, coordinates are the
    # drawing's own user units, those of its viewBox
    to_user = ~se.Matrix(svg.viewbox_transform or "")
    loops = []
    for shape in svg.elements():
        if not isinstance(shape, se.Shape) or isinstance(shape, se.Text) or _undrawn(shape):
            continue
        whole = se.Path(shape) * to_user
        whole.reify()
        for sub in whole.as_subpaths():
            pts = _svg_points(se, se.Path(sub), step)
            if len(pts) > 1:
                if np.linalg.norm(pts[0] - pts[-1]) > 1e-9 * (np.ptp(pts, axis=0).max() or 1):
                    raise OutlineError("path", f"{path.name}: an open path (from "
                                               f"{pts[0].tolist()} to {pts[-1].tolist()})")
                loops.append(pts * [1.0, -1.0])  # SVG's y axis points down
    return loops


def _svg_points(se: object, sub: object, step: float) -> np.ndarray:
    pts = []
    for seg in sub:
        if isinstance(seg, se.Move | se.Line | se.Close):
            pts.append(seg.end)
        else:  # a curve: chords of about ``step``
            n = max(2, int(np.ceil(seg.length() / step)))
            pts.extend(seg.point(t) for t in np.linspace(0, 1, n + 1)[1:])
    return np.array([(q.x, q.y) for q in pts], float)


def _dxf_loops(path: Path, step: float) -> list[np.ndarray]:
    import ezdxf
    from ezdxf import path as dxfpath

    loops = []
    for e in ezdxf.readfile(path).modelspace():
        try:
            p = dxfpath.make_path(e)
        except TypeError:  # not a curve (text, dimensions, ...)
            continue
        # ezdxf flattens to a largest distance of chord from curve (not a chord length): a
        # hundredth of the SVG's chord length is as fine
        pts = np.array([(v.x, v.y) for v in p.flattening(step / 100)])
        if len(pts) < 2:
            continue
        if not p.is_closed:
            raise OutlineError("path", f"{path.name}: an open {e.dxftype()} (handle "
                                       f"{e.dxf.handle}); outlines are closed polylines, "
                                       "circles, ellipses or closed splines")
        loops.append(pts)
    return loops

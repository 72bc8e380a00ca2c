"""Files scenes read, uploaded into the scenes folder: blank mid-surfaces (``mesh.path``) and
per-vertex thickness (``shell.thickness_file``).

An upload is received into a hidden folder of its own inside the scenes folder, under its
final name (the readers take the format from the suffix and name the file in their errors),
read back with the readers the solver uses and checked, and only then linked (a new name)
or renamed (an explicit replace) into place: a file in the scenes folder is always whole and
readable, whatever the client does, and two uploads of one new name cannot both win.
A tool's surface (a tool shape of kind ``mesh``, ``tools.N.shape.path``) shares the blank's
extensions: its upload says ``kind=tool`` and is checked as a tool surface (wound one way, and
closed and not self-intersecting, or open, which its entry says: sim.tools.meshtool); the
listing names a mesh file by the field a scene reads it as, else by what it holds (a closed
surface is a tool's)."""

from __future__ import annotations

import asyncio
import contextlib
import functools
import json
import os
import secrets
import shutil
import threading
from collections.abc import AsyncIterator, Iterator
from pathlib import Path, PurePosixPath
from typing import BinaryIO

import numpy as np

from server.problems import Conflict, Invalid, NotFound
from server.settings import SCENE_NAME_MAX, check_name
from server.store import MESH_SUFFIXES, OUTLINE_SUFFIXES, VALUE_SUFFIXES, SceneStore, held
from sim.scene.fields import MAX_LENGTH
from sim.scene.load import SceneError, read_toml

# what each kind is, by suffix, and the scene field that reads it
KINDS = {"blank": MESH_SUFFIXES, "thickness": VALUE_SUFFIXES, "tool": MESH_SUFFIXES,
         "outline": OUTLINE_SUFFIXES}
# an outline drawing is named by mesh.path too: the blank's field covers it
FIELDS = {"blank": ("mesh", "path"), "thickness": ("shell", "thickness_file")}
FILE_NAME_MAX = SCENE_NAME_MAX
# a triangle this much smaller than the median is flat to round-off: the solver refuses the
# same (sim.terms.elasticity.reference_gradients, detJ below 1e-10 of the median)
FLAT = 1e-10
TEMP_PREFIX = ".upload-"
# s: an upload folder untouched this long is left by a server that died mid-upload (a live one
# is written at least every body_timeout, and then read back once, which takes seconds)
STALE = 3600.0
# the kind each mesh file was uploaded as, for those no scene names yet: an open surface is a
# blank's or a tool's open faces by what the uploader said, not by what it holds (a hidden
# file: the listing shows file names only)
UPLOADED = ".uploaded-kinds.json"
_UPLOADED_LOCK = threading.Lock()


class TooLarge(Exception):
    """An upload past the size limit (413)."""


class Stalled(Exception):
    """An upload whose body stopped arriving (408)."""


def check_file_name(name: str) -> str:
    """``name`` if it is a plain file name (server.settings.NAME: no path, no leading dot) with
    a lower-case suffix of a known kind; else Invalid (422)."""
    check_name(name, "file name", FILE_NAME_MAX)
    kind_of(name)
    return name


def _article(word: str) -> str:
    return "an" if word[:1] in "aeiou" else "a"


def kind_of(name: str, kind: str | None = None) -> str:
    """The kind a file name's suffix says, the first of those that share it (and ``kind``,
    when given, must be one of them)."""
    suffix = PurePosixPath(name).suffix
    found = [k for k, suffixes in KINDS.items() if suffix in suffixes]
    if kind is not None and kind in found:
        return kind
    if not found:
        known = "; ".join(f"{', '.join(s)} for {_article(k)} {k}" for k, s in KINDS.items())
        raise Invalid(f"name {name!r}: unknown extension {suffix or '(none)'!r} (lower case: "
                      f"{known})")
    if kind is not None and kind != found[0]:
        raise Invalid(f"kind {kind!r}: {name!r} is a {found[0]} file by its extension "
                      f"({_article(kind)} {kind}: {', '.join(KINDS[kind])})")
    return found[0]


# ---- reading a file as the solver will ---------------------------------------------------------
def _first(edges: np.ndarray, mask: np.ndarray) -> str:
    return f"first: vertices {edges[np.flatnonzero(mask)[:3]].tolist()}"


def check_blank(V: np.ndarray, F: np.ndarray) -> str | None:
    """What makes ``V (n_v, 3)``, ``F (n_f, 3)`` unusable as a blank mid-surface, or None:
    zero-area triangles, an edge of more than two triangles (no sheet has one), or two
    triangles wound opposite ways across their edge (the thickness would point both ways)."""
    area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]),
                                axis=1)
    flat = np.flatnonzero(area <= FLAT * np.median(area))
    if len(flat):
        return (f"{len(flat)} zero-area (degenerate) triangles, below {FLAT:g} of the median "
                f"area (first: {flat[:5].tolist()})")
    directed = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    edges, inverse, count = np.unique(np.sort(directed, axis=1), axis=0, return_inverse=True,
                                      return_counts=True)
    if (count > 2).any():
        return (f"{int((count > 2).sum())} non-manifold edges, each shared by more than two "
                f"triangles ({_first(edges, count > 2)})")
    # an edge of two triangles is walked once each way when both are wound alike
    forward = np.bincount(inverse.ravel(), weights=directed[:, 0] < directed[:, 1],
                          minlength=len(edges))
    flipped = (count == 2) & (forward != 1)
    if flipped.any():
        return (f"{int(flipped.sum())} edges between triangles wound opposite ways, a flipped "
                f"triangle ({_first(edges, flipped)})")
    return None


def inspect_blank(path: Path) -> dict:
    """The mesh file as the solver reads it (sim.geometry.trimesh, the scene's defaults),
    checked; Invalid naming the file and the problem."""
    from sim.geometry import trimesh as meshes

    try:
        mesh, _, report = meshes.load_with_values(path)
    except ValueError as exc:  # MeshFileError too
        raise Invalid(str(exc)) from None
    problem = check_blank(mesh.vertices, mesh.faces)
    if problem:
        raise Invalid(f"{path.name}: {problem}")
    return {"vertices": report["vertices"], "triangles": report["triangles"],
            "extent": _extent(mesh.vertices)}


def _extent(points: np.ndarray) -> list[float]:
    """The bounding box's sides in the file's own units: what a scene's ``scale`` turns
    into metres, shown so that a drawing in mm read as metres is seen before a run."""
    return [float(d) for d in np.ptp(points, axis=0)]


def inspect_thickness(path: Path) -> dict:
    """The values as the solver reads them (sim.model.sheet.read_values), each a thickness in
    metres: positive, finite, within the scene's bound on lengths."""
    from sim.model.sheet import read_values

    try:
        h = read_values(str(path))
    except ValueError as exc:  # names the file
        raise Invalid(str(exc)) from None
    except (TypeError, EOFError) as exc:  # np.load of an empty file: EOFError
        raise Invalid(f"{path.name} is not an array of numbers ({exc or 'no data'})") from None
    if h.size == 0:
        raise Invalid(f"{path.name}: no values (one thickness in m per vertex)")
    bad = np.flatnonzero(~np.isfinite(h) | (h <= 0) | (h > MAX_LENGTH))
    if len(bad):
        raise Invalid(f"{path.name}: {len(bad)} values are no thickness (positive, at most "
                      f"{MAX_LENGTH:.0e} m; value {bad[0]}: {h[bad[0]]:.3g})")
    return {"values": int(h.size)}


def inspect_outline(path: Path) -> dict:
    """The drawing as an outline mesh reads it (sim.geometry.outline.read_drawing): closed
    paths, the largest enclosing the others as holes. Its units are the scene's mesh.scale, so
    its curves are flattened here at a tenth of a drawing unit, fine enough to check; the
    units the file says (``units``: metres per unit and where it says so), the scale's
    default."""
    from sim.geometry import outline

    try:
        shape = outline.read_drawing(path, 1.0, 1.0, extent=False)  # its scale is a scene's
    except outline.OutlineError as exc:
        raise Invalid(str(exc)) from None
    units = outline.drawing_units(path)
    middle = 0.5 * (shape.outer.min(0) + shape.outer.max(0))
    return {"holes": len(shape.holes), "extent": _extent(shape.outer),
            "centre": [float(c) for c in middle],
            "units": units and {"scale": units[0], "said": units[1]}}


def inspect_tool(path: Path) -> dict:
    """The mesh file as a tool's surface (sim.tools.meshtool.read_surface): closed, or open
    (a CAD export of a die's working faces; ``open`` says so, as a scene must, with its side);
    its size is not checked, as the scene's ``scale`` says its units."""
    from sim.tools.meshtool import MeshOptions, read_surface

    try:
        V, F = read_surface(path, MeshOptions(), check_size=False)
        is_open = False
    except ValueError as exc:  # names the file
        if ": open: " not in str(exc):
            raise Invalid(str(exc)) from None
        try:  # wound one way and manifold, only not closed
            V, F = read_surface(path, MeshOptions(open=True), check_size=False)
        except ValueError as exc:
            raise Invalid(str(exc)) from None
        is_open = True
    return {"vertices": len(V), "triangles": len(F), "open": is_open, "extent": _extent(V)}


INSPECT = {"blank": inspect_blank, "thickness": inspect_thickness, "tool": inspect_tool,
           "outline": inspect_outline}


@functools.lru_cache(maxsize=256)
def _described(path: str, kind: str, size: int, mtime_ns: int) -> dict:
    """A kept file's counts, or its problem (a file put there by hand), read once per version
    of the file (the listing would otherwise parse every mesh again)."""
    try:
        return {**INSPECT[kind](Path(path)), "problem": None}
    except Invalid as exc:
        return {"problem": str(exc)}


# ---- receiving ---------------------------------------------------------------------------------
async def spool(chunks: AsyncIterator[bytes], out: BinaryIO, limit: int, idle: float) -> int:
    """Write the chunks to ``out`` as they arrive: TooLarge once past ``limit`` bytes (the
    rest is never read), Stalled when none arrives within ``idle`` seconds. Returns the size."""
    size = 0
    while True:
        try:
            async with asyncio.timeout(idle):
                chunk = await anext(chunks, None)
        except TimeoutError:
            raise Stalled(f"no part of the upload arrived within {idle:g} s") from None
        if chunk is None:
            return size
        size += len(chunk)
        if size > limit:
            raise TooLarge(f"upload larger than {limit} bytes (the server's limit)")
        out.write(chunk)


class FileStore:
    """The uploaded files of a scenes folder (and any of their kinds put there by hand)."""

    def __init__(self, scenes: SceneStore):
        self.scenes = scenes
        self.root = scenes.root

    def path(self, name: str) -> Path:
        return self.root / check_file_name(name)

    def names(self) -> list[str]:
        return sorted(p.name for p in self.root.iterdir()
                      if _is_file_name(p.name) and held(self.root, p))

    def entry(self, name: str, uses: dict[str, list[tuple[str, str]]] | None = None,
              kind: str | None = None) -> dict:
        """The file's entry; its ``kind`` as given (an upload's), else :meth:`kind`."""
        p = self.path(name)
        if not held(self.root, p):
            raise NotFound(f"no file {name!r}")
        uses = (self.uses() if uses is None else uses).get(name, [])
        st = p.stat()
        kind = kind_of(name, kind) if kind else self.kind(p, uses)
        counts = {"vertices": None, "triangles": None, "values": None, "holes": None,
                  "open": None, "extent": None, "centre": None, "units": None,
                  **_described(str(p), kind, st.st_size, st.st_mtime_ns)}
        return {"name": name, "kind": kind, "size": st.st_size, **counts,
                "used_by": list(dict.fromkeys(scene for scene, _ in uses))}

    def entries(self) -> list[dict]:
        uses = self.uses()
        return [self.entry(n, uses) for n in self.names()]

    @staticmethod
    def kind(path: Path, uses: list[tuple[str, str]]) -> str:
        """What a file is: by its extension, and a mesh file (a blank's or a tool's suffix)
        by the field of the first scene that names it, else by the kind it was uploaded as,
        else by what it holds: a closed surface is a tool's (a blank is an open sheet)."""
        kind = kind_of(path.name)
        if kind not in ("blank", "tool"):
            return kind
        for _, field in uses:
            return "tool" if field.startswith("tools.") else "blank"
        uploaded = _uploaded(path.parent).get(path.name)
        if uploaded in ("blank", "tool"):
            return uploaded
        st = path.stat()
        tool = _described(str(path), "tool", st.st_size, st.st_mtime_ns)
        return "tool" if tool["problem"] is None and not tool.get("open") else "blank"

    def uses(self) -> dict[str, list[tuple[str, str]]]:
        """File name -> (scene, field) of each file field of a scene's TOML that names it."""
        out: dict[str, list[tuple[str, str]]] = {}
        for scene in self.scenes.names():
            try:
                raw = read_toml(self.scenes.text(scene))
            except SceneError:
                continue
            for field, value in _named(raw):
                out.setdefault(str(PurePosixPath(value)), []).append((scene, field))
        return out

    def delete(self, name: str) -> None:
        """Refused (409) while a scene names the file: the scene would stop loading."""
        p = self.path(name)
        if not p.is_file():
            raise NotFound(f"no file {name!r}")
        uses = self.uses().get(name)
        if uses:
            scenes = ", ".join(dict.fromkeys(s for s, _ in uses))
            fields = ", ".join(dict.fromkeys(f for _, f in uses))
            raise Conflict(f"file {name!r} is used by scene(s) {scenes} ({fields}); "
                           "change or delete them first")
        p.unlink()
        _remember(self.root, name, None)

    def target(self, name: str, kind: str | None, replace: bool) -> tuple[Path, str]:
        """Where an upload of ``name`` goes and its kind, checked before any byte is read:
        Invalid for a bad name or kind, Conflict when it exists and ``replace`` is not set."""
        path = self.path(name)
        kind = kind_of(name, kind)
        if path.exists() and not replace:
            raise Conflict(f"file {name!r} exists; upload with replace=true to replace it")
        return path, kind

    def sweep(self, now: float) -> list[str]:
        """Remove the upload folders nothing has touched for ``STALE`` seconds before ``now``
        (``time.time()``); returns their names."""
        gone = []
        for tmp in self.root.glob(f"{TEMP_PREFIX}*"):
            try:
                newest = max(p.stat().st_mtime for p in [tmp, *tmp.iterdir()])
            except FileNotFoundError:  # its upload has just ended
                continue
            if now - newest > STALE:
                shutil.rmtree(tmp, ignore_errors=True)
                gone.append(tmp.name)
        return gone

    @contextlib.contextmanager
    def incoming(self, name: str) -> Iterator[Path]:
        """Where an upload of ``name`` is received: that name in a hidden folder of the scenes
        folder (the same file system, so it moves into place by a rename or link). The folder
        and whatever is left in it go when the block ends: kept, refused, or cut off."""
        tmp = self.root / f"{TEMP_PREFIX}{secrets.token_hex(8)}"
        tmp.mkdir(mode=0o700)
        try:
            yield tmp / check_file_name(name)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)

    def keep(self, received: Path, kind: str, replace: bool, said: str | None = None) -> dict:
        """Read the received file back and check it (Invalid names the problem), then put it
        in place: renamed over the old file when ``replace``, else linked only if the name is
        still free (Conflict when a concurrent upload took it). ``said``: the kind the upload
        asked for, if it did: a mesh file is listed as that until a scene names it."""
        INSPECT[kind](received)
        final = self.root / received.name
        if replace:
            os.replace(received, final)
        else:
            try:
                os.link(received, final)
            except FileExistsError:
                raise Conflict(f"file {received.name!r} exists; upload with replace=true to "
                               "replace it") from None
        _remember(self.root, received.name, said if said in ("blank", "tool") else None)
        return self.entry(received.name, kind=kind)


def _uploaded(root: Path) -> dict[str, str]:
    try:
        kinds = json.loads((root / UPLOADED).read_text())
    except (OSError, ValueError):  # none yet, or damaged: the files' contents decide
        return {}
    return kinds if isinstance(kinds, dict) else {}


def _remember(root: Path, name: str, kind: str | None) -> None:
    """Keep (or with None forget) the kind ``name`` was uploaded as; written whole, then
    renamed, so that a reader never sees half of it."""
    with _UPLOADED_LOCK:
        kinds = _uploaded(root)
        if kinds.get(name) == kind:
            return
        kinds.pop(name, None)
        if kind is not None:
            kinds[name] = kind
        tmp = root / f"{UPLOADED}.{secrets.token_hex(4)}"
        tmp.write_text(json.dumps(kinds, indent=1, sort_keys=True))
        os.replace(tmp, root / UPLOADED)


def _named(raw: dict) -> Iterator[tuple[str, str]]:
    """(field, file) of each file field a scene's tables fill: the blank's, the thickness
    file, and every tool shape's mesh (at any depth of its CSG)."""
    for table, key in FIELDS.values():
        section = raw.get(table)
        value = section.get(key) if isinstance(section, dict) else None
        if isinstance(value, str) and value:
            yield f"{table}.{key}", value
    tools = raw.get("tools")
    for i, tool in enumerate(tools if isinstance(tools, list) else []):
        if isinstance(tool, dict):
            yield from _shape_files(tool.get("shape"), f"tools.{i}.shape")


def _shape_files(shape: object, where: str) -> Iterator[tuple[str, str]]:
    if not isinstance(shape, dict):
        return
    if shape.get("kind") == "mesh" and isinstance(shape.get("path"), str) and shape["path"]:
        yield f"{where}.path", shape["path"]
    parts = shape.get("shapes")
    for j, part in enumerate(parts if isinstance(parts, list) else []):
        yield from _shape_files(part, f"{where}.shapes.{j}")


def _is_file_name(text: str) -> bool:
    try:
        return bool(check_file_name(text))
    except Invalid:
        return False


__all__ = ["FileStore", "KINDS", "Stalled", "TooLarge", "check_blank", "check_file_name",
           "inspect_blank", "inspect_outline", "inspect_thickness", "inspect_tool", "kind_of",
           "spool"]

"""Scene files on disk: TOML validated before it is written, written atomically.

A scene's files (``mesh.path`` of a file mesh, ``shell.thickness_file``) are named inside the
scenes folder, relative to it: an absolute path, ``..``, a backslash or a link out of the folder
is refused with a 422 naming the field, so a scene sent over the API cannot make the server read
any other file."""

from __future__ import annotations

import functools
import os
import secrets
from pathlib import Path, PurePosixPath, PureWindowsPath

from server.problems import Conflict, Invalid, NotFound
from server.settings import check_scene_name
from sim.elements import get_element
from sim.geometry import outline
from sim.model import size
from sim.scene.load import Scene, SceneError, read_toml, scene_from_toml

MESH_SUFFIXES = (".obj", ".ply", ".stl")  # what sim.geometry.trimesh.load reads
VALUE_SUFFIXES = (".npy", ".txt", ".csv")  # what sim.model reads as per-vertex values
OUTLINE_SUFFIXES = outline.SUFFIXES  # the drawings an outline mesh reads


def _temp(path: Path, data: str | bytes) -> Path:
    """A new hidden file beside ``path`` holding ``data``. Created with mode 0666 less the
    umask, as any file (mkstemp's 0600 would make saved scenes unreadable to other users)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.parent / f".{path.name}.{secrets.token_hex(8)}.tmp"
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data.encode() if isinstance(data, str) else data)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return tmp


def atomic_write(path: Path, data: str | bytes) -> None:
    """Write to a temporary file in the same folder, then rename: never a half-written file."""
    tmp = _temp(path, data)
    try:
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def exclusive_write(path: Path, data: str | bytes) -> bool:
    """Like ``atomic_write``, but only if ``path`` does not exist yet (a hard link fails on an
    existing name, atomically): of two concurrent writers exactly one wins. Returns whether
    this one did."""
    tmp = _temp(path, data)
    try:
        os.link(tmp, path)
        return True
    except FileExistsError:
        return False
    finally:
        tmp.unlink(missing_ok=True)


def _is_name(text: str) -> bool:
    try:
        return bool(check_scene_name(text))
    except Invalid:
        return False


def held(root: Path, p: Path) -> bool:
    """Whether ``p`` is a file of the folder ``root``: a link out of it (put there by hand)
    is not, so that the service reads nothing outside its folders."""
    return p.is_file() and p.resolve().parent == root.resolve()


class SceneStore:
    def __init__(self, root: Path):
        self.root = root
        root.mkdir(parents=True, exist_ok=True)

    def path(self, name: str) -> Path:
        return self.root / f"{check_scene_name(name)}.toml"

    def names(self) -> list[str]:
        """The scenes: the folder's TOML files whose names are scene names (a file named
        otherwise, or a folder or link put there by hand, could not be addressed)."""
        return sorted(p.stem for p in self.root.glob("*.toml")
                      if _is_name(p.stem) and held(self.root, p))

    def text(self, name: str) -> str:
        p = self.path(name)
        if not held(self.root, p):
            raise NotFound(f"no scene {name!r}")
        try:
            return p.read_bytes().decode("utf-8")
        except UnicodeDecodeError as exc:  # a file put there by hand
            raise SceneError(f"scene {name!r}: the file is not UTF-8 text ({exc.reason} at "
                             f"byte {exc.start})") from None

    def summary(self, name: str) -> dict:
        try:
            raw = read_toml(self.text(name))
            return {"name": name, "description": str(raw.get("description", "")),
                    "valid": True}
        except SceneError:
            return {"name": name, "description": "", "valid": False}

    def scene_files(self, scene: Scene) -> dict[str, Path]:
        """The files a scene reads (``mesh.path`` of a file or outline mesh,
        ``shell.thickness_file``, a mesh tool's ``tools.N.shape.path``), each inside the scenes
        folder, by field. Raises SceneError naming the field. A name is checked before any file
        is looked at, so a refused name touches nothing."""
        mesh_files = {"file": MESH_SUFFIXES, "outline": OUTLINE_SUFFIXES}.get(scene.mesh.kind)
        wanted = {"mesh.path": (scene.mesh.path if mesh_files else None, mesh_files),
                  "shell.thickness_file": (scene.shell.thickness_file, VALUE_SUFFIXES)}
        for i, tool in enumerate(scene.tools):  # a mesh tool's surface, at any CSG depth
            for field, shape in _tool_files(tool.shape, f"tools.{i}.shape"):
                wanted[field] = (shape.path, MESH_SUFFIXES)
        return {f: self._inside(f, text, suffixes)
                for f, (text, suffixes) in wanted.items() if text is not None}

    def _inside(self, field: str, text: str, suffixes: tuple[str, ...]) -> Path:
        rel = PurePosixPath(text)
        if (not text or "\\" in text or "\0" in text or rel.is_absolute()
                or PureWindowsPath(text).drive or ".." in rel.parts):
            raise SceneError(f"{field}: {text!r} must be a relative path inside the scenes "
                             "folder, without '..' or '\\'")
        if rel.suffix.lower() not in suffixes:
            raise SceneError(f"{field}: {text!r} is not a file of the kind it names "
                             f"({', '.join(suffixes)})")
        root = self.root.resolve()
        full = (root / rel).resolve()
        if not full.is_relative_to(root):
            raise SceneError(f"{field}: {text!r} leads out of the scenes folder")
        if not full.is_file():
            raise SceneError(f"{field}: no file {text!r} in the scenes folder")
        return full

    def validate(self, text: str, overrides: dict | None = None) -> Scene:
        """Raises SceneError naming the field; the text is never written when invalid."""
        scene = scene_from_toml(text, overrides)
        self.scene_files(scene)
        return scene

    def solver_overrides(self, scene: Scene) -> dict:
        """Overrides the solver process needs on top of the user's: the full paths of the files
        the scene reads (the solver reads a relative path from its working folder, not the
        scenes folder)."""
        return {f: str(full) for f, full in self.scene_files(scene).items()}

    def checked(self, text: str, overrides: dict, max_bytes: int) -> tuple[Scene, dict]:
        """The scene of ``text`` validated (SceneError naming the field -> 422), its element
        known, and its model within the server's memory limit, as the solver will read it (mesh
        files by their full paths): refused before any build. Returns the scene and the
        overrides the solver reads it with."""
        spec = self.validate(text, overrides)
        try:
            get_element(spec.shell.element)
        except ValueError as exc:  # names the known elements
            raise Invalid(f"shell.element: {exc}") from None
        solver_overrides = {**overrides, **self.solver_overrides(spec)}
        self._check_tool_meshes(spec)
        size.check(scene_from_toml(text, solver_overrides), max_bytes,
                   "the server's --max-memory")
        return spec, solver_overrides

    def _check_tool_meshes(self, scene: Scene) -> None:
        """Invalid (422) naming the field, the tool and the problem of a mesh tool's surface
        (open, self-intersecting, its size once scaled...), before a run builds it."""
        for i, tool in enumerate(scene.tools):
            for field, shape in _tool_files(tool.shape, f"tools.{i}.shape"):
                full = self._inside(field, shape.path, MESH_SUFFIXES)
                st = full.stat()
                problem = _tool_problem(str(full), st.st_size, st.st_mtime_ns, shape.scale,
                                        shape.spacing, shape.open, shape.flip)
                if problem:
                    raise Invalid(f"{field}: tool {tool.name!r}: {problem}")

    def run_text(self, scene: str, toml: str | None) -> tuple[str, bool]:
        """The text a run of ``scene`` runs, and whether it is not the saved scene: ``toml``
        when it says something else than the saved file (compared as validated scenes, so the
        form's re-rendering of an unchanged scene is no edit), else the saved file itself (its
        comments kept)."""
        if toml is None:
            return self.text(scene), False
        edited = self.validate(toml)  # SceneError naming the field -> 422
        try:
            saved = self.text(scene)
            if self.validate(saved) == edited:
                return saved, False
        except (NotFound, SceneError):  # not saved yet, or the saved file is invalid
            pass
        return toml, True

    def save(self, name: str, text: str) -> Scene:
        path = self.path(name)  # the name first: a bad one touches nothing
        scene = self.validate(text)
        atomic_write(path, text)
        return scene

    def create(self, name: str, text: str) -> Scene:
        """Save a new scene; Conflict if the name is taken, also by a concurrent create."""
        path = self.path(name)
        scene = self.validate(text)
        if not exclusive_write(path, text):
            raise Conflict(f"scene {name!r} exists: choose another name (a save replaces it)")
        return scene

    def delete(self, name: str) -> None:
        p = self.path(name)
        if not p.is_file():
            raise NotFound(f"no scene {name!r}")
        p.unlink()


__all__ = ["SceneStore", "SceneError", "atomic_write", "exclusive_write"]


def _tool_files(shape: object, where: str) -> list[tuple[str, object]]:
    """(field, shape) of the mesh shapes of a tool's shape, its CSG operands' included."""
    if getattr(shape, "kind", None) == "mesh":
        return [(f"{where}.path", shape)]
    return [f for j, part in enumerate(getattr(shape, "shapes", []))
            for f in _tool_files(part, f"{where}.shapes.{j}")]


@functools.lru_cache(maxsize=64)
def _tool_problem(path: str, size: int, mtime_ns: int, scale: float, spacing: float,
                  is_open: bool, flip: bool) -> str | None:
    """What makes a tool's mesh file unusable with these options (sim.tools.meshtool), once
    per version of the file; None when it can be used."""
    from sim.tools.meshtool import MeshOptions, read_surface

    try:
        read_surface(path, MeshOptions(scale, spacing, is_open, flip))
    except ValueError as exc:
        return str(exc)
    return None

"""Scene files on disk: TOML text validated before it is written, written atomically."""

from __future__ import annotations

import os
import tempfile
import tomllib
from pathlib import Path

from server.settings import check_name
from sim.scene import Scene, SceneError, scene_from_toml


def atomic_write(path: Path, data: str | bytes) -> None:
    """Write to a temporary file in the same folder, then rename: never a half-written file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data.encode() if isinstance(data, str) else data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


class SceneStore:
    def __init__(self, root: Path):
        self.root = root
        root.mkdir(parents=True, exist_ok=True)

    def path(self, name: str) -> Path:
        return self.root / f"{check_name(name, 'scene name')}.toml"

    def names(self) -> list[str]:
        return sorted(p.stem for p in self.root.glob("*.toml") if not p.name.startswith("."))

    def exists(self, name: str) -> bool:
        return self.path(name).is_file()

    def text(self, name: str) -> str:
        p = self.path(name)
        if not p.is_file():
            raise KeyError(name)
        return p.read_text()

    def summary(self, name: str) -> dict:
        try:
            raw = tomllib.loads(self.text(name))
            return {"name": name, "description": raw.get("description", ""), "valid": True}
        except tomllib.TOMLDecodeError:
            return {"name": name, "description": "", "valid": False}

    @staticmethod
    def validate(text: str, overrides: dict | None = None) -> Scene:
        """Raises SceneError naming the field; the text is never written when invalid."""
        return scene_from_toml(text, overrides)

    def save(self, name: str, text: str) -> Scene:
        scene = self.validate(text)
        atomic_write(self.path(name), text)
        return scene

    def delete(self, name: str) -> None:
        p = self.path(name)
        if not p.is_file():
            raise KeyError(name)
        p.unlink()


__all__ = ["SceneStore", "SceneError", "atomic_write"]

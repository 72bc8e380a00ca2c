"""The page's scene form and its TOML view, kept in sync by the server: scene JSON to TOML
(``render``) and TOML to scene JSON (``parse``), each with validation errors naming the field
(``{"loc": "material.nu", "msg": "Input should be less than 0.5"}``). Nothing is saved here."""

from __future__ import annotations

from pydantic import ValidationError

from server.tomlout import drop_none, edited, to_toml
from sim.scene.load import Scene, SceneError, joined, read_toml, scene_errors
from sim.scene.load import validate as validate_scene
from sim.scene.shapes import MeshShape
from sim.scene.sheet import FileMesh, OutlineMesh, ShellSpec

# the fields that name a file of the scenes folder, by model and field, and the kind of file
# (server.files): the form offers the uploaded files of that kind and an upload button
FILE_FIELDS = {(FileMesh, "path"): "blank", (ShellSpec, "thickness_file"): "thickness",
               (MeshShape, "path"): "tool", (OutlineMesh, "path"): "outline"}


def schema() -> dict:
    """The scene's JSON schema for the form: pydantic's, each file field marked with the kind
    of file it names (``"x-file": "blank"``)."""
    out = Scene.model_json_schema()
    for (model, field), kind in FILE_FIELDS.items():
        out["$defs"][model.__name__]["properties"][field]["x-file"] = kind
    return out


def validate(raw: dict) -> tuple[Scene | None, list[dict]]:
    try:
        return validate_scene(raw), []
    except ValidationError as err:
        return None, scene_errors(err)
    except SceneError as err:
        return None, [{"loc": "scene", "msg": str(err).removeprefix("scene: ")}]


def scene_toml(scene: Scene, *, emitter: str = "auto") -> str:
    """The TOML of a validated scene, defaults left out (the file reads back to the same
    scene)."""
    data = scene.model_dump(mode="json", exclude_defaults=True, exclude_none=True)
    return to_toml(data, emitter=emitter)


def edited_toml(base: str, scene: Scene) -> str | None:
    """``base`` (a scene's TOML, as the file has it) with ``scene``'s values written into it,
    its comments and number formats kept (server.tomlout.edited); None when ``base`` is not a
    valid scene (nothing to diff against) or the edit would not read back as ``scene``."""
    try:
        before, errors = validate(read_toml(base))
    except SceneError:
        return None
    if before is None:
        return None
    text = edited(base, before.model_dump(mode="json"), scene.model_dump(mode="json"),
                  scene.model_dump(mode="json", exclude_defaults=True, exclude_none=True))
    after, _ = validate(read_toml(text))
    return text if after == scene else None


def render(raw: dict, *, emitter: str = "auto", base: str | None = None) -> dict:
    """Scene JSON (from the form) to TOML. A valid scene is written into ``base`` (the
    scene's TOML before the edit: comments and number formats kept) when given, else without
    its defaults; an invalid one as given (less its nulls), so the TOML view still shows what
    the form says."""
    scene, errors = validate(raw)
    try:
        text = ((base is not None and edited_toml(base, scene)) or
                scene_toml(scene, emitter=emitter) if scene is not None
                else to_toml(raw, emitter=emitter))
    except (ValueError, TypeError) as exc:  # e.g. a null inside an array: no TOML for it
        text = None
        errors = errors or [{"loc": "scene", "msg": str(exc)}]
    return {"ok": scene is not None, "toml": text, "errors": errors,
            "error": joined(errors) or None,
            "scene": scene.model_dump(mode="json") if scene is not None else None}


def parse(text: str) -> dict:
    """TOML to scene JSON: the validated scene (every field, defaults filled in) when it is
    valid; else the raw tables (when the TOML itself reads) and the errors."""
    try:
        raw = read_toml(text)
    except SceneError as exc:
        errors = [{"loc": "toml", "msg": str(exc).removeprefix("TOML: ")}]
        return {"ok": False, "scene": None, "raw": None, "errors": errors,
                "error": joined(errors) or None}
    scene, errors = validate(raw)
    return {"ok": scene is not None, "raw": drop_none(raw), "errors": errors,
            "error": joined(errors) or None,
            "scene": scene.model_dump(mode="json") if scene is not None else None}

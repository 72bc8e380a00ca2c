"""The page's scene form and its TOML view, kept in sync by the server: scene JSON to TOML
(``render``) and TOML to scene JSON (``parse``), each with validation errors naming the field
(``{"loc": "material.nu", "msg": "Input should be less than 0.5"}``). Nothing is saved here."""

from __future__ import annotations

from pydantic import ValidationError

from server.tomlout import drop_none, to_toml
from sim.scene.load import Scene, SceneError, joined, read_toml, scene_errors
from sim.scene.load import validate as validate_scene


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


def render(raw: dict, *, emitter: str = "auto") -> dict:
    """Scene JSON (from the form) to TOML. A valid scene is written without its defaults; an
    invalid one as given (less its nulls), so the TOML view still shows what the form says."""
    scene, errors = validate(raw)
    try:
        text = (scene_toml(scene, emitter=emitter) if scene is not None
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

"""/api/scenes: list, read, create, update, delete, duplicate, validate; the JSON schema; the
form's conversions (render: scene JSON to TOML, parse: TOML to scene JSON), which never save."""

from __future__ import annotations

from fastapi import APIRouter, Request, Response
from pydantic import BaseModel, ConfigDict, Field
from starlette.convertors import StringConvertor, register_url_convertor

from server import sceneform, tomlout
from server.errors import BODY, CheckedRoute, documented
from server.settings import RESERVED_SCENE_NAMES, SceneName, ScenePath
from server.store import SceneStore
from sim.scene.load import Scene

router = APIRouter(prefix="/api/scenes", tags=["scenes"], route_class=CheckedRoute)


class SceneSegment(StringConvertor):
    """A ``{name:scene}`` path segment: any but the names of the routes beside it, so that
    ``PUT /api/scenes/schema`` is a 405 (the schema is read-only), not a scene named "schema"."""

    regex = f"(?!(?:{'|'.join(RESERVED_SCENE_NAMES)})(?:/|$))[^/]+"


register_url_convertor("scene", SceneSegment())
NAMED = (405, 422)  # a route naming a scene: a reserved name is another route (405)


EXAMPLE_TOML = """name = "plate"
[mesh]
kind = "rectangle"
size = [0.7, 0.07]
edge_length = 0.035
[shell]
thickness = 0.007
[material]
E = 1.0e9
nu = 0.3
"""


def _example(**values: object) -> ConfigDict:
    """A request body's config: strict (a JSON 0 is no boolean), no unknown fields, and an
    example for the schema."""
    return ConfigDict(strict=True, extra="forbid", json_schema_extra={"examples": [values]})


class SceneText(BaseModel):
    model_config = _example(toml=EXAMPLE_TOML)
    toml: str


class NewScene(BaseModel):
    model_config = _example(name="plate", toml=EXAMPLE_TOML)
    name: SceneName
    toml: str


class NewName(BaseModel):
    model_config = _example(name="cantilever-copy")
    name: SceneName
    toml: str | None = Field(None,
                             description="the text to copy instead of the saved file's (an "
                             "editor's unsaved edits); its name follows the new name too")


class SceneJSON(BaseModel):
    model_config = _example(scene={"name": "plate", "mesh": {"size": [0.7, 0.07]},
                                   "shell": {"thickness": 0.007},
                                   "material": {"E": 1.0e9, "nu": 0.3}})
    scene: dict
    base: str | None = Field(None, description="the scene's TOML before the edit: the "
                             "changed values are written into it, its comments and number "
                             "formats kept")


class SceneSummary(BaseModel):
    name: str
    description: str
    valid: bool = Field(description="whether its TOML reads (not whether the scene is valid)")


class SceneDocument(BaseModel):
    name: str
    toml: str
    scene: Scene | None = Field(description="the validated scene, defaults filled in; null "
                                            "when the scene is invalid")
    error: str | None = Field(description="why the scene is invalid, naming the field")


class Validated(BaseModel):
    ok: bool
    scene: Scene = Field(description="the scene as the solver reads it, defaults filled in")


class FieldError(BaseModel):
    loc: str = Field(description="the field's dotted path, e.g. material.nu")
    msg: str


class Converted(BaseModel):
    """A conversion between the form's scene JSON and TOML, and what is wrong with the scene."""

    ok: bool
    scene: dict | None = Field(description="the validated scene; null when invalid")
    errors: list[FieldError]
    error: str | None = Field(description="the errors in one line")


class Rendered(Converted):
    toml: str | None = Field(description="the TOML (null when the form's JSON has none)")


class Parsed(Converted):
    raw: dict | None = Field(description="the tables as read (null when the TOML does not read)")


# what a new scene's name leads to (OpenAPI links: clients and fuzzers follow them)
NAME_LINKS = {op: {"operationId": op, "parameters": {"name": "$response.body#/name"}}
              for op in ("read_scene", "update_scene", "delete_scene", "duplicate_scene")}
CREATED = {201: {"links": NAME_LINKS}}


def _store(request: Request) -> SceneStore:
    return request.app.state.store


def _read(store: SceneStore, name: str) -> dict:
    text = store.text(name)
    try:
        scene, error = store.validate(text).model_dump(mode="json"), None
    except ValueError as exc:
        scene, error = None, str(exc)
    return {"name": name, "toml": text, "scene": scene, "error": error}


@router.get("", response_model=list[SceneSummary])
def list_scenes(request: Request) -> list[dict]:
    """Every scene of the scenes folder: name, description and whether it is valid (a file
    that does not read is listed as invalid, with the reason)."""
    store = _store(request)
    return [store.summary(n) for n in store.names()]


@router.get("/schema")
def schema() -> dict:
    """The scene's JSON schema: every field with its type, range, unit and description (the
    page's scene form is built from it); a field that names a file of the scenes folder says
    which kind (``"x-file": "blank"``, server.files)."""
    return sceneform.schema()


@router.post("/validate", response_model=Validated, responses=documented(*BODY))
def validate(body: SceneText, request: Request) -> dict:
    """Check a scene's TOML without saving it: the scene as the solver reads it, or a 422
    naming the field and the reason."""
    return {"ok": True, "scene": _store(request).validate(body.toml).model_dump(mode="json")}


@router.post("/render", response_model=Rendered, responses=documented(*BODY))
def render(body: SceneJSON) -> dict:
    """Scene JSON (the page's form) to TOML text, with validation errors naming the field
    (``{"loc": "material.nu", "msg": ...}``). A valid scene is written into ``base`` when
    given (its comments and number formats kept), else without its defaults. Never saves."""
    return sceneform.render(body.scene, base=body.base)


@router.post("/parse", response_model=Parsed, responses=documented(*BODY))
def parse(body: SceneText) -> dict:
    """TOML to scene JSON: ``scene`` (validated, defaults filled in) or ``raw`` and
    ``errors`` naming the fields. Never saves."""
    return sceneform.parse(body.toml)


@router.get("/{name:scene}", response_model=SceneDocument,
            responses=documented(404, *NAMED))
def read_scene(name: ScenePath, request: Request) -> dict:
    """A scene's TOML text and the scene as read from it."""
    return _read(_store(request), name)


@router.post("", status_code=201, response_model=SceneDocument,
             responses={**CREATED, **documented(409, *BODY)})
def create_scene(body: NewScene, request: Request, response: Response) -> dict:
    """Save a new scene (validated first: nothing is written on a 422; 409 when the name is
    taken)."""
    store = _store(request)
    store.create(body.name, body.toml)  # atomic: of two creates of one name, one wins
    response.headers["Location"] = f"/api/scenes/{body.name}"
    return _read(store, body.name)


@router.put("/{name:scene}", response_model=SceneDocument,
            responses=documented(*NAMED, *BODY))
def update_scene(name: ScenePath, body: SceneText, request: Request) -> dict:
    """Replace a scene's TOML (validated first: nothing is written on a 422)."""
    store = _store(request)
    store.save(name, body.toml)
    return _read(store, name)


@router.delete("/{name:scene}", status_code=204, responses=documented(404, *NAMED))
def delete_scene(name: ScenePath, request: Request) -> Response:
    """Delete a scene file (its runs keep their own copy of the scene)."""
    _store(request).delete(name)
    return Response(status_code=204)


@router.post("/{name:scene}/duplicate", status_code=201, response_model=SceneDocument,
             responses={**CREATED, **documented(404, 409, *NAMED, *BODY)})
def duplicate_scene(name: ScenePath, body: NewName, request: Request,
                    response: Response) -> dict:
    """A copy of the scene file under a new name; its ``name`` field follows the new name
    (the rest of the file, comments included, as it is)."""
    store = _store(request)
    text = store.text(name)  # 404 for a missing scene, whatever the body holds
    text = text if body.toml is None else body.toml
    store.create(body.name, tomlout.renamed(text, body.name))
    response.headers["Location"] = f"/api/scenes/{body.name}"
    return _read(store, body.name)

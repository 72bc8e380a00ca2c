"""/api/files: upload, list, read and delete the files scenes read (blank meshes for
``mesh.path``, per-vertex thickness for ``shell.thickness_file``, tool surfaces for a mesh
tool's ``shape.path``), kept in the scenes folder.

The upload's body is the file itself (``Content-Type: application/octet-stream``;
``curl -X POST -T blank.stl 'http://HOST/api/files?name=blank.stl'``), streamed to disk and
counted as it arrives, so its limit (``Settings.max_upload``) holds without the file ever being
in memory."""

from __future__ import annotations

import time
from typing import Literal

from fastapi import APIRouter, Request, Response
from fastapi.concurrency import run_in_threadpool
from pydantic import BaseModel, Field
from starlette.exceptions import HTTPException
from starlette.requests import ClientDisconnect

from server.errors import documented
from server.files import FILE_NAME_MAX, KINDS, FileStore, Stalled, TooLarge, check_file_name, spool
from server.settings import Settings, name_type

router = APIRouter(prefix="/api/files", tags=["files"])

FileName = name_type(check_file_name, FILE_NAME_MAX)
Kind = Literal["blank", "thickness", "tool", "outline"]
# an answer given before the body is all read: the rest of it is never read, so the connection
# cannot carry another request
CLOSE = {"Connection": "close"}


class DrawingUnits(BaseModel):
    scale: float = Field(description="metres per unit of the drawing's coordinates")
    said: str = Field(description='where the file says so: \'width="80mm" over a viewBox 80 '
                                  "wide', '$INSUNITS = 4 (Millimeters)'")


class FileEntry(BaseModel):
    name: str = Field(description="the file's name in the scenes folder: what a scene's "
                                  "mesh.path or shell.thickness_file says")
    kind: Kind = Field(description="blank: a mid-surface mesh; thickness: one value (m) per "
                                   "vertex; tool: a tool's surface mesh; outline: an SVG or "
                                   "DXF drawing of a blank's outline (mesh kind outline). A "
                                   "mesh file is a blank or a tool by the field the first "
                                   "scene naming it reads it as, else by the kind its upload "
                                   "asked for, else by what it holds (a closed surface is a "
                                   "tool's)")
    size: int = Field(description="bytes")
    vertices: int | None = Field(description="a mesh's vertices as the solver reads them")
    triangles: int | None = Field(description="a mesh's triangles")
    values: int | None = Field(description="a thickness file's values")
    holes: int | None = Field(description="an outline's holes (its closed paths but the "
                                          "largest)")
    open: bool | None = Field(description=(
        "a tool's surface with a boundary (a die's working faces from CAD): a scene reads "
        "it with open = true, the tool behind its faces' normals (flip = true: in front)"))
    extent: list[float] | None = Field(description=(
        "a mesh's or a drawing's bounding box sides in the file's own units (x, y[, z]): "
        "a scene's scale turns them into metres (a file in mm needs scale = 0.001)"))
    centre: list[float] | None = Field(description=(
        "a drawing's bounding box centre in its own units (x, y up): where its blank lies, "
        "unless the scene's mesh.centre moves it to the origin"))
    units: DrawingUnits | None = Field(description=(
        "the units a drawing says it is in, which a scene's scale left unset reads it in; "
        "null for a mesh, or a drawing that says none (an SVG in px, a DXF's $INSUNITS 0)"))
    used_by: list[str] = Field(description="the scenes that name the file")
    problem: str | None = Field(description="why the solver could not use the file (one put "
                                            "in the folder by hand); null when it can")


class FileList(BaseModel):
    max_upload: int = Field(description="the largest upload the server takes, in bytes")
    kinds: dict[str, list[str]] = Field(description="each kind's file extensions")
    files: list[FileEntry]


BODY = {"requestBody": {"required": True, "description": "the file's bytes", "content": {
    "application/octet-stream": {"schema": {"type": "string", "format": "binary"}}}}}


def _files(request: Request) -> FileStore:
    return FileStore(request.app.state.store)


def _settings(request: Request) -> Settings:
    return request.app.state.settings


@router.get("", response_model=FileList)
def list_files(request: Request) -> dict:
    """The scenes folder's blank and tool meshes, outline drawings and thickness files
    (uploaded or put there by hand): each one's kind, size, counts as the solver reads it, the
    scenes that name it, and what makes it unusable, if anything; the upload limit and each
    kind's extensions."""
    return {"max_upload": _settings(request).max_upload,
            "kinds": {k: list(v) for k, v in KINDS.items()},
            "files": _files(request).entries()}


@router.post("", status_code=201, response_model=FileEntry, openapi_extra=BODY,
             responses={200: {"model": FileEntry, "description": "replaced"},
                        **documented(400, 408, 409, 413, 422)})
async def upload_file(request: Request, response: Response, name: FileName,
                      kind: Kind | None = None, replace: bool = False) -> dict:
    """Keep the body as ``name`` in the scenes folder, once it reads as its kind (by
    extension: .obj/.ply/.stl a blank, .npy/.txt/.csv a thickness file; ``kind=tool`` a mesh
    file as a tool's surface): 422 naming what is wrong (not a mesh, zero-area triangles,
    non-manifold or flipped edges, values that are no thickness; a tool's surface wound both
    ways or self-intersecting; an open one is kept, its ``open`` true), 413 past the size
    limit, 409 when the name is taken and ``replace`` is not set. Nothing is left behind by a
    refused or interrupted upload."""
    files, limit = _files(request), _settings(request).max_upload
    said = kind  # the uploader's word, kept for a mesh file no scene names yet
    path, kind = files.target(name, kind, replace)
    declared = request.headers.get("content-length", "")
    if declared.isdigit() and int(declared) > limit:  # refused before a byte is read
        raise HTTPException(413, f"upload of {declared} bytes larger than the server's limit, "
                                 f"{limit} bytes", CLOSE)
    existed = path.exists()
    files.sweep(time.time())  # what a server that died mid-upload left
    with files.incoming(name) as received:
        try:
            with open(received, "xb") as out:  # 0666 less the umask, like a saved scene
                await spool(request.stream(), out, limit, _settings(request).body_timeout)
        except TooLarge as exc:
            raise HTTPException(413, str(exc), CLOSE) from None
        except Stalled as exc:
            raise HTTPException(408, str(exc), CLOSE) from None
        except ClientDisconnect:  # nobody will read the answer; the file is gone with it
            raise HTTPException(400, "the upload was cut off") from None
        entry = await run_in_threadpool(files.keep, received, kind, replace, said)
    if existed and replace:
        response.status_code = 200
    response.headers["Location"] = f"/api/files/{name}"
    return entry


@router.get("/{name}", response_model=FileEntry, responses=documented(404, 422))
def read_file(name: FileName, request: Request) -> dict:
    """One file's entry, as the listing has it."""
    return _files(request).entry(name)


@router.delete("/{name}", status_code=204, responses=documented(404, 409, 422))
def delete_file(name: FileName, request: Request) -> Response:
    """Refused (409) while a scene names the file: change those scenes first."""
    _files(request).delete(name)
    return Response(status_code=204)

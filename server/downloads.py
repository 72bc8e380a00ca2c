"""What a file the API hands out looks like on the wire: its media type, the name it is saved
under, and a zip of several files. Shared by a run's exports (server.routers.exports) and its
split rings' files (server.routers.split_ring), so that every download is named and typed the
same way."""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

from fastapi import Response

# each download's media type and the end of its file name (after the run's, or the run's and
# the ring's, name)
MEDIA = {"csv": ("text/csv; charset=utf-8", ".csv"), "json": ("application/json", "_summary.json"),
         "stl": ("model/stl", ".stl"), "ply": ("application/octet-stream", ".ply"),
         "vtu": ("application/zip", "_vtu.zip"), "npz": ("application/octet-stream", ".npz"),
         "png": ("image/png", ".png")}


def attachment(data: bytes, fmt: str, stem: str) -> Response:
    """``data`` as a ``fmt`` (MEDIA) file the browser saves as ``<stem><suffix>``."""
    media, suffix = MEDIA[fmt]
    return Response(data, media_type=media, headers={
        "Content-Disposition": f'attachment; filename="{stem}{suffix}"'})


def zipped(members: dict[str, Path | str]) -> bytes:
    """A zip of ``members``: each name in it, the file on disk (copied as it is) or a text."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        for name, member in members.items():
            if isinstance(member, Path):
                z.write(member, name)
            else:
                z.writestr(name, member)
    return buf.getvalue()


def content(fmts: list[str]) -> dict:
    """The OpenAPI ``content`` of a route that answers any of ``fmts``."""
    return {MEDIA[f][0]: {} for f in fmts}

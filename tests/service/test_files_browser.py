"""Uploads from the scene form in Debian's chromium (Playwright), against the real server in a
subprocess: the blank's ``mesh.path`` and ``shell.thickness_file`` are selects of the scenes
folder's files with an Upload button beside them. A blank and a thickness file uploaded there
(their names made plain), chosen, saved and run; a file that is no mesh says why in the form;
a name taken asks before replacing; a file past the limit is refused before it is sent.
With Q3T_SHOTS set, screenshots of each step go to `$Q3T_SHOTS/files/`."""

from __future__ import annotations

import socket
from pathlib import Path

import httpx
import pytest
import trimesh

from sim.geometry.trimesh import rectangle
from tests.support.browser import serve, shot, shots_dir
from tests.support.scenes import tiny_toml
from tests.support.service import until

SHOTS = shots_dir("files")
pytestmark = pytest.mark.browser
sync_api = pytest.importorskip("playwright.sync_api", reason="playwright not installed")
PLATE = rectangle((0.7, 0.07), 0.035)  # tiny's mesh: 63 vertices, 80 triangles
LIMIT_MIB = 0.05  # the server's upload limit: 52 kB, above the plate's 3 kB


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("files-browser")
    with serve(tmp, {"tiny": tiny_toml()}, "tiny", "--no-viewer",
               "--max-upload", str(LIMIT_MIB)) as (url, _):
        yield url, tmp


@pytest.fixture
def page(open_page, served):
    return open_page(served[0], "#scenes li.sel", "#scene-form [name='mesh.kind']")


def choose(page, field: str, path: Path) -> None:
    """Click the field's Upload button and pick ``path`` in the file chooser it opens."""
    with page.expect_file_chooser() as chooser:
        page.click(f"[data-path='{field}'] button.upload")
    chooser.value.set_files(str(path))


def status(page, field: str) -> str:
    return page.inner_text(f"[data-path='{field}'] .upload-status")


def left_column(page, name: str) -> None:
    """The left column; the form in it never wider than the column (a long file name in a
    select once widened it, and the form scrolled sideways out of view)."""
    wide = page.evaluate("() => { const f = document.getElementById('scene-form');"
                         " return f.scrollWidth - f.clientWidth; }")
    shot(page, SHOTS, name, where="#left")
    assert wide == 0, f"{name}: the form is {wide} px wider than its column"


def test_a_blank_and_a_thickness_uploaded_from_the_form_run(page, served):
    url, tmp = served
    mine = tmp / "mine"
    mine.mkdir()
    obj = mine / "My plate (v2).OBJ"  # as a user's file may be named
    trimesh.Trimesh(PLATE.vertices, PLATE.faces, process=False).export(obj, file_type="obj")
    (mine / "thickness.txt").write_text("\n".join(["0.007"] * len(PLATE.vertices)) + "\n")

    page.select_option("[name='mesh.kind']", "file")
    page.wait_for_selector("[data-path='mesh.path'] select.file-select")
    page.locator("[data-path='mesh.path']").scroll_into_view_if_needed()
    left_column(page, "1-file-kind.png")
    choose(page, "mesh.path", obj)
    until(lambda: status(page, "mesh.path").startswith("uploaded"), "no upload", 300)
    assert status(page, "mesh.path").startswith("uploaded My_plate_v2.obj: blank mesh: 63 "
                                                "vertices, 80 triangles; ")
    assert page.input_value("[name='mesh.path']") == "My_plate_v2.obj"
    assert (tmp / "scenes" / "My_plate_v2.obj").read_bytes() == obj.read_bytes()

    # the thickness from the file: the constant unset, the file's field set
    page.check("[data-path='shell.thickness'] input.unset")
    page.uncheck("[data-path='shell.thickness_file'] input.unset")
    choose(page, "shell.thickness_file", mine / "thickness.txt")
    until(lambda: status(page, "shell.thickness_file").startswith("uploaded"), "no upload", 300)
    assert status(page, "shell.thickness_file") == ("uploaded thickness.txt: thickness file: "
                                                    "63 values")
    # the form's edits reach the TOML view through the server (a sync after the last edit)
    page.wait_for_function("""() => {
        const t = document.getElementById('toml').value;
        return t.includes('path = "My_plate_v2.obj"')
            && t.includes('thickness_file = "thickness.txt"');
    }""")
    assert page.inner_text("#sync") == "valid"
    page.locator("[data-path='shell.thickness_file']").scroll_into_view_if_needed()
    left_column(page, "2-uploaded.png")

    page.fill("#scene-name", "uploaded")
    page.click("#save")
    # a new name: saved as a new scene (the one opened stays as it was)
    page.wait_for_function("document.getElementById('msg').textContent"
                           ".startsWith('saved as uploaded (')")
    files = {f["name"]: f for f in httpx.get(url + "/api/files").json()["files"]}
    assert files["My_plate_v2.obj"]["used_by"] == ["uploaded"]
    page.click("#start")
    run = until(lambda: httpx.get(url + "/api/runs").json(), "no run")[0]["id"]
    done = until(lambda: (st := httpx.get(f"{url}/api/runs/{run}").json())["state"]
                 in ("finished", "failed", "stopped") and st, "the run never ended")
    assert done["state"] == "finished", done["reason"]
    assert done["scene"] == "uploaded"

    # the saved scene names the blank: the form's Delete is refused, saying by whom
    page.on("dialog", lambda dialog: dialog.accept())
    page.click("[data-path='mesh.path'] button.delete-file")
    until(lambda: "used by" in status(page, "mesh.path"), "no refusal shown", 300)
    assert status(page, "mesh.path") == ("file 'My_plate_v2.obj' is used by scene(s) uploaded "
                                         "(mesh.path); change or delete them first")
    assert (tmp / "scenes" / "My_plate_v2.obj").is_file()
    page.locator("[data-path='mesh.path']").scroll_into_view_if_needed()
    left_column(page, "3-delete-refused.png")


def test_a_file_that_is_no_mesh_says_why(page, served):
    _, tmp = served
    junk = tmp / "junk.stl"
    junk.write_text("solid nothing\nendsolid nothing\n")
    page.select_option("[name='mesh.kind']", "file")
    page.wait_for_selector("[data-path='mesh.path'] select.file-select")
    choose(page, "mesh.path", junk)
    until(lambda: "no triangles" in status(page, "mesh.path"), "no refusal shown", 300)
    assert status(page, "mesh.path") == ("junk.stl: no triangles: not a .stl mesh file (text, "
                                          "another format?), or an empty one")
    assert page.locator("[data-path='mesh.path'] .upload-status.bad").count() == 1
    assert not (tmp / "scenes" / "junk.stl").exists()
    page.locator("[data-path='mesh.path']").scroll_into_view_if_needed()
    left_column(page, "4-refused.png")

    big = tmp / "big.obj"  # past the limit: refused before a byte is sent
    big.write_bytes(b"v 0 0 0\n" * int(LIMIT_MIB * 2**20 / 8 + 1))
    choose(page, "mesh.path", big)
    until(lambda: "limit" in status(page, "mesh.path"), "no size refusal shown", 300)
    assert status(page, "mesh.path").startswith("big.obj: 51.2 KiB is past the server's limit")


def test_a_blank_in_mm_says_its_size_read_as_metres(page, served):
    """A blank drawn in mm uploaded with the scale's metres: the form said "valid" and the
    preview showed a blank 700 m across (a browser review); the upload now says so."""
    _, tmp = served
    mm = tmp / "plate_mm.obj"
    trimesh.Trimesh(PLATE.vertices * 1e3, PLATE.faces, process=False).export(mm)
    page.select_option("[name='mesh.kind']", "file")
    page.wait_for_selector("[data-path='mesh.path'] select.file-select")
    choose(page, "mesh.path", mm)
    until(lambda: status(page, "mesh.path").startswith("uploaded"), "no upload", 300)
    assert status(page, "mesh.path").endswith(
        "across in the file's units (scale: metres per unit); read as metres that is 700 m "
        "across: a file in mm needs scale 0.001"), status(page, "mesh.path")


def test_a_name_taken_asks_before_replacing(page, served):
    url, tmp = served
    half = rectangle((0.35, 0.07), 0.035)
    again = tmp / "again.obj"
    trimesh.Trimesh(PLATE.vertices, PLATE.faces, process=False).export(again)
    assert httpx.post(url + "/api/files", params={"name": "again.obj"},
                      content=again.read_bytes()).status_code == 201
    trimesh.Trimesh(half.vertices, half.faces, process=False).export(again)
    page.select_option("[name='mesh.kind']", "file")
    page.wait_for_selector("[data-path='mesh.path'] select.file-select")
    asked = []

    def answer(dialog):
        asked.append(dialog.message)
        if len(asked) == 1:
            dialog.dismiss()
        else:
            dialog.accept()

    page.on("dialog", answer)
    choose(page, "mesh.path", again)  # declined: the file stays as it was
    until(lambda: "exists" in status(page, "mesh.path"), "no conflict shown", 300)
    assert asked == ["again.obj exists in the scenes folder. Replace it?"]
    assert httpx.get(url + "/api/files/again.obj").json()["triangles"] == 80
    choose(page, "mesh.path", again)  # accepted: replaced
    until(lambda: status(page, "mesh.path").startswith("uploaded"), "no replacement", 300)
    counts = f"{len(half.vertices)} vertices, {len(half.faces)} triangles"
    assert status(page, "mesh.path").startswith(f"uploaded again.obj: blank mesh: {counts}; ")
    options = page.locator("[name='mesh.path'] option").all_inner_texts()
    assert f"again.obj (blank mesh: {counts})" in options, options

    page.click("[data-path='mesh.path'] button.delete-file")  # no scene names it: it goes
    until(lambda: status(page, "mesh.path") == "deleted again.obj", "not deleted", 300)
    assert asked[2:] == ["Delete again.obj from the scenes folder?"]
    assert not (tmp / "scenes" / "again.obj").exists()
    assert page.input_value("[name='mesh.path']") == ""
    assert "again.obj" not in "".join(page.locator("[name='mesh.path'] option").all_inner_texts())
    left_column(page, "5-deleted.png")


def test_an_upload_cut_off_over_a_real_socket_leaves_nothing(served):
    """A client that sends part of a declared body and hangs up: the part was on disk in a
    hidden folder of the scenes folder, and goes; no file appears."""
    url, tmp = served
    scenes = tmp / "scenes"
    host, port = url.removeprefix("http://").split(":")
    with socket.create_connection((host, int(port))) as s:
        s.sendall(b"POST /api/files?name=cut.obj HTTP/1.1\r\nHost: x\r\n"
                  b"Content-Type: application/octet-stream\r\nContent-Length: 40000\r\n\r\n")
        s.sendall(b"v 0 0 0\n" * 1000)
        until(lambda: any(p.name.startswith(".upload-") for p in scenes.iterdir()),
              "the upload never reached the disk")
    until(lambda: not any(p.name.startswith(".upload-") for p in scenes.iterdir()),
          "the cut-off upload was left behind")
    assert not (scenes / "cut.obj").exists()
    assert "cut.obj" not in [f["name"] for f in httpx.get(url + "/api/files").json()["files"]]


def test_past_the_limit_over_http_is_a_413_the_client_reads(served):
    """uvicorn and a real client: the 413 comes back (the connection closed after it), whether
    the length is declared or the body is chunked, and nothing is kept."""
    url, tmp = served
    big = b"v 0 0 0\n" * 125_000  # 1 MB, 20 times the limit

    def chunked():
        for i in range(0, len(big), 10_000):
            yield big[i:i + 10_000]

    for body in (big, chunked()):
        r = httpx.post(url + "/api/files", params={"name": "big.obj"}, content=body)
        assert r.status_code == 413 and "52428 bytes" in r.json()["detail"], r.text
        assert r.headers["connection"] == "close"
    assert not (tmp / "scenes" / "big.obj").exists()

"""A table of an unknown kind in the scene form, in Debian's chromium (Playwright), against the
real server in a subprocess: a mesh whose kind is a typo ("rectangel") shows its other fields
read-only with a note saying the kind is unknown, keeps them through form edits (the TOML
view still has them), and choosing the known kind turns them into fields that save.

With Q3T_SHOTS set, screenshots go to `$Q3T_SHOTS/unknown-kind/`."""

from __future__ import annotations

import tomllib

import pytest

from tests.support.browser import new_page, serve, shot, shots_dir
from tests.support.scenes import tiny_toml

SHOTS = shots_dir("unknown-kind")
pytestmark = pytest.mark.browser
sync_api = pytest.importorskip("playwright.sync_api", reason="playwright not installed")
TYPO = tiny_toml().replace('kind = "rectangle"', 'kind = "rectangel"').replace(
    'name = "tiny"', 'name = "typo"')


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("unknown-kind-browser")
    with serve(tmp, {"tiny": tiny_toml(), "typo": TYPO}, "tiny", "--no-viewer") as (url, _):
        yield url, tmp / "scenes"


def synced(page, text: str, present: bool = True) -> None:
    """The TOML view holds ``text`` (or not) once the server has converted the form."""
    page.wait_for_function("([t, p]) => document.getElementById('toml').value.includes(t) === p"
                           " && document.getElementById('sync').textContent !== '…'",
                           arg=[text, present])


def test_an_unknown_kinds_fields_are_kept_and_shown(browser, served):
    url, scenes = served
    page, errors = new_page(browser, url, "#scenes li.sel", "#scene-form [name='material.E']")
    page.click("#scenes li[data-name='typo']")
    kept = page.locator("#scene-form [data-path='mesh.kept']")
    kept.wait_for()
    assert "size = [0.7,0.07]" in kept.inner_text() and "edge_length = 0.035" in \
        kept.inner_text(), kept.inner_text()
    note = page.locator("#scene-form fieldset[data-path='mesh'] .unknown-kind").inner_text()
    assert 'kind "rectangel" is unknown here' in note and "kept" in note, note
    assert page.input_value("[name='mesh.kind']") == "rectangel"
    assert page.evaluate("state.form.value().mesh") == {
        "kind": "rectangel", "size": [0.7, 0.07], "edge_length": 0.035}
    # an edit elsewhere in the form: the TOML the server renders from it keeps the mesh
    page.fill("[name='description']", "an edited description")
    page.dispatch_event("[name='description']", "input")
    synced(page, "an edited description")
    toml = page.input_value("#toml")
    assert "edge_length = 0.035" in toml and "rectangel" in toml, toml
    shot(page, SHOTS, "01-unknown-kind.png", where="#scene-form fieldset[data-path='mesh']")
    # the known kind chosen: the kept values become its fields, and save
    page.select_option("[name='mesh.kind']", "rectangle")
    assert page.input_value("[name='mesh.edge_length']") == "35"  # mm
    synced(page, "rectangel", present=False)
    page.wait_for_function("document.getElementById('sync').textContent === 'valid'")
    page.click("#save")
    page.wait_for_function("t => document.body.innerText.includes(t)", arg="saved typo")
    mesh = tomllib.loads((scenes / "typo.toml").read_text())["mesh"]
    assert mesh == {"kind": "rectangle", "size": [0.7, 0.07], "edge_length": 0.035}, mesh
    shot(page, SHOTS, "02-saved.png")
    page.close()
    assert not errors, errors

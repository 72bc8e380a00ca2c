"""An outline blank's circle in the page's scene form, in Debian's chromium (Playwright),
against the real server in a subprocess: cup_drawing_outline's circle shown in mm, its radius
edited into the TOML (a radius that leaves the rim ring off the blank named at the ring), a
segment count below the bound named at its field.

With Q3T_SHOTS set, screenshots go to `$Q3T_SHOTS/outline-form/`."""

from __future__ import annotations

import pytest

from tests.support import ROOT
from tests.support.browser import open_scene, serve_without_viewer, shot, shots_dir

SHOTS = shots_dir("outline-form")
pytestmark = pytest.mark.browser
pytest.importorskip("playwright.sync_api", reason="playwright not installed")
CIRCLE = "[data-path='mesh.circle']"


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    text = (ROOT / "scenes/cup_drawing_outline.toml").read_text()
    with serve_without_viewer(tmp_path_factory.mktemp("outline-form"),
                              {"cup_drawing_outline": text}, "cup_drawing_outline") as s:
        yield s


def synced(page, text: str, state: str) -> None:
    """The TOML view holds ``text`` and the sync mark says ``state`` once the server has
    converted the form's edits."""
    page.wait_for_function("([t, s]) => document.getElementById('toml').value.includes(t) && "
                           "document.getElementById('sync').textContent === s",
                           arg=[text, state])


def test_the_circle_is_shown_and_edited_in_the_form(open_page, served):
    url, _ = served
    page = open_scene(open_page, url, "cup_drawing_outline", "[name='mesh.circle.radius']")
    assert page.is_checked("[data-path='mesh.points'] input.unset")  # points: not given
    assert not page.is_checked(f"{CIRCLE} input.unset")
    assert page.input_value("[name='mesh.circle.radius']") == "30"  # mm
    assert page.inner_text("[data-path='mesh.circle.radius'] .unit") == "mm"
    assert [page.input_value(f"[name='mesh.circle.center.{i}']") for i in (0, 1)] == ["0", "0"]
    assert page.input_value("[name='mesh.circle.segments']") == "360"

    # a blank that no longer reaches the flange's ring (24 mm out to the edge) is named at
    # the ring as it is edited
    page.fill("[name='mesh.circle.radius']", "22")
    synced(page, "circle = { radius = 0.022,", "1 error(s)")  # as the form has it
    said = page.inner_text("[data-path='regions.0.ring'] > .field-error")
    assert ("regions.0.ring" not in said  # the field is where it is shown
            and "region 'flange' selects no node: no node of the blank lies 24 mm or more"
            in said), said
    page.locator("[data-path='regions.0.ring']").scroll_into_view_if_needed()
    shot(page, SHOTS, "1-rim-missed.png", where="#left")
    page.fill("[name='mesh.circle.radius']", "31")
    synced(page, "circle = { radius = 0.031, segments = 360 }", "valid")
    page.fill("[name='mesh.circle.segments']", "14")
    synced(page, "segments = 14", "1 error(s)")
    said = page.inner_text("[data-path='mesh.circle.segments'] .field-error")
    assert "greater than or equal to 15" in said, said
    assert page.evaluate("document.querySelector(\"[name='mesh.circle.segments']\")"
                         ".validationMessage") == "must be ≥ 15"
    page.locator(CIRCLE).scroll_into_view_if_needed()
    shot(page, SHOTS, "2-circle-edited.png", where="#left")

"""What a forming engineer reads on the page, in Debian's chromium (Playwright), against the
real server in a subprocess without the viewer:

- a tool's rotation (a shape's rotation vector, a keyframe row's rx, ry, rz) in degrees, the
  file in radians: 90 deg typed is pi/2 in the file to the last bit, and an edit elsewhere
  leaves the rotations' numbers in the file as they were;
- a keyframe row's offsets in mm, its time bare; a thickness gradient in mm/mm;
- the live parameters name the run they act on, and say so when the editor holds another
  scene or an edit;
- with --no-viewer, the 3-D box says the viewer is off and how to turn it on; opened from
  another machine while the viewer stays on loopback, that it cannot be reached and how.

With Q3T_SHOTS set, screenshots go to `$Q3T_SHOTS/page-units/`."""

from __future__ import annotations

import math
import socket
import tomllib

import httpx
import pytest

from tests.support.browser import open_scene, serve, serve_without_viewer, shot, shots_dir
from tests.support.scenes import PRESS_TOML
from tests.support.service import ENDED, until

SHOTS = shots_dir("page-units")
pytestmark = pytest.mark.browser
sync_api = pytest.importorskip("playwright.sync_api", reason="playwright not installed")

QUARTER = 1.5707963267948966  # pi/2, as a scene file written by hand or by Python has it
SIXTH = 0.5235987755982988  # pi/6: 30 deg
# the press with a punch turned a quarter about z (round, so it presses the same) and turning
# a further 30 deg about z down its stroke, and a sheet tapered 5 um per mm along x
TURN = PRESS_TOML.replace('name = "press"', 'name = "turn"').replace(
    'shape = { kind = "punch", radius = 0.004, height = 0.01, edge_radius = 0.001 }',
    'shape = { kind = "punch", radius = 0.004, height = 0.01, edge_radius = 0.001, '
    f'rotation = [0.0, 0.0, {QUARTER}] }}').replace(
    "velocity = [0.0, 0.0, -0.0002]",
    f"keyframes = [[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, -0.0002, 0.0, 0.0, "
    f"{SIXTH}]]").replace(
    "thickness = 0.0005", "thickness = 0.0005\nthickness_gradient = [0.005, 0.0, 0.0]")
PUNCH = "tools.1"


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    scenes = {"press": PRESS_TOML, "turn": TURN}
    with serve_without_viewer(tmp_path_factory.mktemp("page-units"), scenes, "press") as s:
        yield s


def synced(page, *texts: str) -> None:
    """The TOML view holds ``texts`` once the server has converted the form's edits."""
    try:
        page.wait_for_function("ts => ts.every((t) => document.getElementById('toml').value"
                               ".includes(t)) && document.getElementById('sync').textContent"
                               " === 'valid'", arg=list(texts))
    except sync_api.TimeoutError:
        raise AssertionError(f"the form never synced {texts}: sync {page.inner_text('#sync')!r}"
                             f", TOML:\n{page.input_value('#toml')}") from None


def field(page, path: str) -> tuple[str, str]:
    """A number input's text and the unit shown beside it."""
    inp = page.locator(f"input[name='{path}']")
    unit = page.locator(f"[data-path='{path}'] > label > .unit")
    return inp.input_value(), unit.inner_text() if unit.count() else ""


def test_rotations_show_in_degrees_and_go_back_in_radians(open_page, served):
    url, tmp = served
    page = open_scene(open_page, url, "turn", f"[name='{PUNCH}.shape.rotation.2']")
    rotation = f"{PUNCH}.shape.rotation"
    assert page.input_value(f"[name='{rotation}.2']") == "90"
    assert page.inner_text(f"[data-path='{rotation}'] > label > .unit") == "deg"
    # a keyframe row: t bare, offsets in mm, the rotation vector in deg
    row = [field(page, f"{PUNCH}.keyframes.1.{i}") for i in range(7)]
    assert row == [("1", ""), ("0", "mm"), ("0", "mm"), ("-0.2", "mm"), ("0", "deg"),
                   ("0", "deg"), ("30", "deg")], row
    legend = page.inner_text(f"fieldset[data-path='{PUNCH}.keyframes'] > legend")
    assert "(t, mm, deg)" in legend, legend
    # the taper: thickness per length along the sheet, mm/mm (= m/m: the same number)
    gradient = [field(page, f"shell.thickness_gradient.{i}") for i in range(3)]
    assert page.input_value("[name='shell.thickness_gradient.0']") == "0.005"
    assert page.inner_text("[data-path='shell.thickness_gradient'] > label > .unit") == "mm/mm", (
        gradient)
    page.locator(f"fieldset[data-path='{PUNCH}']").scroll_into_view_if_needed()
    page.locator(f"[data-path='{rotation}']").scroll_into_view_if_needed()
    shot(page, SHOTS, "1-rotation-in-deg.png", where="#left")

    # an edit elsewhere, saved: the rotations in the file are the numbers they were
    page.fill("[name='description']", "turned punch")
    synced(page, 'description = "turned punch"')
    page.click("#save")
    page.wait_for_function("() => document.getElementById('msg').textContent === 'saved turn'")
    saved = (tmp / "scenes" / "turn.toml").read_text()
    assert f"rotation = [0.0, 0.0, {QUARTER}]" in saved, saved
    assert f"[1.0, 0.0, 0.0, -0.0002, 0.0, 0.0, {SIXTH}]" in saved, saved

    # 90 deg typed about x: pi/2 to the last bit; 45 in a keyframe: pi/4; -0.1 mm: -0.0001 m
    page.fill(f"[name='{rotation}.0']", "90")
    page.fill(f"[name='{PUNCH}.keyframes.1.5']", "45")
    page.fill(f"[name='{PUNCH}.keyframes.1.3']", "-0,1")
    synced(page, "rotation = [1.57", "0.785")
    page.click("#save")
    page.wait_for_function("() => document.getElementById('msg').textContent === 'saved turn'")
    punch = tomllib.loads((tmp / "scenes" / "turn.toml").read_text())["tools"][1]
    assert punch["shape"]["rotation"] == [math.pi / 2, 0.0, QUARTER]
    assert punch["keyframes"][1] == [1.0, 0.0, 0.0, -0.0001, 0.0, math.pi / 4, SIXTH]
    # and they show as typed when the scene is read again
    page.reload()  # the tab's scene is kept over a reload
    page.wait_for_selector("#scenes li.sel[data-name='turn']")
    page.wait_for_selector(f"[name='{rotation}.0']")
    assert page.input_value(f"[name='{rotation}.0']") == "90"
    assert page.input_value(f"[name='{PUNCH}.keyframes.1.5']") == "45"
    # a bound in degrees: the schema's 160 turns
    page.fill(f"[name='{rotation}.1']", "1e6")
    message = page.eval_on_selector(f"[name='{rotation}.1']", "e => e.validationMessage")
    assert message.startswith("must be ≤ ") and message.endswith(" deg"), message


def test_the_live_parameters_name_the_run_they_act_on(open_page, served):
    url, _ = served
    page = open_scene(open_page, url, "press", "[name='material.E']")
    say = page.locator("#sliders-for")
    until(lambda: "no run selected" in say.inner_text(), f"sliders say {say.inner_text()!r}")
    before = {r["id"] for r in httpx.get(url + "/api/runs").json()}
    page.click("#start")

    def ended() -> dict | None:
        new = [r for r in httpx.get(url + "/api/runs").json() if r["id"] not in before]
        return new[0] if new and new[0]["state"] in ENDED else None

    run = until(ended, "the press never ended")["id"]
    subject = f"Live parameters of run {run} (press; finished)"
    until(lambda: say.inner_text() == subject, f"sliders say {say.inner_text()!r}")
    shot(page, SHOTS, "2-sliders-of-the-run.png", where="#left")

    # another scene in the editor: the sliders still act on the run, and say so
    page.click("#scenes li[data-name='turn']")
    page.wait_for_selector("#scenes li.sel[data-name='turn']")
    until(lambda: "Not the editor's scene (turn)" in say.inner_text(),
          f"sliders say {say.inner_text()!r}")
    assert say.inner_text().startswith(subject)
    shot(page, SHOTS, "3-sliders-another-scene.png", where="#left")
    # the run's own scene back: no warning; a field edited: the warning again
    page.click("#scenes li[data-name='press']")
    page.wait_for_selector("#scenes li.sel[data-name='press']")
    until(lambda: say.inner_text() == subject, f"sliders say {say.inner_text()!r}")
    page.fill("[name='material.nu']", "0.3")
    until(lambda: "Not the editor's scene (press, edited)" in say.inner_text(),
          f"sliders say {say.inner_text()!r}")


def test_without_the_viewer_the_3d_box_says_so(open_page, served):
    url, _ = served
    page = open_page(url, "#scenes li.sel")
    box = page.locator("#viewer-box")
    page.wait_for_selector("#viewer-box.off")
    text = box.inner_text()
    assert "The 3-D viewer is off" in text and "q3t serve --no-viewer" in text, text
    assert "restart it without --no-viewer" in text, text
    assert page.locator("#viewer").count() == 0  # no blank frame
    assert not page.is_visible("#full-window")
    box_size = box.bounding_box()
    assert box_size["width"] > 200 and box_size["height"] > 200, box_size
    shot(page, SHOTS, "4-no-viewer.png")


def test_a_page_from_another_machine_says_the_viewer_is_not_reachable(open_page, tmp_path):
    """The service on all interfaces (``--host 0.0.0.0``, with its token) keeps the viewer on
    loopback: a page opened by the machine's network address cannot reach it, and the 3-D box
    says so and how to reach it, instead of a blank frame."""
    address = lan_address()
    if address is None:
        pytest.skip("this machine has no non-loopback IPv4 address to open the page by")
    with serve(tmp_path, {"press": PRESS_TOML}, "press", "--host", "0.0.0.0",
               token="t0ken") as (url, vport):
        remote = url.replace("127.0.0.1", address)
        page = open_page(f"{remote}/?token=t0ken", "#scenes li.sel")
        page.wait_for_selector("#viewer-box.off")
        text = page.locator("#viewer-box").inner_text()
        assert "The 3-D viewer is not reachable from this machine" in text, text
        assert f"127.0.0.1:{vport}" in text and "--expose-viewer" in text, text
        assert page.locator("#viewer").count() == 0  # no blank frame
        shot(page, SHOTS, "5-viewer-not-reachable.png")
        # the same server opened on its own machine (loopback) shows the viewer
        page = open_page(f"{url}/?token=t0ken", "#scenes li.sel")
        assert page.get_attribute("#viewer", "src").startswith(f"http://127.0.0.1:{vport}/")


def lan_address() -> str | None:
    """This machine's address on its network (the one a route out would use), if any."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(("192.0.2.1", 9))  # no packet is sent: UDP connect only picks a route
            address = s.getsockname()[0]
        except OSError:
            return None
    return None if address.startswith("127.") else address

"""A forming engineer's own inputs from the page (issue 18) in Debian's chromium (Playwright),
against the real server in a subprocess, each a run of a few steps on a coarse mesh:

- an outline drawing (SVG, a hole in it) uploaded for the blank from the form, run;
- the material's Hill48 fields (r-values, rolling direction) edited in the form, with their
  units and descriptions, and run as unsaved edits;
- a Hill48 cup drawn through its die shows its rim height around the axis, in mm;
- tool meshes in the scenes folder offered for a mesh tool's surface, each labelled with its
  kind (tool mesh, blank mesh).

With Q3T_SHOTS set, screenshots of each go to `$Q3T_SHOTS/forming-inputs/`."""

from __future__ import annotations

import tomllib
from pathlib import Path

import httpx
import pytest
import trimesh

from tests.support import ROOT
from tests.support.browser import (
    js_number,
    open_scene,
    serve_without_viewer,
    shot,
    shots_dir,
    stacked_rows,
)
from tests.support.scenes import PRESS_TOML, tiny_cup_toml
from tests.support.service import ENDED, until

SHOTS = shots_dir("forming-inputs")
pytestmark = pytest.mark.browser
sync_api = pytest.importorskip("playwright.sync_api", reason="playwright not installed")
# the press in 2 steps, its centre held by the vertices within 3 mm (an outline's unstructured
# mesh has none within the press's 1 mm)
PRESS = PRESS_TOML.replace("steps = 3", "steps = 2").replace(
    "min = [-0.001, -0.001, -1.0], max = [0.001, 0.001, 1.0]",
    "min = [-0.003, -0.003, -1.0], max = [0.003, 0.003, 1.0]")
# a 20 x 20 mm blank (drawing units mm) with a 3 mm hole off the punch
SVG = ('<svg xmlns="http://www.w3.org/2000/svg" width="20mm" height="20mm" '
       'viewBox="-10 -10 20 20">'
       '<path d="M -10 -10 H 10 V 10 H -10 Z"/><circle cx="6" cy="6" r="1.5"/></svg>')
HILL = {"r0": 0.663, "r45": 0.86, "r90": 0.717}  # AA5754-O (scenes/cup_drawing_aa5754.toml)
# the tiny cup as a Hill48 sheet drawn through its die: a 15 mm blank, 8 mm of stroke in 4
# steps (a few seconds), its whole edge up the wall, so the summary has its rim
EARS = tiny_cup_toml(4).replace('name = "tiny_cup"', 'name = "ears"').replace(
    "r_outer = 0.012\nedge_length = 0.003", "r_outer = 0.0075\nedge_length = 0.0035").replace(
    'flc = { kind = "keeler_brazier", n = 0.2 }',
    'flc = { kind = "keeler_brazier", n = 0.2 }\n'
    'hill48 = { r0 = 0.663, r45 = 0.86, r90 = 0.717, rolling_angle = 0.0 }').replace(
    "velocity = [0.0, 0.0, -0.002]", "velocity = [0.0, 0.0, -0.008]")


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """The server's url and its folder (scenes/, runs/), without the viewer: the press and
    the Hill48 cup."""
    scenes = {"press": PRESS, "ears": EARS}
    with serve_without_viewer(tmp_path_factory.mktemp("forming-inputs"), scenes, "press") as s:
        yield s


def upload(page, field: str, path: Path) -> str:
    """Upload ``path`` with the field's Upload button; the form's word on it."""
    with page.expect_file_chooser() as chooser:
        page.click(f"[data-path='{field}'] button.upload")
    chooser.value.set_files(str(path))
    said = f"[data-path='{field}'] .upload-status"
    page.wait_for_function(f"""() => /^(uploaded|.*:)/.test(
        document.querySelector("{said}").textContent)""")
    return page.inner_text(said)


def synced(page, *texts: str) -> None:
    """The TOML view holds ``texts`` once the server has converted the form's edits (a
    hang guard's failure says what the page shows instead)."""
    try:
        page.wait_for_function("ts => ts.every((t) => document.getElementById('toml').value"
                               ".includes(t)) && document.getElementById('sync').textContent"
                               " === 'valid'", arg=list(texts))
    except sync_api.TimeoutError:
        errors = page.locator("#scene-form .field-error").all_inner_texts()
        raise AssertionError(f"the form never synced {texts}: sync "
                             f"{page.inner_text('#sync')!r}, errors {[e for e in errors if e]}, "
                             f"TOML:\n{page.input_value('#toml')}") from None


def started_run(page, url: str) -> dict:
    """Start a run with the page's button: its status once it has ended (a hang guard's
    failure says what the page and the run showed last)."""
    before = {r["id"] for r in httpx.get(url + "/api/runs").json()}
    page.click("#start")
    seen: dict = {}

    def ended() -> dict | None:
        runs = [r["id"] for r in httpx.get(url + "/api/runs").json() if r["id"] not in before]
        st = httpx.get(f"{url}/api/runs/{runs[0]}").json() if runs else {}
        seen.update(message=page.inner_text("#msg"), **{k: st.get(k) for k in (
            "id", "state", "step", "reason")})
        return st if st.get("state") in ENDED else None

    try:
        return until(ended, "")
    except AssertionError:
        raise AssertionError(f"the run never ended, last seen: {seen}") from None


def test_an_outline_drawing_uploaded_for_the_blank_runs(open_page, served):
    url, tmp = served
    drawing = tmp / "Blank with hole.svg"
    drawing.write_text(SVG)
    page = open_scene(open_page, url, "press", "[name='mesh.kind']")
    page.select_option("[name='mesh.kind']", "outline")
    page.wait_for_selector("[data-path='mesh.path'] select.file-select")
    page.uncheck("[data-path='mesh.path'] input.unset")
    assert upload(page, "mesh.path", drawing) == (  # in mm as the file says: no scale
        "uploaded Blank_with_hole.svg: outline drawing: 1 hole; 20 × 20 across in the file's "
        'units, each 1 mm as it says (width="20mm" over a viewBox 20 wide): scale may be left '
        "empty")
    page.fill("[name='mesh.edge_length']", "4")  # mm, as the form shows lengths
    synced(page, 'path = "Blank_with_hole.svg"', "edge_length = 0.004")
    assert "scale" not in page.input_value("#toml")
    page.locator("[data-path='mesh.path']").scroll_into_view_if_needed()
    shot(page, SHOTS, "1-outline-uploaded.png", where="#left")
    st = started_run(page, url)
    assert st["state"] == "finished", st["reason"]
    built = httpx.get(f"{url}/api/runs/{st['id']}/result").json()["built"]["mesh"]
    assert built["vertices"] > 20, built  # the drawing's blank, not the press's rectangle
    assert st["records"][-1]["probes"]["punch_force"] > 0
    page.wait_for_function("([id]) => { const s = document.getElementById('summary');"
                           " return s.dataset.run === id && s.dataset.ready === 'true'; }",
                           arg=[st["id"]])  # its summary drawn: the run ended on the page too
    shot(page, SHOTS, "2-outline-run.png")


def test_hill48_fields_edited_in_the_form_run(open_page, served):
    url, _ = served
    page = open_scene(open_page, url, "press", "[name='material.E']")
    hill = "material.hill48"
    page.uncheck(f"fieldset[data-path='{hill}'] > legend input.unset")
    for name, value in HILL.items():
        page.uncheck(f"[data-path='{hill}.{name}'] input.unset")
        page.fill(f"[name='{hill}.{name}']", str(value))
        # dimensionless: no unit, and the name's tooltip says what it is
        assert page.locator(f"[data-path='{hill}.{name}'] .unit").count() == 0
        title = page.get_attribute(f"[data-path='{hill}.{name}'] .key", "title")
        assert "r-value" in title and "rolling direction" in title, title
    page.uncheck(f"[data-path='{hill}.rolling_angle'] input.unset")
    page.fill(f"[name='{hill}.rolling_angle']", "30")
    assert page.inner_text(f"[data-path='{hill}.rolling_angle'] .unit") == "deg"
    synced(page, "hill48", "r45 = 0.86", "rolling_angle = 30")
    page.focus(f"[name='{hill}.r45']")
    page.locator(f"fieldset[data-path='{hill}']").scroll_into_view_if_needed()
    shot(page, SHOTS, "3-hill48-fields.png", where="#left")
    st = started_run(page, url)
    assert st["state"] == "finished", st["reason"]
    assert st["edited"]  # the form's edits ran, the saved scene is as it was
    ran = tomllib.loads(httpx.get(f"{url}/api/runs/{st['id']}/scene").text)
    hill48 = ran["material"]["hill48"]
    assert {k: hill48[k] for k in [*HILL, "rolling_angle"]} == {**HILL, "rolling_angle": 30.0}
    assert "hill48" not in httpx.get(f"{url}/api/scenes/press").json()["toml"]


def test_a_hill48_cup_shows_its_rim_height_around_the_axis_in_mm(open_page, served):
    url, _ = served
    page = open_scene(open_page, url, "ears", "[name='material.hill48.r0']")
    st = started_run(page, url)
    assert st["state"] == "finished", st["reason"]
    page.wait_for_selector("#rim-fig:not([hidden])")
    summary = {e["name"]: e for e in httpx.get(f"{url}/api/runs/{st['id']}/summary").json()
               ["summary"]}
    largest = summary["max_rim_height"]["display"]
    assert largest["unit"] == "mm"
    plot = page.evaluate("""() => { const d = document.getElementById('rim-plot');
        return { y: d.data[0].y, x: d.data[0].x, ytitle: d.layout.yaxis.title.text,
                 xtitle: d.layout.xaxis.title.text }; }""")
    assert plot["ytitle"] == "rim height (mm)" and "(deg)" in plot["xtitle"]
    assert max(plot["y"]) == pytest.approx(largest["value"], rel=1e-9)
    # the rim of a cup drawn 8 mm: millimetres up the wall, not metres, all round
    assert 1 < min(plot["y"]) <= max(plot["y"]) < 8, plot["y"]
    assert min(plot["x"]) >= 0 and max(plot["x"]) <= 360 and plot["x"] == sorted(plot["x"])
    card = page.locator("#summary .quantity[data-name='earing'] .value").inner_text()
    assert card.endswith(" %"), card
    # an earing that is the mesh's six waves more than the sheet's four ears says so on the card
    flag = summary["earing"].get("flag") or ""
    earing = page.locator("#summary .quantity[data-name='earing']")
    assert earing.get_attribute("data-flag") == flag
    assert ("the mesh's, not ears" in earing.locator(".at").inner_text()) == \
        (flag == "mesh")
    # a card's tooltip says what else its entry holds: the rim's highest point's angle
    angle = summary["max_rim_height"]["at"]["angle"]["display"]["value"]
    tip = page.get_attribute("#summary .quantity[data-name='max_rim_height']", "title")
    assert f"at {js_number(angle)} deg about the punch axis" in tip, tip
    page.locator("#rim-fig").scroll_into_view_if_needed()
    shot(page, SHOTS, "4-rim-height.png", settle_ms=500)  # the plot settles
    probes_have_a_legend_per_quantity(page)


def probes_have_a_legend_per_quantity(page) -> None:
    """The probes' plot: a row per quantity (the cup's tool force, thickness, displacement),
    each with a legend of its own above it, titled with the quantity and its unit and naming
    that row's probes; the rows and their legends stacked without overlapping."""
    page.wait_for_selector("#probes-fig:not([hidden])")
    rows = stacked_rows(page, "probes-plot")
    assert [(r["title"], r["unit"], r["names"]) for r in rows] == [
        ("<b>tool force</b> (kN)", "kN", ["punch_force"]),
        ("<b>thickness</b> (mm)", "mm", ["min_thickness"]),
        ("<b>displacement</b> (mm)", "mm", ["centre_dz"])], rows


def test_probe_legends_fit_above_their_rows(open_page, served):
    """The page's first scene's probes (cup_drawing_outline: 15 probes of 10 kinds) drawn at
    the plot column's narrowest width (320 px), at 600 and 900 px, and drawn at one of 320
    and 900 px then resized to the other (a window resized): each quantity's legend, as
    plotly draws it, ends above its own row's plot and inside the plot's width."""
    url, _ = served
    page = open_page(url, "#scenes li.sel")
    probes = tomllib.loads((ROOT / "scenes/cup_drawing_outline.toml").read_text())["probes"]
    series = [{"name": p["name"], "kind": p["kind"], "unit": "mm", "steps": [0, 1, 2],
               "values": [0.0, 1.0, 2.0]} for p in probes]
    heights = {}
    for widths in ((320,), (600,), (900,), (900, 320), (320, 900)):
        rows = page.evaluate("""async ([series, widths]) => {
            const div = document.createElement('div');
            div.style.width = widths[0] + 'px';
            document.body.append(div);
            await Plots.probes(div, series, []);
            for (const w of widths.slice(1)) {
              // the plot is drawn again once the resize is seen: its height changes with
              // the legends' lines (at most a second: a hang fails here, not in the wait)
              const before = div._fullLayout.height;
              div.style.width = w + 'px';
              for (let t = 0; t < 50 && div._fullLayout.height === before; t++)
                await new Promise((ok) => setTimeout(ok, 20));
            }
            const L = div._fullLayout, box = div.getBoundingClientRect(), rows = [];
            for (let k = 1; L[k > 1 ? 'legend' + k : 'legend']; k++) {
              const g = div.querySelector('g.legend' + (k > 1 ? k : '')).getBoundingClientRect();
              rows.push({ bottom: g.bottom - box.top, right: g.right - box.left,
                          plot: L[k > 1 ? 'yaxis' + k : 'yaxis']._offset,
                          height: L.height,
                          names: div.data.filter((t) => t.legend === (k > 1 ? 'legend' + k
                                                                           : 'legend')).length });
            }
            Plots.purge(div);
            div.remove();
            return rows; }""", [series, list(widths)])
        width = widths[-1]
        assert len(rows) == len({p["kind"] for p in probes}), rows
        assert sum(r["names"] for r in rows) == len(probes)
        for r in rows:
            assert r["bottom"] <= r["plot"] and r["right"] <= width, (widths, r)
        heights[widths] = rows[0]["height"]
    # the legends take more lines the narrower the plot, and a resized plot is laid out as
    # one drawn at its new width
    assert heights[(320,)] > heights[(600,)] > heights[(900,)], heights
    assert heights[(900, 320)] == heights[(320,)] and heights[(320, 900)] == heights[(900,)]


def test_tool_meshes_are_offered_for_a_mesh_tool_labelled_by_kind(open_page, served):
    url, tmp = served
    punch = trimesh.creation.cylinder(radius=0.004, height=0.01, sections=48)
    sheet = trimesh.creation.box([0.01, 0.01, 0.001])
    for name, mesh, kind in (("punch.stl", punch, "tool"),
                             ("sheet.obj", trimesh.Trimesh(sheet.vertices, sheet.faces[:2]),
                              "blank")):
        r = httpx.post(f"{url}/api/files", params={"name": name, "kind": kind},
                       content=mesh.export(file_type=Path(name).suffix[1:]))
        assert r.status_code == 201, r.text
    field = "tools.1.shape.path"  # the press's punch
    page = open_scene(open_page, url, "press", "[name='tools.1.shape.kind']")
    page.select_option("[name='tools.1.shape.kind']", "mesh")
    page.wait_for_function(f"""() => document.querySelectorAll(
        "[name='{field}'] option").length > 2""")
    options = page.locator(f"[name='{field}'] option").all_inner_texts()
    # the field's own kind first, each with its kind in words
    sheet = httpx.get(f"{url}/api/files/sheet.obj").json()
    assert options[1:] == ["punch.stl (tool mesh: 98 vertices, 192 triangles)",
                           f"sheet.obj (blank mesh: {sheet['vertices']} vertices, 2 triangles)"]
    page.select_option(f"[name='{field}']", "punch.stl")
    synced(page, 'path = "punch.stl"')
    page.locator(f"[data-path='{field}']").scroll_into_view_if_needed()
    shot(page, SHOTS, "5-tool-meshes.png", where="#left")

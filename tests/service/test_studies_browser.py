"""A refinement study from the page (web/studies.js) in Debian's chromium, against the real
server in a subprocess: a finished run shows "Study: error against mesh size"; opened, it
plans the scene's default study with the run's element added, each case's DoFs, memory and
predicted time as the API gives them; levels typed wrong are said at once, a level too fine for
the server's memory is refused naming the field; a study started shows its progress and ends
with the run's error estimate in the headline; a study cancelled says so. A run not finished
has no such panel. With Q3T_SHOTS set, screenshots go to its folder studies."""

from __future__ import annotations

import httpx
import pytest

from tests.support.browser import VIEWER_FOR_SHOTS, open_scene, serve, shot, shots_dir
from tests.support.scenes import tiny_toml

SHOTS = shots_dir("studies")
pytestmark = pytest.mark.browser
sync_api = pytest.importorskip("playwright.sync_api", reason="playwright not installed")


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("studies-browser")
    with serve(tmp, {"tiny": tiny_toml()}, "tiny", *VIEWER_FOR_SHOTS,
               "--max-memory", "0.5") as (url, _):
        yield url, tmp / "runs"


def finished_with_study(open_page, url: str, asked: list | None = None):
    """The tiny scene run from the page to its end, its study panel opened on its plan; the
    page and the run's id. ``asked``: the urls the page requests go to this list."""
    page = open_scene(open_page, url, "tiny", "[name='mesh.kind']")
    if asked is not None:
        page.on("request", lambda r: asked.append(r.url))
    before = page.get_attribute("#status", "data-run") or ""
    if not before:  # no run shown: nothing to study
        assert page.is_hidden("#study-box")
    page.click("#start")
    # the new run, finished (the page may show an earlier finished run until it starts)
    page.wait_for_function("(b) => { const s = document.getElementById('status').dataset; "
                           "return s.run && s.run !== b && s.state === 'finished'; }", arg=before)
    page.wait_for_selector("#study-box:not([hidden])")
    page.click("#study-box summary")
    page.wait_for_selector("#study-table")
    return page, page.get_attribute("#status", "data-run")


def start(page, cases: int, **inputs: str) -> None:
    """The study of ``inputs`` (``#study-<key>``: its text) planned with ``cases`` cases and
    started, once the page says it runs."""
    for key, text in inputs.items():
        page.fill(f"#study-{key.replace('_', '-')}", text)
    page.click("#study-plan")
    page.wait_for_function(f"document.querySelectorAll('#study-table tbody tr').length === "
                           f"{cases}")
    page.click("#study-start")
    page.wait_for_selector("#study-progress[data-state='running']")
    assert page.is_visible("#study-cancel")


def test_a_study_is_planned_started_and_gives_the_estimate(served, open_page):
    url, runs = served
    assert httpx.get(f"{url}/api/runs").json() == []  # nothing finished: nothing to study
    asked = []
    page, run = finished_with_study(open_page, url, asked)
    assert "no study for this scene" in page.inner_text("#estimate")
    # an elastic run has no forming limit diagram: the page does not ask for one (a 404 in
    # the console), which the run's plots said
    assert httpx.get(f"{url}/api/runs/{run}/plots").json()["forming_limits"] is False
    assert not [u for u in asked if "forming_limits" in u], asked
    # the headline's line points at the panel, which its link opens
    page.click("#study-box summary")  # closed again, for the link to open
    assert not page.eval_on_selector("#study-box", "b => b.open")
    assert page.inner_text("#estimate-plan") == "plan one under the plots"
    page.click("#estimate-plan")
    assert page.eval_on_selector("#study-box", "b => b.open")
    plan = httpx.post(f"{url}/api/studies/plan", json={"run": run}).json()
    assert page.input_value("#study-elements") == ", ".join(plan["elements"])
    assert page.input_value("#study-levels") == "140, 70, 35"
    assert (page.input_value("#study-ref-element"), page.input_value("#study-ref-edge")) == (
        "quadratic", "17.5")
    rows = page.eval_on_selector_all("#study-table tbody tr", "rs => rs.map(r => "
                                     "[...r.cells].map(c => c.textContent))")
    assert len(rows) == len(plan["cases"])
    assert rows[0][0] == "quadratic 17.5 mm (ref.)" and rows[1][0] == "linear 140 mm"
    assert [r[1] for r in rows] == [f"{c['dofs']:,}" for c in plan["cases"]]
    assert page.inner_text("#study-table tfoot").startswith(
        f"whole study, warm-up included ({len(rows)} cases; largest build 0.3")
    notes = page.inner_text("#study-notes")
    assert "within about a factor of two" in notes and "q3t study tiny --elements" in notes
    assert page.is_enabled("#study-start")
    page.locator("#study-box").scroll_into_view_if_needed()
    shot(page, SHOTS, "plan.png", settle_ms=500)
    # typed wrong: said at once, and nothing can start
    # a field edited after the plan: Start waits for Plan (it starts the plan on screen)
    page.fill("#study-levels", "140, 70")
    assert page.is_disabled("#study-start") and page.is_visible("#study-stale")
    # a decimal comma is a decimal comma
    page.fill("#study-levels", "70, 17,5")
    page.click("#study-plan")
    page.wait_for_function("document.getElementById('study-stale').hidden")
    assert [r[0] for r in page.eval_on_selector_all(
        "#study-table tbody tr", "rs => rs.map(r => [...r.cells].map(c => c.textContent))")
        if r[0].startswith("linear")] == ["linear 70 mm", "linear 17.5 mm"]
    page.fill("#study-levels", "70, -35")
    page.click("#study-plan")
    assert page.inner_text("#study-error") == (
        "levels: mesh edge lengths in mm, positive numbers, separated by commas")
    assert page.is_disabled("#study-start")
    # the server's word, naming the field: a level finer than the reference, ...
    page.fill("#study-levels", "70, 5")
    page.click("#study-plan")
    page.wait_for_function("document.getElementById('study-error').textContent !== ''")
    assert page.inner_text("#study-error").startswith(
        "reference.edge_mm: 17.5 mm is coarser than the finest level (5 mm)")
    assert page.inner_text("#study-cases") == ""  # no plan on screen
    # ... and a reference too fine for the server's memory (--max-memory 0.5)
    page.fill("#study-ref-edge", "5")
    page.click("#study-plan")
    page.wait_for_function("document.getElementById('study-error').textContent"
                           ".startsWith('reference.edge_mm: quadratic')")
    assert page.inner_text("#study-error").startswith(
        "reference.edge_mm: quadratic at 5 mm would have ")
    # a small study: two levels of two elements against the quadratic prism at 17.5 mm
    start(page, 5, elements="q3t, linear", levels="70, 35", ref_edge="17.5")
    assert page.inner_text("#study-progress").startswith("Study of tiny running: ")
    assert "now: quadratic 17.5 mm (reference), " in page.inner_text("#study-progress")
    shot(page, SHOTS, "running.png", settle_ms=300)
    page.wait_for_selector("#study-progress[data-state='finished']", timeout=180_000)
    assert page.is_hidden("#study-cancel")
    assert page.inner_text("#study-progress").startswith("Study of tiny finished: 5 cases in ")
    assert "done: linear 35 mm, converged, " in page.inner_text("#study-progress")
    # the headline's estimate comes from the study's report at the next poll
    page.wait_for_function("document.getElementById('estimate').dataset.available === 'true'")
    est = page.inner_text("#estimate")
    assert est.startswith("error estimate: ") and "vs quadratic at 17.5 mm" in est
    assert (runs / "study-tiny" / "report.json").is_file()
    shot(page, SHOTS, "finished.png", settle_ms=500)


def test_a_study_cancelled_from_the_page_says_so(served, open_page):
    url = served[0]
    page, _ = finished_with_study(open_page, url)
    # the three routine elements and the reference at one level
    start(page, 4, levels="35", ref_edge="10")
    assert page.inner_text("#study-line .text").startswith("Study of tiny running: ")
    # a page opened meanwhile (a reload) shows the study in its headline, whichever run it
    # shows, and cancels it from there (the panel is under a finished run's plots)
    other = open_page(url, "#scenes li.sel")
    other.wait_for_selector("#study-line[data-state='running']")
    assert other.is_visible("#study-line-cancel") and other.is_hidden("#study-line-close")
    shot(other, SHOTS, "reloaded-running.png", settle_ms=300)
    other.click("#study-line-cancel")
    other.wait_for_selector("#study-line[data-state='cancelled']")
    assert "cancelled after" in other.inner_text("#study-line .text")
    other.click("#study-line-close")
    assert other.is_hidden("#study-line")
    # the page that started it hears it too, at its next poll of the study
    page.wait_for_selector("#study-progress[data-state='cancelled']")
    assert "cancelled after" in page.inner_text("#study-progress")
    # the first test's study wrote the scene's report, which a cancelled one leaves
    assert "the scene's last report stays" in page.inner_text("#study-progress")
    assert page.is_enabled("#study-start")
    shot(page, SHOTS, "cancelled.png", settle_ms=300)
    # the page opened cold, with no study running, has no study line
    assert open_page(url, "#scenes li.sel").is_hidden("#study-line")

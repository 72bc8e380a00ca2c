"""The documentation stays true: the scene reference is what the schema renders, the README's
example scene loads and runs as it stands, the README names every shipped scene and every
``q3t`` command, every relative link in README.md and docs/ leads to a file (and heading), and
every test a page names exists."""

import ast
import importlib
import io
import re
import tomllib
from contextlib import redirect_stdout
from pathlib import Path

import pytest

from sim.scene.load import scene_from_toml
from sim.scene_reference import reference
from sim.stepping.simulation import Simulation
from tests.support import ROOT

README = (ROOT / "README.md").read_text()
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


def test_the_scene_reference_is_the_schema_rendered():
    on_disk = (ROOT / "docs" / "scene-reference.md").read_text()
    assert on_disk == reference(), "docs/scene-reference.md is out of date: run make docs"


def test_the_readme_example_scene_runs_as_it_stands():
    """The README's one TOML block, unchanged: it validates, builds and dents the sheet, and
    the dent stays after the release (plastic) but springs back a little (elastic)."""
    blocks = re.findall(r"```toml\n(.*?)```", README, re.S)
    assert len(blocks) == 1, "the README should hold exactly one example scene"
    sim = Simulation.from_scene(scene_from_toml(blocks[0]))
    assert sim.run(), sim.failure
    pressing, released = sim.records[:-1], sim.records[-1]
    assert len(pressing) == sim.model.scene.stepping.steps
    force = [r.probes["punch_force"] for r in pressing]
    assert all(b > a > 0 for a, b in zip(force, force[1:], strict=False))  # the sheet resists
    assert released.probes["punch_force"] == 0.0  # the punch is retracted
    loaded, after = pressing[-1].probes["centre"], released.probes["centre"]
    assert loaded < -0.003  # dented by most of the 4 mm stroke
    # most of the dent is kept; the springback, elastic recovery of a few per cent, is far
    # above the 1e-3 that tells it from no change at all
    assert loaded * (1 - 1e-3) < after < 0.5 * loaded


def _q3t_commands() -> list[str]:
    """The subcommands of the ``q3t`` entry point pyproject.toml declares."""
    target = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]["q3t"]
    module, func = target.split(":")
    out = io.StringIO()
    with redirect_stdout(out), pytest.raises(SystemExit):
        getattr(importlib.import_module(module), func)(["--help"])
    return re.search(r"\{([\w,-]+)\}", out.getvalue()).group(1).split(",")


def test_the_readme_names_every_scene_and_command():
    for scene in sorted((ROOT / "scenes").glob("*.toml")):
        assert f"| `{scene.stem}` |" in README, f"scenes/{scene.name} is not in the README"
    for cmd in _q3t_commands():
        assert f"`q3t {cmd}" in README, f"q3t {cmd} is not in the README's command table"


def _anchors(page: Path) -> set[str]:
    """The anchors GitHub gives a page's headings: lower case, punctuation dropped, spaces
    to hyphens."""
    heads = re.findall(r"^#+ (.+)$", page.read_text(), re.M)
    return {re.sub(r"[^\w\- ]", "", h.lower()).replace(" ", "-") for h in heads}


@pytest.mark.parametrize("page", PAGES, ids=[str(p.relative_to(ROOT)) for p in PAGES])
def test_relative_links_lead_to_files_and_headings(page):
    for target, anchor in re.findall(r"\]\(([^)#\s]*)(?:#([^)\s]*))?\)", page.read_text()):
        if "://" in target:
            continue
        path = page.parent / target if target else page
        assert path.exists(), f"{page.name}: no {target}"
        if anchor:
            assert anchor in _anchors(path), f"{page.name}: no heading #{anchor} in {target}"


# tests/<tier>/test_x.py, or test_x.py alone (verification.md), with an optional ::test_name
TEST_REF = re.compile(r"(?<![\w/.])((?:tests/[\w/]*)?test_\w+\.py)(?:::(\w+))?")


def _test_files() -> dict[str, list[Path]]:
    by_name: dict[str, list[Path]] = {}
    for path in sorted((ROOT / "tests").rglob("test_*.py")):
        by_name.setdefault(path.name, []).append(path)
    return by_name


def _functions(path: Path) -> set[str]:
    return {n.name for n in ast.walk(ast.parse(path.read_text())) if isinstance(n, ast.FunctionDef)}


@pytest.mark.parametrize("page", PAGES, ids=[str(p.relative_to(ROOT)) for p in PAGES])
def test_the_tests_a_page_names_exist(page):
    """A path under tests/ is a file there; a bare file name is one file of the tiers; a
    ``::test`` is a function of that file. A test file moved or renamed, or a test renamed,
    fails here until the pages follow."""
    by_name = _test_files()
    for ref, test in TEST_REF.findall(page.read_text()):
        if ref.startswith("tests/"):
            path = ROOT / ref
            assert path.is_file(), f"{page.name}: no {ref}"
        else:
            found = by_name.get(ref, [])
            assert len(found) == 1, f"{page.name}: {ref} is {len(found)} files under tests/"
            path = found[0]
        assert not test or test in _functions(path), f"{page.name}: no {test} in {ref}"

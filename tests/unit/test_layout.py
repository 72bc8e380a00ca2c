"""The import graph keeps the layout: the solver (sim outside sim/apps) imports neither its
command-line apps nor the server, the server does not import the apps, no two project modules
import each other round a circle, and the service's commands join ``q3t`` through the
``q3t.commands`` entry points declared in pyproject.toml (so sim never imports server). The tests
keep a layout too: each test file in a tier folder, no test module importing another.

Imports are read from the source with ast, those inside functions included: a lazy import is
still an arrow of the graph."""

import ast
import importlib.util
import tomllib
from importlib.metadata import EntryPoint, entry_points
from pathlib import Path

import pytest

from sim.apps import cli
from sim.apps.cases import PRELOAD
from tests.support import ROOT

PACKAGES = ("sim", "server")
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _sources() -> dict[str, Path]:
    return {_module_name(p): p for pkg in PACKAGES for p in sorted((ROOT / pkg).rglob("*.py"))}


def _imported(node: ast.AST, module: str, is_package: bool, known: set[str]) -> list[str]:
    """The project modules an import statement names: ``from a import b`` is module ``a.b`` when
    that is a module, else ``a``; relative imports are resolved against ``module``."""
    if isinstance(node, ast.Import):
        names = [a.name for a in node.names]
    else:
        base = node.module or ""
        if node.level:
            pkg = module.split(".") if is_package else module.split(".")[:-1]
            pkg = pkg[:len(pkg) - node.level + 1]
            base = ".".join([*pkg, *([base] if base else [])])
        names = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base
                 for a in node.names]
    out = []
    for name in names:
        while name and name not in known:  # import a.b.c of a package: the longest module
            name = name.rpartition(".")[0]
        if name:
            out.append(name)
    return out


def import_graph() -> dict[str, set[str]]:
    """Project module -> the project modules it imports (anywhere in its source)."""
    src = _sources()
    graph: dict[str, set[str]] = {}
    for mod, path in src.items():
        tree = ast.parse(path.read_text(), str(path))
        graph[mod] = {t for n in ast.walk(tree) if isinstance(n, ast.Import | ast.ImportFrom)
                      for t in _imported(n, mod, path.name == "__init__.py", set(src))} - {mod}
    return graph


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    out = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while (w := stack.pop()) != v:
                comp.append(w)
            if comp:
                out.append(sorted([v, *comp]))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def _apps(mod: str) -> bool:
    return mod == "sim.apps" or mod.startswith("sim.apps.")


def _server(mod: str) -> bool:
    return mod == "server" or mod.startswith("server.")


GRAPH = import_graph()


def test_the_graph_sees_function_level_imports():
    # the apps load dask and the solver lazily; the graph must still have those arrows
    assert "sim.stepping.simulation" in GRAPH["sim.apps.cases"]
    assert "sim.apps.common" in GRAPH["sim.apps.sweep"]


def test_the_solver_imports_neither_its_apps_nor_the_server():
    bad = {m: sorted(t for t in ts if _apps(t) or _server(t))
           for m, ts in GRAPH.items() if m.startswith("sim") and not _apps(m)}
    assert {m: ts for m, ts in bad.items() if ts} == {}


def test_sim_never_imports_the_server():
    bad = {m: sorted(t for t in ts if _server(t)) for m, ts in GRAPH.items()
           if m.startswith("sim")}
    assert {m: ts for m, ts in bad.items() if ts} == {}


def test_the_server_does_not_import_the_apps():
    bad = {m: sorted(t for t in ts if _apps(t)) for m, ts in GRAPH.items() if _server(m)}
    assert {m: ts for m, ts in bad.items() if ts} == {}


def test_no_import_circle_through_the_apps_or_the_server():
    assert [c for c in circles(GRAPH) if any(_apps(m) or _server(m) for m in c)] == []


def test_no_import_circle():
    assert circles(GRAPH) == []


def test_the_circle_finder_finds_circles():
    g = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}
    assert circles(g) == [["a", "b", "c"]]


def test_no_app_imports_a_private_name_of_another_module():
    src = _sources()
    bad = []
    for mod, path in src.items():
        if not _apps(mod):
            continue
        for n in ast.walk(ast.parse(path.read_text())):
            if isinstance(n, ast.ImportFrom) and n.module and n.module.split(".")[0] in PACKAGES:
                bad += [f"{mod}: {n.module}.{a.name}" for a in n.names
                        if a.name.startswith("_") and n.module != mod]
    assert bad == []


def test_the_forkserver_preloads_modules_that_exist():
    # a name that no longer exists is skipped without a word by multiprocessing: every case
    # would then import the solver itself
    assert all(importlib.util.find_spec(m) is not None for m in PRELOAD)


def _declared() -> list[EntryPoint]:
    group = PYPROJECT["project"]["entry-points"][cli.COMMANDS]
    return [EntryPoint(name, value, cli.COMMANDS) for name, value in group.items()]


def test_q3t_is_the_apps_main():
    assert PYPROJECT["project"]["scripts"]["q3t"] == "sim.apps.cli:main"


def test_the_service_commands_join_q3t_through_the_entry_points(monkeypatch, capsys):
    """The group as pyproject.toml declares it (whatever is installed): ``q3t serve`` is found
    through it, and the declared objects are the server's."""
    assert [ep.value for ep in _declared()] == ["server.cli:add_parser"]
    monkeypatch.setattr(cli, "entry_points", lambda group: [e for e in _declared()
                                                            if e.group == group])
    with pytest.raises(SystemExit) as exc:
        cli.main(["serve", "--help"])
    assert exc.value.code == 0 and "--expose-viewer" in capsys.readouterr().out


def test_without_the_service_stack_q3t_has_no_service_commands(monkeypatch, capsys):
    """An entry point whose module does not import (the service extra not installed) is left
    out, as before: q3t's own commands still work and serve is an unknown command."""
    missing = EntryPoint("service", "no_such_module_q3t:add_parser", cli.COMMANDS)
    monkeypatch.setattr(cli, "entry_points", lambda group: [missing])
    with pytest.raises(SystemExit) as exc:
        cli.main(["serve"])
    assert exc.value.code == 2 and "invalid choice: 'serve'" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        cli.main(["run", "--help"])
    assert exc.value.code == 0


def test_the_installed_entry_points_are_the_declared_ones():
    """The service tests start ``python -m sim.apps serve``, which finds serve only in the
    installed metadata: a stale install (pyproject.toml changed since) is said here first."""
    installed = {(ep.name, ep.value) for ep in entry_points(group=cli.COMMANDS)}
    declared = {(ep.name, ep.value) for ep in _declared()}
    assert installed == declared, ("the installed package metadata is stale: reinstall "
                                   "(make, or pip install -e .)")


def _imports_of(path: Path) -> set[str]:
    """Every module an import in ``path`` names, with the names it imports from one (``from
    tests.unit import test_x`` names tests.unit.test_x)."""
    out = set()
    for n in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(n, ast.Import):
            out |= {a.name for a in n.names}
        elif isinstance(n, ast.ImportFrom):
            base = n.module or ""
            out |= {base, *(f"{base}.{a.name}" for a in n.names)}
    return out


def test_test_files_sit_in_tiers_and_no_test_module_imports_another():
    """tests/ holds tier folders and tests/support/, no test file of its own. What test modules
    share is a helper in tests/support/: importing a test module would run its module-level
    set-up (and skips) in the importer and tie two tiers together."""
    tests = ROOT / "tests"
    files = sorted(tests.rglob("test_*.py"))
    assert files and all(p.parent.parent == tests and p.parent.name != "support" for p in files)
    for path in sorted(tests.rglob("*.py")):
        named = [m for m in _imports_of(path) if any(part.startswith("test_")
                                                     for part in m.split("."))]
        assert not named, f"{path.relative_to(ROOT)} imports the test modules {named}"

"""The scene files' field reference, docs/scene-reference.md, rendered from the schema itself.

Each table of a scene is a section listing its fields with their type, bounds, default and the
comment the schema's source gives them, so the reference says exactly what ``load_scene``
accepts. ``python -m sim.scene_reference [PATH]`` writes it (``make docs``);
tests/unit/test_docs.py fails when the file differs from what this renders.
"""

from __future__ import annotations

import ast
import inspect
import io
import json
import re
import sys
import textwrap
import tokenize
import typing
from pathlib import Path

from pydantic import BaseModel

from sim.scene.load import Scene

TOP = "top level"  # the scene's own fields
OUT = Path(__file__).resolve().parent.parent / "docs" / "scene-reference.md"
HEADER = """\
# Scene field reference

Generated from the scene schema by `make docs` (`python -m sim.scene_reference`); do not edit
by hand: `tests/unit/test_docs.py` fails when this file and the schema differ. How the tables fit
together, with examples: [scenes.md](scenes.md). Units are SI (m, Pa, kg, s, N). A field without
a default is required; "unset" means the field may be left out, and what then happens is in its
note or the table's description. Checks that tie fields together (a mesh kind's required
fields, one thickness source, a law's own parameters) are in the table descriptions.
"""


def reference() -> str:
    """The whole reference as markdown."""
    schema = Scene.model_json_schema()
    defs = schema["$defs"]
    classes = _model_classes(Scene)
    parts, done = [HEADER], {}
    for path, name in [(TOP, "Scene"), *_tables(schema["properties"], defs, "")]:
        node = schema if name == "Scene" else defs[name]
        if name in done:
            continue
        parts.append(_section(path, node, classes[name], done))
        done[name] = (path, node)
    return "\n".join(parts)


def _tables(props: dict, defs: dict, prefix: str) -> list[tuple[str, str]]:
    """(path, schema name) of every table below ``props``, in document order; a path is
    dotted, ``[]`` marking a list of tables (``tools[].shape``)."""
    out = []
    for field, s in props.items():
        ref, many = _ref(s)
        if ref is None:
            continue
        path = f"{prefix}.{field}" if prefix else field
        path += "[]" if many else ""
        out.append((path, ref))
        out += _tables(defs[ref]["properties"], defs, path)
    return out


def _title(path: str) -> str:
    """A table's heading as a scene file writes it: ``[mesh]``, ``[[tools]]``; nested ones by
    their dotted path."""
    if "." in path or path == TOP:
        return path
    return f"[[{path[:-2]}]]" if path.endswith("[]") else f"[{path}]"


def _ref(s: dict) -> tuple[str | None, bool]:
    """The table a field holds (its schema name) and whether it is a list of them."""
    s = _non_null(s)
    if "$ref" in s:
        return s["$ref"].rsplit("/", 1)[1], False
    items = s.get("items", {})
    if "$ref" in items:
        return items["$ref"].rsplit("/", 1)[1], True
    return None, False


def _section(path: str, node: dict, cls: type[BaseModel], done: dict) -> str:
    comments = _field_comments(cls)
    rows = ["| field | type | bounds | default | note |", "|---|---|---|---|---|"]
    like = _same_fields(node, done)
    for field, s in node["properties"].items():
        if like and like[1]["properties"].get(field) == s:
            continue
        default = "required" if field in node.get("required", []) else _default(s)
        rows.append(f"| `{field}` | {_type(s)} | {_bounds(s)} | {default} | "
                    f"{_cell(comments.get(field, ''))} |")
    head = "## The scene file's top level" if path == TOP else f"## `{_title(path)}`"
    intro = [_markdown(_description(cls, with_bases=like is None))] if cls is not Scene else []
    if like:
        intro.append(f"Every field of `{_title(like[0])}`, the same way, except:")
    return "\n\n".join([head, *(i for i in intro if i), "\n".join(rows)]) + "\n"


def _description(cls: type[BaseModel], with_bases: bool) -> str:
    """The class's docstring, and those of the model classes it inherits fields from (the
    tool shape's ``_Shape``) unless their fields were described already."""
    docs = [k.__dict__.get("__doc__") for k in cls.__mro__
            if issubclass(k, BaseModel) and k is not BaseModel
            and (k is cls or with_bases)]
    return "\n\n".join(inspect.cleandoc(d) for d in docs if d)


def _same_fields(node: dict, done: dict) -> tuple[str, dict] | None:
    """An already rendered table sharing most fields with ``node`` (the tool shape's operands
    are the shape again, with other kinds): only the differences are listed then."""
    for path, other in done.values():
        shared = [f for f, s in node["properties"].items() if other["properties"].get(f) == s]
        if len(shared) > len(node["properties"]) / 2:
            return path, other
    return None


def _non_null(s: dict) -> dict:
    """A field that may be left unset is ``anyOf [X, null]``: X."""
    alts = [a for a in s.get("anyOf", []) if a.get("type") != "null"]
    return {**s, **alts[0]} if len(alts) == 1 else s


def _type(s: dict) -> str:
    s = _non_null(s)
    ref, many = _ref(s)
    if ref:
        return "list of tables" if many else "table"
    if "enum" in s:
        return "one of " + ", ".join(f'`"{v}"`' for v in s["enum"])
    if "const" in s:
        return f'`"{s["const"]}"`'
    if s.get("type") == "array":
        if "prefixItems" in s:
            return "[" + ", ".join(_type(i) for i in s["prefixItems"]) + "]"
        return "list of " + _plural(_type(s.get("items", {})))
    if s.get("type") == "string" and "pattern" in s:
        return f"string matching `{s['pattern']}`"
    return {"number": "number", "integer": "integer", "string": "string",
            "boolean": "boolean"}.get(s.get("type"), "any")


def _plural(t: str) -> str:
    return t + "s" if t in ("number", "integer", "string", "boolean") else t


def _bounds(s: dict) -> str:
    """``lo < x <= hi`` of a number, or of every item of an array when they share it."""
    s = _non_null(s)
    items = s.get("prefixItems") or ([s["items"]] if isinstance(s.get("items"), dict) else [])
    if s.get("type") == "array":
        each = {_bounds(i) for i in items}
        inner = each.pop().removeprefix("each ") if len(each) == 1 else ""
        return f"each {inner}" if inner else ""
    lo = [f"{_num(s[k])} {op} x" for k, op in (("minimum", "≤"), ("exclusiveMinimum", "<"))
          if k in s]
    hi = [f"x {op} {_num(s[k])}" for k, op in (("maximum", "≤"), ("exclusiveMaximum", "<"))
          if k in s]
    if lo and hi:
        return f"{lo[0]}{hi[0][1:]}"
    return (lo or hi or [""])[0]


def _default(s: dict) -> str:
    if "default" not in s:
        return "required"
    v = s["default"]
    if v is None:
        return "unset"
    if isinstance(v, dict):
        return "its defaults"
    return f"`{_toml(v)}`"


def _toml(v: object) -> str:
    """A default as a scene file writes it."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return _num(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml(x) for x in v) + "]"
    return json.dumps(v)


def _num(v: float) -> str:
    """1e6, not 1e+06."""
    return re.sub(r"e\+?(-?)0*(\d)", r"e\1\2", f"{v:g}") if isinstance(v, float) else str(v)


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def _markdown(doc: str) -> str:
    """A docstring as markdown: reST's ``code`` becomes `code`."""
    return re.sub(r"``(.+?)``", r"`\1`", doc.strip())


def _model_classes(root: type[BaseModel]) -> dict[str, type[BaseModel]]:
    """Every model class reachable from ``root`` through its fields' types, by name."""
    found: dict[str, type[BaseModel]] = {}

    def visit(tp: object) -> None:
        if isinstance(tp, type) and issubclass(tp, BaseModel):
            if tp.__name__ not in found:
                found[tp.__name__] = tp
                for f in tp.model_fields.values():
                    visit(f.annotation)
            return
        for arg in typing.get_args(tp):
            visit(arg)

    visit(root)
    return found


def _field_comments(cls: type[BaseModel]) -> dict[str, str]:
    """The source comments of each field: the comment lines right above it and the comment at
    the end of its line(s), from the class that declares it (base classes included)."""
    out: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if not (isinstance(klass, type) and issubclass(klass, BaseModel)) or klass is BaseModel:
            continue
        try:
            source = textwrap.dedent(inspect.getsource(klass))
        except (OSError, TypeError):
            continue
        out.update(_comments_in(source))
    return out


def _comments_in(source: str) -> dict[str, str]:
    lines = source.splitlines()
    comment_at = {tok.start[0]: tok.string.lstrip("#").strip()
                  for tok in tokenize.generate_tokens(io.StringIO(source).readline)
                  if tok.type == tokenize.COMMENT}
    body = ast.parse(source).body[0].body
    out = {}
    for node in body:
        if not (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)):
            continue
        above, n = [], node.lineno - 1
        while n >= 1 and lines[n - 1].lstrip().startswith("#"):
            above.insert(0, comment_at[n])
            n -= 1
        after = [comment_at[k] for k in range(node.lineno, node.end_lineno + 1)
                 if k in comment_at]
        text = " ".join(above + after)
        if text:
            out[node.target.id] = text
    return out


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    path = Path(args[0]) if args else OUT
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(reference())
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

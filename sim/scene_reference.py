"""The scene files' field reference, docs/scene-reference.md, rendered from the schema itself.

Each table of a scene is a section listing its fields with their type, unit, bounds, default
and description, all from the schema (``Scene.model_json_schema()``: the same descriptions and
units the page's form and /docs show), so the reference says exactly what ``load_scene``
accepts. A table of several kinds (``[mesh]``, a tool's shape, ``[[loads]]``) has a section per
kind, listing that kind's fields. ``python -m sim.scene_reference [PATH]`` writes it (``make
docs``); tests/unit/test_docs.py fails when the file differs from what this renders.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

from sim.scene.load import TAGS, Scene

TOP = "top level"  # the scene's own fields
OUT = Path(__file__).resolve().parent.parent / "docs" / "scene-reference.md"
HEADER = """\
# Scene field reference

Generated from the scene schema by `make docs` (`python -m sim.scene_reference`); do not edit
by hand: `tests/unit/test_docs.py` fails when this file and the schema differ. How the tables fit
together, with examples: [scenes.md](scenes.md). Values are SI in the file (m, Pa, kg, s, N);
the unit column names each number's ("1": a plain number; the page's form shows lengths in mm,
stresses in MPa, forces in kN and angles in deg, and writes SI). A field without a default is
required; "unset" means the field may be left out, and what then happens is in its
description. A table of several kinds takes the fields of its `kind` only; checks that tie
fields together (one thickness source, a law's own parameters) are in the table descriptions.
"""


def reference() -> str:
    """The whole reference as markdown."""
    schema = Scene.model_json_schema()
    defs = schema["$defs"]
    parts, done = [HEADER], {}
    tables = [(TOP, "Scene", False), *_tables(schema["properties"], defs, "")]
    for path, name, of_kinds in tables:
        if name in done:
            continue
        node = schema if name == "Scene" else defs[name]
        head = _heading(path, node, of_kinds)
        # a table two parts of the file share (a ring of nodes) is rendered once, under both
        # names; a CSG operand, the same table nested in itself, is not another name
        parent = path.rsplit(".", 1)[0]
        also = [f"`{_title(p)}`" for p, n, _ in tables
                if n == name and p != path and not p.startswith(parent)]
        head += "".join(f", {a}" for a in also)
        parts.append(_section(head, node, done))
        done[name] = (head, node)
    return "\n".join(parts)


def _tables(props: dict, defs: dict, prefix: str) -> list[tuple[str, str, bool]]:
    """(path, schema name, whether it is one of several kinds) of every table below
    ``props``, in document order; a path is dotted, ``[]`` marking a list of tables
    (``tools[].shape``)."""
    out = []
    for field, s in props.items():
        refs, many = _refs(s)
        path = f"{prefix}.{field}" if prefix else field
        path += "[]" if many else ""
        for ref in refs:
            out.append((path, ref, len(refs) > 1))
            out += _tables(defs[ref]["properties"], defs, path)
    return out


def _title(path: str) -> str:
    """A table's heading as a scene file writes it: ``[mesh]``, ``[[tools]]``; nested ones by
    their dotted path."""
    if "." in path or path == TOP:
        return path
    return f"[[{path[:-2]}]]" if path.endswith("[]") else f"[{path}]"


def _refs(s: dict) -> tuple[list[str], bool]:
    """The tables a field holds (schema names: one, or one per kind) and whether it is a
    list of them."""
    s = _non_null(s)
    many = "$ref" not in s and "oneOf" not in s and isinstance(s.get("items"), dict)
    s = s["items"] if many else s
    alts = s.get("oneOf", [s])
    refs = [a["$ref"].rsplit("/", 1)[1] for a in alts if "$ref" in a]
    return refs, many and bool(refs)


def _heading(path: str, node: dict, of_kinds: bool) -> str:
    """``[mesh]``, kind `disk`: the table and, of a table of several kinds, its kind."""
    if path == TOP:
        return "The scene file's top level"
    tag = next((t for t in TAGS if t in node["properties"]), "kind")
    kind = node["properties"].get(tag, {})
    kinds = ([kind["const"]] if "const" in kind else kind.get("enum", [])) if of_kinds else []
    return f"`{_title(path)}`" + (f", {tag} {' / '.join(f'`{k}`' for k in kinds)}"
                                  if kinds else "")


def _section(head: str, node: dict, done: dict) -> str:
    rows = ["| field | type | unit | bounds | default | description |",
            "|---|---|---|---|---|---|"]
    like = _same_fields(node, done)
    for field, s in node["properties"].items():
        if like and like[1]["properties"].get(field) == s:
            continue
        default = "required" if field in node.get("required", []) else _default(s)
        rows.append(f"| `{field}` | {_type(s)} | {s.get('unit', '')} | {_bounds(s)} | "
                    f"{default} | {_cell(s.get('description', ''))} |")
    intro = [_markdown(node.get("description", ""))] if node["title"] != "Scene" else []
    if like:
        intro.append(f"Every field of {like[0]}, the same way, except:")
    return "\n\n".join([f"## {head}", *(i for i in intro if i), "\n".join(rows)]) + "\n"


def _same_fields(node: dict, done: dict) -> tuple[str, dict] | None:
    """An already rendered table of the same kind sharing most fields with ``node`` (a CSG
    operand is the tool's CSG shape again, with other operands): only the differences are
    listed then."""
    kind = node["properties"].get("kind", {}).get("enum")
    for path, other in done.values():
        if other["properties"].get("kind", {}).get("enum") != kind:
            continue
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
    refs, many = _refs(s)
    if refs:
        what = "list of tables" if many else "table"
        return what + (" (of a kind)" if len(refs) > 1 else "")
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
    return text.replace("|", "\\|").replace("\n", " ")


def _markdown(doc: str) -> str:
    """A docstring as markdown: reST's ``code`` becomes `code`."""
    return re.sub(r"``(.+?)``", r"`\1`", doc.strip())


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    path = Path(args[0]) if args else OUT
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(reference())
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

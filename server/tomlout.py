"""Scene dicts to TOML text: ``tomli_w`` when it is installed, else the small emitter here;
and an edit of a scene file's own text (``edited``, ``renamed``), which keeps its comments,
layout and number formats (tomlkit's round trip).

The emitter covers what scenes use: tables, arrays of tables, inline tables for small objects
(``plane = { point = [...], normal = [...] }``), numbers, strings, booleans and arrays. TOML has
no null: ``None`` values in tables are left out; a ``None`` inside an array is an error.
"""

from __future__ import annotations

import math
import re
from collections.abc import MutableMapping

import tomlkit
from tomlkit.exceptions import TOMLKitError
from tomlkit.items import AoT, Array, InlineTable

BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")
INLINE_WIDTH = 88  # a nested table whose ``key = { ... }`` line fits is written inline


def have_tomli_w() -> bool:
    try:
        import tomli_w  # noqa: F401
    except ImportError:
        return False
    return True


def to_toml(data: dict, *, emitter: str = "auto") -> str:
    """``emitter``: "auto" (tomli_w if installed), "tomli_w" or "builtin"."""
    data = drop_none(data)
    if emitter == "tomli_w" or (emitter == "auto" and have_tomli_w()):
        import tomli_w

        return tomli_w.dumps(data)
    return dumps(data)


def drop_none(value: object) -> object:
    """The value without ``None`` entries in tables (TOML cannot say null)."""
    if isinstance(value, dict):
        return {k: drop_none(v) for k, v in value.items() if v is not None}
    if isinstance(value, (list, tuple)):
        return [drop_none(v) for v in value]
    return value


def key(k: str) -> str:
    return k if BARE_KEY.match(k) else string(k)


def string(s: str) -> str:
    out = []
    for ch in s:
        if ch == "\\":
            out.append("\\\\")
        elif ch == '"':
            out.append('\\"')
        elif ch == "\n":
            out.append("\\n")
        elif ch == "\t":
            out.append("\\t")
        elif ch == "\r":
            out.append("\\r")
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04x}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def number(x: float) -> str:
    if math.isnan(x):
        return "nan"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    ax = abs(x)
    if ax == 0 or 1e-4 <= ax < 1e6:
        return repr(x)  # shortest round-trip, always with "." or "e"
    for p in range(17):  # shortest scientific form that reads back to the same float
        s = f"{x:.{p}e}"
        if float(s) == x:
            break
    mant, _, exp = s.partition("e")
    return f"{mant}e{int(exp)}"


def value(v: object, where: str = "value") -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return number(v)
    if isinstance(v, str):
        return string(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(value(x, f"{where}.{i}") for i, x in enumerate(v)) + "]"
    if isinstance(v, dict):
        if not v:
            return "{}"
        return "{ " + ", ".join(f"{key(k)} = {value(x, f'{where}.{k}')}" for k, x in v.items()
                               if x is not None) + " }"
    if v is None:
        raise ValueError(f"{where}: TOML has no null")
    raise ValueError(f"{where}: cannot write {type(v).__name__} as TOML")


def _is_table_array(v: object) -> bool:
    return isinstance(v, list) and bool(v) and all(isinstance(x, dict) for x in v)


def dumps(data: dict) -> str:
    """TOML text of ``data``; reads back (tomllib) to the same dict, with tuples as lists."""
    blocks: list[list[str]] = []
    _table(data, [], None, blocks)
    return "\n".join("\n".join(b) for b in blocks if b).rstrip("\n") + "\n"


def _table(d: dict, path: list[str], header: str | None, blocks: list[list[str]]) -> None:
    lines = [header] if header else []
    later: list[tuple[str, object]] = []
    for k, v in d.items():
        if v is None:
            continue
        where = ".".join([*path, k])
        if isinstance(v, dict) or _is_table_array(v):
            line = f"{key(k)} = {value(v, where)}"
            if path and len(line) <= INLINE_WIDTH:  # small and nested: inline
                lines.append(line)
            else:
                later.append((k, v))
        else:
            lines.append(f"{key(k)} = {value(v, where)}")
    if header is not None or lines:
        lines.append("")
        blocks.append(lines)
    for k, v in later:
        sub = [*path, k]
        name = ".".join(key(p) for p in sub)
        if isinstance(v, dict):
            _table(v, sub, f"[{name}]", blocks)
        else:
            for item in v:
                _table(item, sub, f"[[{name}]]", blocks)


# ---- edits of a scene file's text ---------------------------------------------------------------
def edited(base: str, old: dict, new: dict, lean: dict) -> str:
    """``base``, a scene file's TOML, with what differs between ``old`` (its scene, every
    field) and ``new`` (the edited scene, every field) written into it: comments, layout and
    the format of every value left alone are kept (``68.0e9`` stays). A field the file lacks
    is added only when ``lean`` (the edited scene without its defaults) has it; a field the
    edit drops (unset, or of another kind) is removed."""
    doc = tomlkit.parse(base)
    _apply(doc, old, new, lean)
    return tomlkit.dumps(doc)


def renamed(text: str, name: str) -> str:
    """A scene file's text with its ``name`` field set to ``name`` (a copy under a new
    name); a text that is not TOML, or has no top-level name, as it was."""
    try:
        doc = tomlkit.parse(text)
    except TOMLKitError:
        return text
    if not isinstance(doc.get("name"), str):
        return text
    doc["name"] = name
    return tomlkit.dumps(doc)


def with_element(text: str, element: str) -> str:
    """A scene file's text with ``[shell] element`` set to ``element`` (the copy of a run
    made with another element than its file's: it runs again as it ran); its trailing comment,
    which described the file's element, dropped. A text that is not TOML, as it was."""
    try:
        doc = tomlkit.parse(text)
    except TOMLKitError:
        return text
    if "shell" not in doc:
        doc["shell"] = tomlkit.table()
    doc["shell"]["element"] = element
    _uncomment(doc["shell"]["element"])
    return tomlkit.dumps(doc)


def _apply(node: MutableMapping, old: dict, new: dict, lean: dict) -> None:
    for k in [k for k in node if new.get(k) is None]:
        del node[k]
    for k, v in new.items():
        if v is None or old.get(k) == v:
            continue
        if k not in node:
            if k in lean:
                node[k] = _item(lean[k], _inline(node))
        elif isinstance(v, dict) and isinstance(old.get(k), dict):
            _apply(node[k], old[k], v, lean.get(k, {}))
            if isinstance(node[k], InlineTable):
                _uncomment(node[k])
        elif _tables(v) and _tables(old.get(k)) and isinstance(node[k], (AoT, Array)):
            _apply_list(node[k], old[k], v, lean.get(k, []))
            if isinstance(node[k], Array):  # inline tables on one line: one comment for all
                _uncomment(node[k])
        else:
            node[k] = _item(lean.get(k, v), _inline(node))
            _uncomment(node[k])


def _uncomment(item: object) -> None:
    """An edited line loses its trailing comment: it described the value the file had
    (``velocity = [0.0, 0.0, -0.03]   # 25 mm stroke`` would mislead), and tomlkit carries
    it over to the new value. Comment lines of their own stay."""
    trivia = getattr(item, "trivia", None)
    if trivia is not None:
        trivia.comment = trivia.comment_ws = ""


def _apply_list(items: AoT | Array, old: list, new: list, lean: list) -> None:
    """Tables of a list edited item by item; items added at the end or dropped from it."""
    for i, v in enumerate(new[: len(old)]):
        _apply(items[i], old[i], v, lean[i] if i < len(lean) else {})
    for i in range(len(old) - 1, len(new) - 1, -1):
        del items[i]
    for v in lean[len(old):]:
        item = _item(v, inline=isinstance(items, Array))  # AoT: a [[table]]
        if isinstance(items, AoT):
            item.add(tomlkit.nl())  # a blank line before the next table, as scene files have
        items.append(item)


def _tables(v: object) -> bool:
    return isinstance(v, list) and all(isinstance(x, dict) for x in v)


def _inline(parent: MutableMapping) -> bool | None:
    """Inside an inline table everything is inline; elsewhere a table is inline if short."""
    return True if isinstance(parent, InlineTable) else None


def _item(v: object, inline: bool | None) -> object:
    """A new value as this module writes it (``6.8e10``, not ``68000000000.0``); a table
    inline (``inline``), a [table] (False) or inline when its line is short (None)."""
    v = drop_none(v)
    if isinstance(v, dict) and (inline is False or
                                (inline is None and len(value(v)) > INLINE_WIDTH)):
        table = tomlkit.table()
        for k, x in v.items():
            table[k] = _item(x, None)
        return table
    return tomlkit.value(value(v))

"""Checks on parsed TOML or JSON (nested dicts and lists) before anything recursive sees it:
nesting depth, text that is not Unicode and TOML's dates. Both parsers accept what the rest
cannot take: arrays nested a thousand deep (every recursive walk after them overflows the
stack), JSON's ``"\\ud800"``, a lone surrogate (no UTF-8 for it: it cannot be written or sent
back), and TOML's dates and times, which no scene field takes and JSON cannot carry (the
scene is validated as JSON, whose error would name no field)."""

from __future__ import annotations

import datetime

# levels of tables and arrays within each other; the deepest scene (a tool's CSG shape of CSG
# operands with polygon points) needs 9, a request body with a scene 11
MAX_DEPTH = 32


def _dotted(path: tuple) -> str:
    return ".".join(str(p) for p in path)


def _not_text(s: str) -> str | None:
    try:
        s.encode("utf-8")
        return None
    except UnicodeEncodeError as exc:
        return f"{s[exc.start]!r} at character {exc.start} is not text (a lone surrogate)"


def tree_problem(data: object, limit: int = MAX_DEPTH, prefix: tuple = ()) -> str | None:
    """A problem of ``data`` as ``"<path>: <reason>"`` (the path of keys and indices
    from ``prefix``), or None. Iterative: it must not overflow on what it checks."""
    stack = [(prefix, data)]
    while stack:
        path, value = stack.pop()
        if len(path) - len(prefix) > limit:
            return f"{_dotted(path[:len(prefix) + limit])}: nested deeper than {limit} levels"
        if isinstance(value, str):
            if (why := _not_text(value)) is not None:
                return f"{_dotted(path) or 'value'}: {why}"
        elif isinstance(value, dict):
            for key, item in value.items():
                if (why := _not_text(key)) is not None:
                    return f"{_dotted(path) or 'value'}: a key: {why}"
                stack.append((path + (key,), item))
        elif isinstance(value, list):
            stack.extend((path + (i,), item) for i, item in enumerate(value))
        elif isinstance(value, (datetime.date, datetime.time)):  # a datetime is a date
            return f"{_dotted(path) or 'value'}: a TOML date or time, which no scene field takes"
    return None

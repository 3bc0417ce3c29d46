"""Key paths into nested TOML/JSON data: ``loops.cart.controller.gains[1]``, one module for all of them.

A key path is a list of parts, ``str`` for a table key and ``int`` for an array index::

    parse("loops.cart.z0[1]")            -> ["loops", "cart", "z0", 1]
    text(["grid", "sim.period"])         -> 'grid."sim.period"'   (a key that is not a bare TOML key is quoted)
    assign(data, parts, value, source)   sets a value in place (creating tables), ScenarioError if it cannot
    flatten({"a": {"b": [1, 2]}})        -> {"a.b[0]": 1, "a.b[1]": 2}

Used by ``--set`` (scenario loader), the sweep file (its [set], [grid], [draw] keys name scenario key
paths), the sweep table's columns and the replay diff of recorded metrics.
"""

from __future__ import annotations

import re

from ftstab_mj.config.errors import ScenarioError, describe

_BARE = re.compile(r"^[A-Za-z0-9_-]+$")  # a TOML bare key
_PATH = re.compile(r"^[A-Za-z0-9_-]+(\[\d+\])*(\.[A-Za-z0-9_-]+(\[\d+\])*)*$")
MAX_PARTS = 32  # deeper than any table of the schema; bounds what a --set can create


def parse(path: str) -> list | None:
    """The parts of ``path`` (``"a.b[1]"`` -> ``["a", "b", 1]``), or None when it is not a key path."""
    if len(path) > 1000 or not _PATH.match(path):
        return None
    parts: list = []
    for piece in path.split("."):
        name, *idx = piece.split("[")
        parts.append(name)
        parts.extend(int(i.rstrip("]")) for i in idx)
    return parts if len(parts) <= MAX_PARTS else None


def join(path: str, key) -> str:
    """``path`` extended by one part: ``a.b`` + 1 -> ``a.b[1]``; + "c" -> ``a.b.c``; + "x.y" -> ``a.b."x.y"``."""
    if isinstance(key, int):
        return f"{path}[{key}]"
    k = key if _BARE.match(key) else quote(key)
    return f"{path}.{k}" if path else k


def text(parts) -> str:
    """The key path of ``parts`` as written in errors and columns (inverse of :func:`parse` on bare keys)."""
    out = ""
    for p in parts:
        out = join(out, p)
    return out


def quote(key: str) -> str:
    """``key`` as a TOML basic string (the quoting of keys and string values)."""
    out = ['"']
    for c in key:
        if c in '"\\':
            out.append("\\" + c)
        elif c == "\n":
            out.append("\\n")
        elif c == "\t":
            out.append("\\t")
        elif ord(c) < 0x20 or ord(c) == 0x7F:  # TOML forbids raw control characters in strings
            out.append(f"\\u{ord(c):04x}")
        else:
            out.append(c)
    return "".join(out) + '"'


def bare(key: str) -> bool:
    """True when ``key`` needs no quotes in TOML (letters, digits, '_' and '-')."""
    return bool(_BARE.match(key))


def within(path: str, prefix: str) -> bool:
    """True when ``path`` is ``prefix`` or lies inside it (``a.b[1]`` lies inside ``a.b``)."""
    return path == prefix or path.startswith(prefix + ".") or path.startswith(prefix + "[")


def has(data, parts) -> bool:
    """Whether the key path ``parts`` exists in ``data``."""
    node = data
    for part in parts:
        if isinstance(part, int):
            if not isinstance(node, list) or part >= len(node):
                return False
        elif not isinstance(node, dict) or part not in node:
            return False
        node = node[part]
    return True


def assign(data: dict, parts, value, source: str) -> None:
    """Set ``data[parts] = value`` in place, creating missing tables (and arrays before an index).

    A table value replaces the whole table at that path (``loops.cart.controller = {...}`` swaps a
    law's parameters for another's). Raises ScenarioError(source, ...) when a part of the path is an
    array index that does not exist or a key under something that is not a table.
    """

    node, path = data, ""
    for part, nxt in zip(parts, list(parts[1:]) + [None]):
        if isinstance(part, int):
            if not isinstance(node, list) or part >= len(node):
                size = f"an array of {len(node)} items" if isinstance(node, list) else describe(node)
                raise ScenarioError(source, join(path, part), "an existing array index", size)
        elif not isinstance(node, dict):
            raise ScenarioError(source, path, "a table to set a key in", describe(node))
        if nxt is None:
            node[part] = value
        else:
            if isinstance(node, dict) and part not in node:
                node[part] = [] if isinstance(nxt, int) else {}
            node = node[part]
        path = join(path, part)


def flatten(value, prefix: str = "", out: dict | None = None) -> dict:
    """Spread nested tables and arrays into ``out`` as {"a.b[0]": scalar}; returns ``out``."""
    out = {} if out is None else out
    stack = [(prefix, value)]  # iterative: input depth is bounded by the readers, not by Python's stack
    while stack:
        path, v = stack.pop()
        if isinstance(v, dict):
            stack.extend((join(path, k), x) for k, x in reversed(list(v.items())))
        elif isinstance(v, (list, tuple)):
            stack.extend((join(path, i), x) for i, x in reversed(list(enumerate(v))))
        else:
            out[path] = v
    return out

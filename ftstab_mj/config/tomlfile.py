"""TOML in and out: the one reader of input files (scenario, sweep, expectations) and the one writer.

Reading: every failure names the file, a key path ("(file)" for the file itself, "(TOML syntax)" for
a parse error), what was expected and what was found, through the caller's ScenarioError subclass.
The text is bounded (size, nesting: ftstab_mj.config.validate) before the parser sees it, and the parsed
data (depth, size, 64-bit integers) before anyone walks it.

Writing: :func:`dumps` (a document) and :func:`value_text` (one value, e.g. for an error message).
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

from ftstab_mj.config import keypath
from ftstab_mj.config.errors import ScenarioError


def parse_text(text: str, source: str, error: type[ScenarioError] = ScenarioError, where: str = "(TOML syntax)"):
    """The table of TOML ``text`` once bounded (see the module docstring); errors name ``source``.

    ``where``: the key path of a problem of the text as a whole (the file's, or a --set key's)."""
    from ftstab_mj.config.validate import structure_problem, text_problem

    problem = text_problem(text)
    if problem:
        raise error(source, where, problem, "more" if "characters" in problem else "deeper nesting")
    try:
        data = tomllib.loads(text)
    except ValueError as exc:  # TOMLDecodeError, or an integer literal of more than 4300 digits
        raise error(source, where, "valid TOML", str(exc).split("; use sys.")[0]) from None
    problem = structure_problem(data)
    if problem:
        path, expected, found = problem
        raise error(source, where if where != "(TOML syntax)" else path, expected, found)
    return data


def read_toml(path, kind: str, error: type[ScenarioError] = ScenarioError) -> dict:
    """The table of the TOML file ``path``; ``kind`` names it in errors (e.g. "scenario file (.toml)")."""
    from ftstab_mj.config.validate import MAX_FILE_BYTES, not_regular

    src, p = str(path), Path(path)
    found = not_regular(p)  # a FIFO would block the read for ever, /dev/zero never end
    if found:
        raise error(src, "(file)", f"an existing {kind}", found)
    try:
        if p.stat().st_size > MAX_FILE_BYTES:
            raise error(src, "(file)", f"a {kind} of at most {MAX_FILE_BYTES} bytes", f"{p.stat().st_size} bytes")
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise error(src, "(file)", f"a readable {kind}", exc.strerror or str(exc)) from None
    except UnicodeDecodeError as exc:
        raise error(src, "(file)", "UTF-8 text", f"undecodable bytes ({exc.reason})") from None
    return parse_text(text, src, error)


def value_text(v) -> str:
    """``v`` (bool, int, float, str, list/tuple, dict) as a TOML value; tables inline."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return keypath.quote(v)
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else ("nan" if v != v else ("inf" if v > 0 else "-inf"))
    if isinstance(v, int):
        return str(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(value_text(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{_key(k)} = {value_text(x)}" for k, x in v.items()) + " }" if v else "{}"
    raise TypeError(f"no TOML form for {v!r}")  # callers pass TOML/JSON data only


def _key(k: str) -> str:
    return k if keypath.bare(k) else keypath.quote(k)


def dumps(tree: dict, header: str = "", inline=lambda table: False) -> str:
    """TOML text of ``tree``: scalars and arrays as ``key = value``, sub-tables as [a.b] sections
    (or inline when ``inline(table)`` says so); ``header`` lines become comments at the top."""
    lines = [f"# {line}" if line else "#" for line in header.splitlines()]

    def emit(table: dict, name: str):
        leaves = {k: v for k, v in table.items() if not (isinstance(v, dict) and not inline(v))}
        groups = {k: v for k, v in table.items() if k not in leaves}
        if name and (leaves or not groups):
            lines.append(f"\n[{name}]")
        lines.extend(f"{_key(k)} = {value_text(v)}" for k, v in leaves.items())
        for k, v in groups.items():
            emit(v, f"{name}.{_key(k)}" if name else _key(k))

    emit(tree, "")
    return "\n".join(lines) + "\n"

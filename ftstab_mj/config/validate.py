"""The one configuration reader: raw TOML data -> typed values, every error one line with its key path.

Scenario files (ftstab_mj.scenario.loader), sweep files (ftstab_mj.studies.sweep.spec) and expectation files
(ftstab_mj.metrics.expectations) are read through :class:`Reader`; its error names the file (and the ``--set``
or sweep row that wrote the value), the key path, what is allowed and what was found::

    scenarios/x.toml (--set sim.period=1e9): sim.period: expected ..., found 1000000000.0 (a float)

Plain dataclasses carry the schema (a field's ``metadata["check"]`` is a value -> None | "what is
allowed" function, the ones below). No validation library: msgspec (14 ms to import) and pydantic
(41 ms) would each need their errors rewritten into this format, and the readers are ~150 lines.

Limits. Every value a run uses is bounded so that the run can honour it: finite and representable,
and within a work limit stated with its reason (:data:`LIMITS`). Nested data is bounded in depth and
size before anything walks it (:func:`check_text`, :func:`check_structure`).
"""

from __future__ import annotations

import math
import types
import typing
from dataclasses import MISSING, fields, is_dataclass

from ftstab_mj.config import keypath
from ftstab_mj.config.errors import ScenarioError, counted, describe

# -- limits, with the reason each one is stated for ---------------------------------------------------
INT64 = (-(2 ** 63), 2 ** 63 - 1)
from ftstab_mj.config.limits import (MAX_FILE_BYTES, MAX_SAMPLES, MAX_STEPS,  # noqa: E402 - the one table
                                     MAX_STATE, MAX_STEPS_PER_PERIOD, MAX_SWEEP_ROWS)  # noqa: F401 - re-exported
MAX_DEPTH = 16  # arrays/tables nested deeper than any file of ours (the deepest, a sweep group, is 5)
MAX_ITEMS = 100_000  # values in one file or --set
MAX_NAME = 200  # characters of a name that becomes a file name: <name>.sweep.json must fit in 255 bytes
LIMITS = {
    "samples": (MAX_SAMPLES, "a run logs up to ~350 B of each sample and loop (MCAP + Rerun) and its final-window "
                             "metrics need ~6 B of each at the end: 1e7 samples is ~3.5 GB of logs and ~60 MB of memory"),
    "steps": (MAX_STEPS, "at ~3 us a physics step, MuJoCo's own cost, 1e9 steps is about an hour of computing"),
    "steps_per_period": (MAX_STEPS_PER_PERIOD, "the run loop holds the inputs of every physics step of a batch "
                                               "of periods, 32 B a step and loop"),
}


def limit_text(what: str, unit: str) -> str:
    value, reason = LIMITS[what]
    return f"at most {value:.0e} {unit} ({reason})".replace("e+0", "e")


# -- field checks: value -> None if allowed, else the text of what is allowed -------------------------
def positive(v):
    return None if v > 0 else "a number > 0"


def non_negative(v):
    return None if v >= 0 else "a number >= 0"


def one_of(*allowed):
    def check(v):
        return None if v in allowed else "one of " + ", ".join(repr(a) for a in allowed)
    return check


def open_unit_interval(v):
    return None if 0 < v < 1 else "a number in the open interval (0, 1)"


def fraction(v):
    return None if 0 < v <= 1 else "a number in (0, 1]"


def box_count(v):
    """A work limit of the branch and bound (boxes), as control.certificate.certify takes it."""
    return None if 1 <= v <= 10 ** 10 else "an integer number of boxes in [1, 10^10]"


def time_step(v):
    # 1e-7 s is 10 million steps per simulated second; below it a run is an error, not a study.
    return None if v >= 1e-7 else "a time step >= 1e-7 s"


def state_limit(v):
    # MuJoCo resets a state beyond 1e10 on its own (a warning, zeros): our limit must fire first.
    return None if 0 < v <= MAX_STATE else "a number in (0, 1e9] (MuJoCo resets states beyond 1e10)"


def identifier(v):
    """A name that becomes a file name (<name>.mcap, <name>.parquet): ASCII, short, no separator."""
    ok = v != "" and all(c.isascii() and (c.isalnum() or c in "_-") for c in v)
    if not ok:
        return "a non-empty name of ASCII letters, digits, '_' and '-' (it names the log files)"
    if len(v) > MAX_NAME:
        return (f"a name of at most {MAX_NAME} characters (it names files such as <name>.sweep.json, "
                f"and a file name has at most 255 bytes)")
    return None


def one_line(v):
    return None if v.strip() and "\n" not in v and len(v) <= 1000 else "one non-empty line (at most 1000 characters)"


def whole_steps(period: float, step: float) -> int | None:
    """N when period = N * step (N >= 1, to 1e-9 relative: MuJoCo holds u over whole steps), else None.

    The one test of the control period (the loader and ftstab_mj.simulation.run_loop both use it)."""
    ratio = period / step
    if not math.isfinite(ratio) or ratio > 2 ** 53:
        return None
    n = round(ratio)
    return n if n >= 1 and abs(n * step - period) <= 1e-9 * period else None


def number_problem(v, *, integer=False) -> str | None:
    """None when ``v`` is a finite number (an integer of 64 bits if ``integer``), else what is expected."""
    import numbers

    if isinstance(v, bool) or not isinstance(v, numbers.Real):
        return "an integer" if integer else "a number"
    if integer:
        if not isinstance(v, numbers.Integral):
            return "an integer"
        return None if INT64[0] <= v <= INT64[1] else "an integer of 64 bits (|n| < 9.2e18)"
    if isinstance(v, numbers.Integral) and not INT64[0] <= v <= INT64[1]:
        return "a number (an integer must fit in 64 bits, |n| < 9.2e18; write a float such as 1e20)"
    return None if math.isfinite(v) else "a finite number"


# -- bounded input ------------------------------------------------------------------------------------
def text_problem(text: str) -> str | None:
    """None when TOML ``text`` is small and shallow enough to be parsed, else what is allowed.

    Counts the nesting of arrays and inline tables outside strings and comments, without parsing:
    the TOML parser recurses into nested values and would exhaust Python's stack first.
    """
    if len(text) > MAX_FILE_BYTES:
        return f"at most {MAX_FILE_BYTES} characters"
    depth = deepest = 0
    i, n = 0, len(text)
    line_start = True
    while i < n:
        c = text[i]
        if c in "\"'":
            q3 = text.startswith(c * 3, i)
            end = text.find(c * 3 if q3 else c, i + (3 if q3 else 1))
            while c == '"' and end > 0 and _escaped(text, end):
                end = text.find(c * 3 if q3 else c, end + 1)
            if end < 0:
                return None  # unterminated string: the parser reports it
            i = end + (3 if q3 else 1)
            line_start = False
            continue
        if c == "#":
            j = text.find("\n", i)
            i = n if j < 0 else j
            continue
        if c == "\n":
            line_start = True
        elif c in "[{" and not (line_start and depth == 0):  # a [table] header is not nesting
            depth += 1
            deepest = max(deepest, depth)
            if deepest > MAX_DEPTH:
                return f"arrays and tables nested at most {MAX_DEPTH} deep"
        elif c in "]}" and depth > 0:
            depth -= 1
        elif not c.isspace():
            line_start = False
        i += 1
    return None


def _escaped(text: str, i: int) -> bool:
    k = i - 1
    while k >= 0 and text[k] == "\\":
        k -= 1
    return (i - 1 - k) % 2 == 1


def structure_problem(data) -> tuple[str, str, str] | None:
    """(key path, expected, found) of the first problem of parsed data, else None: depth, size, integers.

    Iterative, so it is safe on any data (it runs before every recursive walk of a file's values, and on
    every sweep row). A value's place is kept as (parent's place, key), and written as a key path only for
    the value that has the problem: writing every value's path cost ~60 % of the walk.
    """
    stack, count = [(None, data, 0)], 0
    while stack:
        where, v, depth = stack.pop()
        count += 1
        if count > MAX_ITEMS:
            return _path_of(where) or "(top level)", f"at most {MAX_ITEMS} values in one file", "more"
        if depth > MAX_DEPTH:
            return _path_of(where), f"arrays and tables nested at most {MAX_DEPTH} deep", "deeper nesting"
        if isinstance(v, dict):
            stack.extend(((where, str(k)), x, depth + 1) for k, x in v.items())
        elif isinstance(v, (list, tuple)):
            stack.extend(((where, i), x, depth + 1) for i, x in enumerate(v))
        elif isinstance(v, int) and not isinstance(v, bool) and not INT64[0] <= v <= INT64[1]:
            return (_path_of(where), "an integer of 64 bits (TOML integers are 64-bit; write a float such as 1e20)",
                    describe(v))
    return None


def _path_of(where) -> str:
    """The key path of a place of structure_problem: None (the top) or (parent's place, key)."""
    parts = []
    while where is not None:
        where, key = where
        parts.append(key)
    return keypath.text(reversed(parts))


# -- the reader ---------------------------------------------------------------------------------------
class TableMemo:
    """What a :class:`Reader` read from the tables of ``base`` (raw TOML data, never changed while the
    memo lives): a sweep row's data are the base's own tables but along its overridden paths
    (ftstab_mj.scenario.loader.scenario_with), so its reader reads only those paths again. The memo
    holds ``base``: the ids of its tables (``tables``) name them for as long as it lives."""

    def __init__(self, base):
        self.base, self.tables, self.read = base, set(), {}
        stack = [base]  # iterative: the depth of input is bounded by the readers, not by Python's stack
        while stack:
            v = stack.pop()
            if isinstance(v, dict):
                self.tables.add(id(v))
                stack.extend(v.values())
            elif isinstance(v, list):
                stack.extend(v)


class Reader:
    """Typed values from raw TOML data; every problem raises ``error_cls`` with the key path.

    notes: {key path: "--set x=1" or "row 3: x = 1"}: an error at (or inside, or around) such a path
    names it after the file, since the value came from there and not from the file.
    """

    def __init__(self, source: str, notes: dict[str, str] | None = None, error_cls=ScenarioError,
                 memo: TableMemo | None = None):
        self.source, self.notes, self.error_cls = source, dict(notes or {}), error_cls
        self.memo = memo

    def memoized(self, tp, value, path, build):
        """``build(tp, value, path)``, or what it gave before when ``value`` is a table of the memo's
        base (:class:`TableMemo`) read before at this path as ``tp``: a table read without error once
        reads the same again (the typed values are frozen and the checks depend on the table only)."""
        memo = self.memo
        if memo is None or id(value) not in memo.tables:
            return build(tp, value, path)
        key = (id(value), tp, path)
        out = memo.read.get(key, memo)
        if out is memo:
            out = memo.read[key] = build(tp, value, path)
        return out

    def error(self, path: str, expected: str, found: str) -> ScenarioError:
        src = self.source
        for npath, note in self.notes.items():
            if keypath.within(path, npath) or keypath.within(npath, path):
                src = f"{self.source} ({note})"
        return self.error_cls(src, path or "(top level)", expected, found)

    def bounded(self, data, path: str = ""):
        """``data`` unchanged once its depth, size and integers are within the limits."""
        problem = structure_problem(data)
        if problem:
            p, expected, found = problem
            raise self.error(keypath.join(path, p) if path and p else (p or path), expected, found)
        return data

    # -- scalars ------------------------------------------------------------------------------------
    def number(self, value, path, check=None) -> float:
        problem = number_problem(value)
        if problem:
            raise self.error(path, problem, describe(value))
        return self._checked(float(value), value, path, check)

    def integer(self, value, path, low: int | None = None, high: int | None = None) -> int:
        problem = number_problem(value, integer=True)
        if problem is None and low is not None and value < low:
            problem = f"an integer >= {low}"
        if problem is None and high is not None and value > high:
            problem = f"an integer <= {high}"
        if problem:
            raise self.error(path, problem, describe(value))
        return int(value)

    def string(self, value, path, check=None) -> str:
        if not isinstance(value, str):
            raise self.error(path, "a string", describe(value))
        return self._checked(value, value, path, check)

    def boolean(self, value, path) -> bool:
        if not isinstance(value, bool):
            raise self.error(path, "true or false", describe(value))
        return value

    def numbers(self, value, path, n: int) -> tuple:
        if not isinstance(value, list) or len(value) != n:
            raise self.error(path, f"an array of {counted(n, 'number')}", describe(value))
        return tuple(self.number(v, keypath.join(path, i)) for i, v in enumerate(value))

    def _checked(self, v, raw, path, check):
        allowed = check(v) if check is not None else None
        if allowed:
            raise self.error(path, allowed, describe(raw))
        return v

    # -- tables -------------------------------------------------------------------------------------
    def table(self, value, path, keys, required=()) -> dict:
        """``value`` once it is a table with keys among ``keys`` and every key of ``required``."""
        if not isinstance(value, dict):
            raise self.error(path, "a table", describe(value))
        for k in value:
            if k not in keys:
                raise self.error(keypath.join(path, k), "one of the keys " + ", ".join(keys), f"unknown key {k!r}")
        for k in required:
            if k not in value:
                raise self.error(keypath.join(path, k), "a value", "nothing: the key is required")
        return value

    def convert(self, tp, value, path):
        """Convert raw TOML ``value`` to the annotated type ``tp`` (float, int, str, bool, dict,
        ``X | None``, ``tuple[X, ...]``, a dataclass; a subclass may handle more in :meth:`special`)."""
        if type(value) is dict and tp is not dict and self.memo is not None:  # a base's table: read once
            return self.memoized(tp, value, path, self._convert)
        return self._convert(tp, value, path)

    def _convert(self, tp, value, path):
        if tp is float:
            return self.number(value, path)
        if tp is int:
            return self.integer(value, path)
        if tp is str:
            return self.string(value, path)
        if tp is bool:
            return self.boolean(value, path)
        if tp is dict:
            if not isinstance(value, dict):
                raise self.error(path, "a table", describe(value))
            return dict(value)
        origin, args = typing.get_origin(tp), typing.get_args(tp)
        if origin in (typing.Union, types.UnionType):  # X | None, float | str | None
            inner = [a for a in args if a is not type(None)]
            if isinstance(value, str) and str in inner:
                return value
            arrays = [a for a in inner if typing.get_origin(a) is tuple]
            if isinstance(value, list) and arrays:  # "a number or an array": the array form
                return self.convert(arrays[0], value, path)
            return self.convert(inner[0], value, path)
        if origin is tuple and len(args) == 2 and args[1] is Ellipsis:
            if not isinstance(value, list) or not value:
                raise self.error(path, "a non-empty array of numbers", describe(value))
            return tuple(self.convert(args[0], v, keypath.join(path, i)) for i, v in enumerate(value))
        special = self.special(tp, value, path)
        if special is not NotImplemented:
            return special
        if is_dataclass(tp):
            return tp(**self.fields_of(tp, value, path))
        raise TypeError(f"schema type {tp!r} at {path} has no converter")  # a bug in the schema, not input

    def special(self, tp, value, path):
        """Hook for types the schema reads its own way; NotImplemented for the others."""
        return NotImplemented

    def fields_of(self, cls, value, path, skip=(), checks=None):
        """{field name: converted value} for the keys present in the table ``value``; checks keys.

        A field's check is ``metadata["check"]`` or ``checks[name]`` (for classes defined elsewhere).
        """
        hints, all_fields = _hints_and_fields(cls)
        flds = [f for f in all_fields if f.init and not f.name.startswith("_") and f.name not in skip]
        names = [f.name for f in flds]
        self.table(value, path, names)
        out = {}
        for f in flds:
            # keypath.join without its regex: an ASCII identifier is a bare TOML key
            p = (f"{path}.{f.name}" if path else f.name) if f.name.isascii() else keypath.join(path, f.name)
            if f.name not in value:
                if f.default is MISSING and f.default_factory is MISSING:
                    doc = f.metadata.get("doc", f.name)
                    raise self.error(p, f"a value ({doc})", "nothing: the key is required")
                continue
            v = self.convert(hints[f.name], value[f.name], p)
            check = f.metadata.get("check") or (checks or {}).get(f.name)
            allowed = check(v) if check is not None and v is not None else None
            if allowed:
                raise self.error(p, allowed, describe(value[f.name]))
            out[f.name] = v
        return out


_HINTS: dict[type, tuple[dict, tuple]] = {}  # class -> (hints, fields)


def _hints_and_fields(cls) -> tuple[dict, tuple]:
    """The resolved type hints and the fields of dataclass ``cls``, kept per class: resolving the hints
    (typing.get_type_hints) was the largest cost of validating a sweep row (~1 ms a row)."""
    hit = _HINTS.get(cls)
    if hit is None:
        hit = _HINTS[cls] = (typing.get_type_hints(cls), fields(cls))
    return hit


# -- input files: regular files only, bounded --------------------------------------------------------------
def not_regular(path) -> str | None:
    """None when ``path`` is a regular file (symlinks followed), else what it is, as an error's "found": "no such
    file", "a directory", "a FIFO (named pipe)", "a character device", "a block device", "a socket", "a symlink
    loop" or the OS's reason. Models, scenarios and includes are read from regular files only: opening a FIFO
    waits for a writer for ever, and a device (/dev/zero) never ends."""
    import errno
    import os
    import stat

    try:
        mode = os.stat(path).st_mode
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return "a symlink loop"
        if exc.errno in (errno.ENOENT, errno.ENOTDIR):
            return "no such file"
        return exc.strerror or str(exc)
    if stat.S_ISREG(mode):
        return None
    return ("a directory" if stat.S_ISDIR(mode) else "a FIFO (named pipe)" if stat.S_ISFIFO(mode)
            else "a character device" if stat.S_ISCHR(mode) else "a block device" if stat.S_ISBLK(mode)
            else "a socket" if stat.S_ISSOCK(mode) else "not a regular file")

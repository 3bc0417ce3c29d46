"""Pinned metrics with tolerances (``ftstab check LOG.mcap --expect EXPECT.toml``).

An expectation file mirrors the metrics dict (``ftstab replay LOG.mcap --json``): tables and
keys are metric names, and each leaf is either an exact value (string, boolean, integer, float,
or a list of them) or a table with these keys::

    value = X, atol = A, rtol = R     |got - X| <= A + R |X|   (element-wise for lists; A, R default 0)
    min = A  /  max = B               A <= got  /  got <= B  (may be combined with value)
    null = true                       the metric is undefined (JSON null: e.g. never settled)

Example::

    status = "completed"
    [loops.cart]
    settle_time = { value = 1.234, atol = 0.002 }   # s, two control periods
    final_abs_z_max = { max = [1e-3, 2e-2] }
    theorem3 = { Delta_held = true }
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass

from ftstab_mj.errors import ScenarioError

SPEC_KEYS = ("value", "atol", "rtol", "min", "max", "null")


class ExpectationError(ScenarioError):
    """An expectation file is malformed or names a metric the log does not have (exit 2, one line)."""


@dataclass(frozen=True)
class Outcome:
    """One expectation checked: its key path, whether it holds, and a readable line."""

    path: str
    ok: bool
    line: str


def load_expectations(path) -> dict:
    """Parse an expectation file (TOML). Raises ExpectationError naming the file on bad syntax."""
    path = str(path)
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except OSError as exc:
        raise ExpectationError(path, "<file>", "a readable TOML file", exc.strerror) from None
    except tomllib.TOMLDecodeError as exc:
        raise ExpectationError(path, "<file>", "valid TOML", str(exc)) from None


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _fmt(x) -> str:
    if x is None:
        return "null"
    if isinstance(x, list):
        return "[" + ", ".join(_fmt(v) for v in x) + "]"
    if isinstance(x, float):
        return f"{x:.10g}"
    return repr(x) if isinstance(x, str) else str(x).lower() if isinstance(x, bool) else str(x)


def _numbers(source, path, what, x):
    """x as a list of floats (a scalar becomes a one-element list); validates the expectation."""
    items = x if isinstance(x, list) else [x]
    if not items or not all(_is_number(v) for v in items):
        raise ExpectationError(source, f"{path}.{what}", "a number or a list of numbers", _fmt(x))
    return [float(v) for v in items]


def _check_spec(source: str, path: str, spec: dict, got) -> Outcome:
    unknown = sorted(set(spec) - set(SPEC_KEYS))
    if unknown:
        raise ExpectationError(source, f"{path}.{unknown[0]}", "one of " + ", ".join(SPEC_KEYS), "an unknown key")
    if "null" in spec:
        if spec["null"] is not True or len(spec) > 1:
            raise ExpectationError(source, f"{path}.null", "null = true alone", _fmt(spec))
        return Outcome(path, got is None, f"{path}: expected null, got {_fmt(got)}")
    if not any(k in spec for k in ("value", "min", "max")):
        raise ExpectationError(source, path, "a table with value, min or max", _fmt(spec))
    atol = _numbers(source, path, "atol", spec.get("atol", 0.0))[0]
    rtol = _numbers(source, path, "rtol", spec.get("rtol", 0.0))[0]
    if atol < 0 or rtol < 0:
        raise ExpectationError(source, path, "atol, rtol >= 0", f"atol {atol}, rtol {rtol}")
    g = got if isinstance(got, list) else [got]
    if any(v is not None and not _is_number(v) for v in g):
        raise ExpectationError(source, path, "a numeric metric for value/min/max", f"the metric is {_fmt(got)}")
    problems, wanted = [], []
    for key in ("value", "min", "max"):
        if key not in spec:
            continue
        ref = _numbers(source, path, key, spec[key])
        if len(ref) == 1 and len(g) > 1:
            ref = ref * len(g)
        if len(ref) != len(g):
            problems.append(f"{len(g)} values where {key} has {len(ref)}")
            continue
        if key == "value":
            tol = "".join(f" {n} {v:g}" for n, v in (("atol", atol), ("rtol", rtol)) if v)
            wanted.append(f"{_fmt(spec[key])}" + (f" ({tol.strip()})" if tol else ""))
        else:
            wanted.append(f"{key} {_fmt(spec[key])}")
        for i, (x, r) in enumerate(zip(g, ref)):
            where = f"[{i}]" if len(g) > 1 else ""
            if x is None or not math.isfinite(x):
                problems.append(f"{where} is {_fmt(x)}".strip())
            elif key == "value" and abs(x - r) > atol + rtol * abs(r):
                problems.append(f"{where} off by {x - r:+.3g} (allowed {atol + rtol * abs(r):.3g})".strip())
            elif key == "min" and x < r:
                problems.append(f"{where} below min by {r - x:.3g}".strip())
            elif key == "max" and x > r:
                problems.append(f"{where} above max by {x - r:.3g}".strip())
    line = f"{path}: expected {', '.join(wanted)}, got {_fmt(got)}" + (f": {'; '.join(problems)}" if problems else "")
    return Outcome(path, not problems, line)


def check_metrics(metrics: dict, expected: dict, source: str = "<expectations>") -> list[Outcome]:
    """Compare ``metrics`` (compute_metrics' dict) with an expectation tree; one Outcome per leaf.

    Raises ExpectationError (naming ``source`` and the key path) for a malformed expectation or a
    metric the log does not have.
    """
    out: list[Outcome] = []

    def walk(exp, got, path):
        for key, want in exp.items():
            p = f"{path}.{key}" if path else key
            if not isinstance(got, dict) or key not in got:
                have = ", ".join(sorted(got)) if isinstance(got, dict) else "a value, not a table"
                raise ExpectationError(source, p, f"a metric of the log ({have})", "no such metric")
            value = got[key]
            if isinstance(want, dict) and isinstance(value, dict):
                walk(want, value, p)
            elif isinstance(want, dict):
                out.append(_check_spec(source, p, want, value))
            else:
                same = (type(want) is type(value) or (_is_number(want) and _is_number(value))) and want == value
                out.append(Outcome(p, same, f"{p}: expected {_fmt(want)}, got {_fmt(value)}"))

    walk(expected, metrics, "")
    return out

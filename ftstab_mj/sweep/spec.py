"""Sweep files: the schema (frozen dataclasses) and the strict TOML loader.

A sweep file names a base scenario and the scenario parameters to vary, by the key paths of
``ftstab run --set`` (``sim.period``, ``loops.cart.controller.gains[1]``)::

    name = "robust_period"              # names the output files DIR/<name>.parquet, ...
    description = "one line"
    scenario = "../cart_robust.toml"    # the base scenario, relative to this file
    seed = 0                            # seed of the Monte Carlo draws (default 0)
    combine = "product"                 # how the [grid] axes combine: "product" (default) or "zip"
    samples = 1                         # Monte Carlo draws per grid point (default 1)

    [set]                               # overrides of every run (before the grid and the draws)
    "sim.duration" = 4.0

    [grid]                              # one axis per key path
    "sim.period" = [1e-4, 1e-3, 1e-2]                                # a list of values
    "loops.cart.controller.phibar" = {range = [0.5, 2.0, 0.5]}       # start, stop (inclusive), step
    "loops.cart.controller.k" = {linspace = [-0.3, -0.1], num = 3}
    "loops.cart.disturbance.amplitude" = {logspace = [0.1, 10], num = 5}   # geometric, end values

    [grid.r]                            # a group: its key paths move together, as one axis
    "plant.model" = ["cart", "cart_force_rate"]
    "loops.cart.z0" = [[0.1, 0.0], [0.1, 0.0, 0.0]]

    [draw]                              # Monte Carlo: key path = seeded distribution
    "loops.cart.z0[0]" = {uniform = [-1, 1]}        # also loguniform, normal = [mean, std],
    "seed" = {integers = [0, 1000000]}              # integers (inclusive), choice = [...]

    [[report.plot]]                     # PNG figures of `ftstab sweep --report` (see report.py)
    x = "sim.period"
    y = "metrics.loops.cart.final_abs_z_max[0]"
    by = "plant.model"
    logx = true
    logy = true
    fit = true

Every problem raises :class:`SweepError`, one line: file, key path, what was expected, what was found.
The expansion into runs is in :mod:`ftstab_mj.sweep.expand`.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

from ftstab_mj.errors import ScenarioError, SweepError
from ftstab_mj.scenario.loader import describe, parse_override
from ftstab_mj.scenario.schema import identifier, one_line
from ftstab_mj.tomlfile import read_toml

COMBINE = ("product", "zip")
GRID_KINDS = ("range", "linspace", "logspace")  # besides a plain list of values
DISTRIBUTIONS = ("uniform", "loguniform", "normal", "integers", "choice")


@dataclass(frozen=True)
class GridParam:
    """One varied key path and its values (a list, or a range/linspace/logspace as written).

    kind: "values" | "range" | "linspace" | "logspace"; args: the values (values), (start, stop,
    step) (range) or (start, stop) (linspace, logspace); num: number of points (linspace, logspace).
    """

    path: str
    kind: str
    args: tuple
    num: int = 0


@dataclass(frozen=True)
class Axis:
    """One axis of the grid: key paths whose values move together (all of the same length)."""

    name: str  # the key path, or the group's name for [grid.<group>]
    params: tuple[GridParam, ...]
    group: bool = False

    def label(self, path: str) -> str:
        """Where ``path`` is varied in the sweep file: grid."sim.period", or grid.<group>."plant.model"."""
        return key_label(key_label("grid", self.name), path) if self.group else key_label("grid", path)


@dataclass(frozen=True)
class Draw:
    """A Monte Carlo parameter: key path, distribution (one of DISTRIBUTIONS) and its arguments."""

    path: str
    dist: str
    args: tuple


@dataclass(frozen=True)
class PlotSpec:
    """One PNG of the report: column y against column x, one series per value of column ``by``.

    fit: fit a line to log10(y) against log10(x) per series and print its slope (needs logx, logy).
    """

    x: str
    y: str
    by: str | None = None
    logx: bool = False
    logy: bool = False
    fit: bool = False
    title: str = ""
    xlabel: str = ""
    ylabel: str = ""


@dataclass(frozen=True)
class Sweep:
    """A validated sweep file. ``scenario`` is the base scenario's path resolved against the file."""

    name: str
    description: str
    scenario: Path
    source: str  # the sweep file as the user named it (prefix of every error)
    seed: int = 0
    combine: str = "product"
    samples: int = 1
    set: tuple[tuple[str, object], ...] = ()  # (key path, value) applied to every run
    axes: tuple[Axis, ...] = ()
    draws: tuple[Draw, ...] = ()
    plots: tuple[PlotSpec, ...] = ()


def key_label(path: str, key) -> str:
    """Key path inside the sweep file; keys that hold dots are quoted as in TOML."""
    if isinstance(key, int):
        return f"{path}[{key}]"
    k = f'"{key}"' if not key.replace("_", "").replace("-", "").isalnum() else key
    return f"{path}.{k}" if path else k


class _Reader:
    def __init__(self, source: str):
        self.source = source

    def error(self, path: str, expected: str, found: str) -> SweepError:
        return SweepError(self.source, path or "(top level)", expected, found)

    def table(self, value, path, keys: tuple[str, ...], required: tuple[str, ...] = ()) -> dict:
        if not isinstance(value, dict):
            raise self.error(path, "a table", describe(value))
        for k in value:
            if k not in keys:
                raise self.error(key_label(path, k), "one of the keys " + ", ".join(keys), f"unknown key {k!r}")
        for k in required:
            if k not in value:
                raise self.error(key_label(path, k), "a value", "nothing: the key is required")
        return value

    def number(self, value, path) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.error(path, "a finite number", describe(value))
        return value

    def integer(self, value, path, low: int) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise self.error(path, f"an integer >= {low}", describe(value))
        return value

    def string(self, value, path, check=None) -> str:
        if not isinstance(value, str):
            raise self.error(path, "a string", describe(value))
        allowed = check(value) if check else None
        if allowed:
            raise self.error(path, allowed, describe(value))
        return value

    def boolean(self, value, path) -> bool:
        if not isinstance(value, bool):
            raise self.error(path, "true or false", describe(value))
        return value

    def numbers(self, value, path, n: int) -> tuple:
        if not isinstance(value, list) or len(value) != n:
            raise self.error(path, f"an array of {n} numbers", describe(value))
        return tuple(self.number(v, key_label(path, i)) for i, v in enumerate(value))

    def key_path(self, key: str, path: str) -> str:
        try:
            parse_override(f"{key}=0", self.source)
        except ScenarioError:
            raise self.error(path, "a scenario key path like sim.period or loops.cart.z0[0]", repr(key)) from None
        return key

    # -- [grid] ---------------------------------------------------------------------------------
    def grid_param(self, key: str, value, path: str) -> GridParam:
        self.key_path(key, path)
        if isinstance(value, list):
            if not value:
                raise self.error(path, "a non-empty array of values", describe(value))
            return GridParam(key, "values", tuple(value))
        if not isinstance(value, dict):
            raise self.error(path, "an array of values or a table {range|linspace|logspace = ...}", describe(value))
        kinds = [k for k in value if k in GRID_KINDS]
        if len(kinds) != 1:
            raise self.error(path, "exactly one of range = [start, stop, step], linspace = [start, stop], "
                             "logspace = [start, stop]", describe(value))
        kind = kinds[0]
        if kind == "range":
            self.table(value, path, ("range",))
            start, stop, step = self.numbers(value["range"], key_label(path, "range"), 3)
            if step == 0 or (stop - start) / step < 0:
                raise self.error(key_label(path, "range"), "a step that goes from start towards stop",
                                 f"start {start:g}, stop {stop:g}, step {step:g}")
            return GridParam(key, kind, (start, stop, step))
        self.table(value, path, (kind, "num"), required=(kind, "num"))
        start, stop = self.numbers(value[kind], key_label(path, kind), 2)
        num = self.integer(value["num"], key_label(path, "num"), 1)
        if kind == "logspace" and not (start > 0 and stop > 0):
            raise self.error(key_label(path, kind), "two end values > 0 (geometric spacing)", describe(value[kind]))
        return GridParam(key, kind, (start, stop), num)

    def grid(self, value, path) -> tuple[Axis, ...]:
        if not isinstance(value, dict):
            raise self.error(path, "a table of key path = values", describe(value))
        axes = []
        for key, body in value.items():
            p = key_label(path, key)
            if isinstance(body, dict) and body and not set(body) & set(GRID_KINDS + ("num",)):  # a group
                if not key.replace("_", "").replace("-", "").isalnum():
                    raise self.error(p, "a group name of letters, digits, '_' and '-'", repr(key))
                params = tuple(self.grid_param(k, v, key_label(p, k)) for k, v in body.items())
                axes.append(Axis(key, params, group=True))
            else:
                axes.append(Axis(key, (self.grid_param(key, body, p),)))
        return tuple(axes)

    # -- [draw] ---------------------------------------------------------------------------------
    def draw(self, key: str, value, path: str) -> Draw:
        self.key_path(key, path)
        if not isinstance(value, dict) or len(value) != 1 or next(iter(value)) not in DISTRIBUTIONS:
            raise self.error(path, "a table with one of " + ", ".join(f"{d} = [...]" for d in DISTRIBUTIONS),
                             describe(value))
        (dist, args), = value.items()
        p = key_label(path, dist)
        if dist == "choice":
            if not isinstance(args, list) or not args:
                raise self.error(p, "a non-empty array of values", describe(args))
            return Draw(key, dist, tuple(args))
        if dist == "integers":
            if not isinstance(args, list) or len(args) != 2:
                raise self.error(p, "an array of 2 integers [low, high] (both included)", describe(args))
            lo, hi = (self.integer(v, key_label(p, i), -(2 ** 63)) for i, v in enumerate(args))
            if hi < lo:
                raise self.error(p, "low <= high", describe(args))
            return Draw(key, dist, (lo, hi))
        a, b = self.numbers(args, p, 2)
        if dist == "normal" and b < 0:
            raise self.error(key_label(p, 1), "a standard deviation >= 0", describe(b))
        if dist in ("uniform", "loguniform") and b < a:
            raise self.error(p, "low <= high", describe(args))
        if dist == "loguniform" and a <= 0:
            raise self.error(key_label(p, 0), "a number > 0 (log-uniform)", describe(a))
        return Draw(key, dist, (a, b))

    # -- [report] -------------------------------------------------------------------------------
    def plots(self, value, path) -> tuple[PlotSpec, ...]:
        self.table(value, path, ("plot",))
        plots = value.get("plot", [])
        if not isinstance(plots, list):
            raise self.error(key_label(path, "plot"), "an array of tables [[report.plot]]", describe(plots))
        out = []
        names = tuple(PlotSpec.__dataclass_fields__)
        for i, body in enumerate(plots):
            p = key_label(key_label(path, "plot"), i)
            self.table(body, p, names, required=("x", "y"))
            kw = {k: (self.boolean(v, key_label(p, k)) if k in ("logx", "logy", "fit") else self.string(v, key_label(p, k)))
                  for k, v in body.items()}
            spec = PlotSpec(**kw)
            if spec.fit and not (spec.logx and spec.logy):
                raise self.error(key_label(p, "fit"), "logx = true and logy = true (the fit is a log-log slope)",
                                 f"logx = {str(spec.logx).lower()}, logy = {str(spec.logy).lower()}")
            out.append(spec)
        return tuple(out)

    def sweep(self, raw: dict, base_dir: Path) -> Sweep:
        keys = ("name", "description", "scenario", "seed", "combine", "samples", "set", "grid", "draw", "report")
        self.table(raw, "", keys, required=("name", "description", "scenario"))
        name = self.string(raw["name"], "name", identifier)
        description = self.string(raw["description"], "description", one_line)
        scenario = Path(os.path.normpath(base_dir / self.string(raw["scenario"], "scenario")))
        if not scenario.is_file():
            raise self.error("scenario", "an existing scenario file, relative to the sweep file",
                             f"{raw['scenario']!r} (no such file: {scenario})")
        seed = self.integer(raw.get("seed", 0), "seed", 0)
        combine = self.string(raw.get("combine", "product"), "combine",
                              lambda v: None if v in COMBINE else "one of " + ", ".join(map(repr, COMBINE)))
        samples = self.integer(raw.get("samples", 1), "samples", 1)
        fixed = raw.get("set", {})
        if not isinstance(fixed, dict):
            raise self.error("set", "a table of key path = value", describe(fixed))
        fixed = tuple((self.key_path(k, key_label("set", k)), v) for k, v in fixed.items())
        axes = self.grid(raw.get("grid", {}), "grid")
        draws_raw = raw.get("draw", {})
        if not isinstance(draws_raw, dict):
            raise self.error("draw", "a table of key path = {distribution = [...]}", describe(draws_raw))
        draws = tuple(self.draw(k, v, key_label("draw", k)) for k, v in draws_raw.items())
        if samples > 1 and not draws:
            raise self.error("samples", "1 when there is no [draw] table (identical runs otherwise)", str(samples))
        seen: dict[str, str] = {}
        varied = [(a.label(p.path), p.path) for a in axes for p in a.params]
        for where, path in varied + [(key_label("draw", d.path), d.path) for d in draws]:
            if path in seen:
                raise self.error(where, "each key path varied once", f"{path!r}, also varied at {seen[path]}")
            seen[path] = where
        plots = self.plots(raw.get("report", {}), "report")
        return Sweep(name, description, scenario, self.source, seed, combine, samples, fixed, axes, draws, plots)


def load_sweep(path) -> Sweep:
    """Read and validate a sweep file. Raises :class:`SweepError` (one line) on any problem.

    Expansion checks that need the values (zip lengths, key paths absent from the base scenario)
    are made by :func:`ftstab_mj.sweep.expand.expand`.
    """
    raw = read_toml(path, "sweep file (.toml)", SweepError)
    return _Reader(str(path)).sweep(raw, Path(path).parent)

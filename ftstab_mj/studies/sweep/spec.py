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
The expansion into runs is in :mod:`ftstab_mj.studies.sweep.expand`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from ftstab_mj.config import keypath
from ftstab_mj.config.errors import SweepError, describe
from ftstab_mj.config.tomlfile import read_toml
from ftstab_mj.config.validate import MAX_SWEEP_ROWS, Reader, identifier, one_line

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
        return keypath.join(keypath.join("grid", self.name), path) if self.group else keypath.join("grid", path)


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


class _Reader(Reader):
    def __init__(self, source: str):
        super().__init__(source, error_cls=SweepError)

    def key_path(self, key: str, path: str) -> str:
        if keypath.parse(key) is None:
            raise self.error(path, "a scenario key path like sim.period or loops.cart.z0[0]", repr(key))
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
            start, stop, step = self.numbers(value["range"], keypath.join(path, "range"), 3)
            if step == 0 or (stop - start) / step < 0:
                raise self.error(keypath.join(path, "range"), "a step that goes from start towards stop",
                                 f"start {start:g}, stop {stop:g}, step {step:g}")
            if (stop - start) / step + 1 > MAX_SWEEP_ROWS:
                raise self.error(keypath.join(path, "range"), f"at most {MAX_SWEEP_ROWS} values (a sweep's limit "
                                 "on runs)", f"{(stop - start) / step + 1:.3g} values")
            return GridParam(key, kind, (start, stop, step))
        self.table(value, path, (kind, "num"), required=(kind, "num"))
        start, stop = self.numbers(value[kind], keypath.join(path, kind), 2)
        num = self.integer(value["num"], keypath.join(path, "num"), 1, MAX_SWEEP_ROWS)
        if kind == "logspace" and not (start > 0 and stop > 0):
            raise self.error(keypath.join(path, kind), "two end values > 0 (geometric spacing)", describe(value[kind]))
        return GridParam(key, kind, (start, stop), num)

    def grid(self, value, path) -> tuple[Axis, ...]:
        if not isinstance(value, dict):
            raise self.error(path, "a table of key path = values", describe(value))
        axes = []
        for key, body in value.items():
            p = keypath.join(path, key)
            if isinstance(body, dict) and body and not set(body) & set(GRID_KINDS + ("num",)):  # a group
                if not key.replace("_", "").replace("-", "").isalnum():
                    raise self.error(p, "a group name of letters, digits, '_' and '-'", repr(key))
                params = tuple(self.grid_param(k, v, keypath.join(p, k)) for k, v in body.items())
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
        p = keypath.join(path, dist)
        if dist == "choice":
            if not isinstance(args, list) or not args:
                raise self.error(p, "a non-empty array of values", describe(args))
            return Draw(key, dist, tuple(args))
        if dist == "integers":
            if not isinstance(args, list) or len(args) != 2:
                raise self.error(p, "an array of 2 integers [low, high] (both included)", describe(args))
            lo, hi = (self.integer(v, keypath.join(p, i), -(2 ** 63)) for i, v in enumerate(args))
            if hi < lo:
                raise self.error(p, "low <= high", describe(args))
            return Draw(key, dist, (lo, hi))
        a, b = self.numbers(args, p, 2)
        if dist == "normal" and b < 0:
            raise self.error(keypath.join(p, 1), "a standard deviation >= 0", describe(b))
        if dist in ("uniform", "loguniform") and b < a:
            raise self.error(p, "low <= high", describe(args))
        if dist == "loguniform" and a <= 0:
            raise self.error(keypath.join(p, 0), "a number > 0 (log-uniform)", describe(a))
        return Draw(key, dist, (a, b))

    # -- [report] -------------------------------------------------------------------------------
    def plots(self, value, path) -> tuple[PlotSpec, ...]:
        self.table(value, path, ("plot",))
        plots = value.get("plot", [])
        if not isinstance(plots, list):
            raise self.error(keypath.join(path, "plot"), "an array of tables [[report.plot]]", describe(plots))
        out = []
        names = tuple(PlotSpec.__dataclass_fields__)
        for i, body in enumerate(plots):
            p = keypath.join(keypath.join(path, "plot"), i)
            self.table(body, p, names, required=("x", "y"))
            kw = {k: (self.boolean(v, keypath.join(p, k)) if k in ("logx", "logy", "fit") else self.string(v, keypath.join(p, k)))
                  for k, v in body.items()}
            spec = PlotSpec(**kw)
            if spec.fit and not (spec.logx and spec.logy):
                raise self.error(keypath.join(p, "fit"), "logx = true and logy = true (the fit is a log-log slope)",
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
        seed = self.integer(raw.get("seed", 0), "seed", 0)  # SeedSequence takes any integer >= 0
        combine = self.string(raw.get("combine", "product"), "combine",
                              lambda v: None if v in COMBINE else "one of " + ", ".join(map(repr, COMBINE)))
        samples = self.integer(raw.get("samples", 1), "samples", 1, MAX_SWEEP_ROWS)
        fixed = raw.get("set", {})
        if not isinstance(fixed, dict):
            raise self.error("set", "a table of key path = value", describe(fixed))
        fixed = tuple((self.key_path(k, keypath.join("set", k)), v) for k, v in fixed.items())
        axes = self.grid(raw.get("grid", {}), "grid")
        draws_raw = raw.get("draw", {})
        if not isinstance(draws_raw, dict):
            raise self.error("draw", "a table of key path = {distribution = [...]}", describe(draws_raw))
        draws = tuple(self.draw(k, v, keypath.join("draw", k)) for k, v in draws_raw.items())
        if samples > 1 and not draws:
            raise self.error("samples", "1 when there is no [draw] table (identical runs otherwise)", str(samples))
        seen: dict[str, str] = {}
        varied = [(a.label(p.path), p.path) for a in axes for p in a.params]
        for where, path in varied + [(keypath.join("draw", d.path), d.path) for d in draws]:
            if path in seen:
                raise self.error(where, "each key path varied once", f"{path!r}, also varied at {seen[path]}")
            seen[path] = where
        plots = self.plots(raw.get("report", {}), "report")
        return Sweep(name, description, scenario, self.source, seed, combine, samples, fixed, axes, draws, plots)


def load_sweep(path) -> Sweep:
    """Read and validate a sweep file. Raises :class:`SweepError` (one line) on any problem.

    Expansion checks that need the values (zip lengths, key paths absent from the base scenario)
    are made by :func:`ftstab_mj.studies.sweep.expand.expand`.
    """
    raw = read_toml(path, "sweep file (.toml)", SweepError)
    return _Reader(str(path)).sweep(raw, Path(path).parent)

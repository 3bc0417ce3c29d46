"""Expansion of a sweep into runs: grid values, product or zip of the axes, seeded Monte Carlo draws.

Row i is grid point g and draw j, with i = g * samples + j (grid points in the order of
``itertools.product`` over the axes as written, the first axis slowest). Draw j of key path P takes
its randomness from ``SeedSequence([sweep seed, j, crc32(P)])`` and nothing else, so:

- the table is the same whatever the engine and the number of workers;
- adding or removing a drawn parameter does not change the values drawn for the others;
- every grid point sees the same draws (common random numbers: comparisons across the grid are
  paired, which removes the draw-to-draw variance from differences between grid points).
"""

from __future__ import annotations

import itertools
import math
import zlib
from dataclasses import dataclass

import numpy as np

from ftstab_mj.config.errors import SweepError
from ftstab_mj.studies.sweep.spec import Axis, Draw, GridParam, Sweep
from ftstab_mj.config.validate import MAX_SWEEP_ROWS

SIGNIFICANT_DIGITS = 12  # computed grid values are rounded so 0.1 + 0.2 reads 0.3 in the table


@dataclass(frozen=True)
class Row:
    """One run of the sweep: its index, its draw index and the (key path, value) pairs it sets."""

    index: int
    sample: int
    params: tuple[tuple[str, object], ...]


def _round(v: float) -> float:
    return float(f"{v:.{SIGNIFICANT_DIGITS}g}")


def grid_values(p: GridParam) -> tuple:
    """The values of one grid parameter. range: start, start + step, ... up to stop included."""
    if p.kind == "values":
        return p.args
    if p.kind == "range":
        start, stop, step = p.args
        n = math.floor((stop - start) / step + 1e-9) + 1  # stop included despite rounding of (stop - start)
        return tuple(_round(start + i * step) for i in range(n))
    start, stop = p.args
    pts = np.linspace(start, stop, p.num) if p.kind == "linspace" else np.geomspace(start, stop, p.num)
    return tuple(_round(v) for v in pts)


def axis_values(axis: Axis, source: str) -> list[tuple[tuple[str, object], ...]]:
    """The points of one axis: [((path, value), ...) per point]; a group's parameters are zipped."""
    cols = [(p.path, grid_values(p)) for p in axis.params]
    lengths = {len(v) for _, v in cols}
    if len(lengths) > 1:
        found = ", ".join(f"{path}: {len(v)}" for path, v in cols)
        raise SweepError(source, f"grid.{axis.name}", "key paths with the same number of values (a group moves "
                         "them together)", found)
    return [tuple((path, vals[i]) for path, vals in cols) for i in range(lengths.pop())]


def grid_points(sweep: Sweep) -> list[tuple[tuple[str, object], ...]]:
    """Every grid point as ((path, value), ...), combining the axes by product or zip."""
    axes = [axis_values(a, sweep.source) for a in sweep.axes]
    if not axes:
        return [()]
    if sweep.combine == "zip":
        lengths = {len(a) for a in axes}
        if len(lengths) > 1:
            found = ", ".join(f"{a.name}: {len(v)}" for a, v in zip(sweep.axes, axes))
            raise SweepError(sweep.source, "grid", 'axes with the same number of values (combine = "zip")', found)
        combos = zip(*axes)
    else:
        combos = itertools.product(*axes)
    points = min(len(a) for a in axes) if sweep.combine == "zip" else math.prod(len(a) for a in axes)
    if points * sweep.samples > MAX_SWEEP_ROWS:
        raise SweepError(sweep.source, "grid", f"at most {MAX_SWEEP_ROWS} runs (grid points x samples)",
                         f"{points} grid points x {sweep.samples} samples")
    return [tuple(pair for point in combo for pair in point) for combo in combos]


def draw_value(d: Draw, seed: int, sample: int):
    """Value of drawn parameter ``d`` in draw ``sample``: a plain float/int (or a ``choice`` value)."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, sample, zlib.crc32(d.path.encode())]))
    a = d.args
    if d.dist == "uniform":
        return float(rng.uniform(a[0], a[1]))
    if d.dist == "loguniform":
        return float(math.exp(rng.uniform(math.log(a[0]), math.log(a[1]))))
    if d.dist == "normal":
        return float(rng.normal(a[0], a[1]))
    if d.dist == "integers":
        return int(rng.integers(a[0], a[1], endpoint=True))
    return a[int(rng.integers(len(a)))]  # choice


def expand(sweep: Sweep) -> list[Row]:
    """All runs of the sweep, in row order (see the module docstring for the numbering and seeding)."""
    draws = [tuple((d.path, draw_value(d, sweep.seed, j)) for d in sweep.draws) for j in range(sweep.samples)]
    rows = []
    for point in grid_points(sweep):
        for j, drawn in enumerate(draws):
            rows.append(Row(len(rows), j, point + drawn))
    return rows

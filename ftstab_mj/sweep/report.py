"""The sweep report: one PNG per ``[[report.plot]]`` of the sweep file, and log-log slopes.

Each figure shows column ``y`` against column ``x`` for the completed runs, one series per value of
column ``by``: every run as a faint dot, the median over the runs sharing an x (Monte Carlo draws)
as a line. With ``fit = true`` the slope of log10(median y) against log10(x), fitted by least
squares per series, is in the legend and in the returned fits. Runs that did not complete, or whose
value is missing or not positive on a log axis, are left out and counted on the figure.

Drawn with matplotlib's object API (``Figure`` + Agg canvas): no pyplot, no global state.
"""

from __future__ import annotations

import difflib
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ftstab_mj import keypath
from ftstab_mj.errors import SweepError
from ftstab_mj.records import COMPLETED
from ftstab_mj.sweep.spec import PlotSpec, Sweep
from ftstab_mj.sweep.table import read_table


@dataclass(frozen=True)
class Fit:
    """Least-squares line log10(y) = slope * log10(x) + intercept through a series' medians."""

    plot: str  # the PNG file name
    series: str  # "by = value", or "all runs"
    slope: float
    intercept: float
    points: int  # distinct x values fitted


def loglog_fit(x, y) -> tuple[float, float]:
    """(slope, intercept) of the least-squares line through (log10 x, log10 y); x, y > 0, >= 2 points."""
    return tuple(float(c) for c in np.polyfit(np.log10(x), np.log10(y), 1))


def _medians(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    xs = np.unique(x)
    return xs, np.array([np.median(y[x == v]) for v in xs])


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9]+", "_", text.removeprefix("metrics.loops.")).strip("_")


def _column(table: dict, name: str, sweep: Sweep, where: str) -> list:
    if name not in table:
        near = difflib.get_close_matches(name, list(table), n=1)
        hint = f" (did you mean {near[0]!r}?)" if near else ""
        raise SweepError(sweep.source, where, "a column of the sweep's table", f"{name!r}{hint}")
    return table[name]


def plot_one(spec: PlotSpec, table: dict, sweep: Sweep, where: str, path: Path) -> list[Fit]:
    """Draw one figure to ``path``; return its fits (empty without ``fit``)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.ticker import NullFormatter

    xs, ys = _column(table, spec.x, sweep, keypath.join(where, "x")), _column(table, spec.y, sweep, keypath.join(where, "y"))
    by = _column(table, spec.by, sweep, keypath.join(where, "by")) if spec.by else [None] * len(xs)
    status = table["status"]

    def usable(v, log):
        return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and (v > 0 or not log)

    keep = [i for i in range(len(xs)) if status[i] == COMPLETED and usable(xs[i], spec.logx) and usable(ys[i], spec.logy)]
    left_out = len(xs) - len(keep)
    fig = Figure(figsize=(5.0, 3.6), dpi=200)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    fits = []
    groups = sorted({by[i] for i in keep}, key=lambda v: (type(v).__name__, v))  # one type per column but None
    for n, g in enumerate(groups):
        idx = [i for i in keep if by[i] == g]
        x, y = np.array([xs[i] for i in idx], float), np.array([ys[i] for i in idx], float)
        label = f"{spec.by} = {g}" if spec.by else "all runs"
        color = f"C{n % 10}"
        mx, my = _medians(x, y)
        if len(mx) < len(x):  # several runs per x: show them all, faint
            ax.plot(x, y, ".", color=color, alpha=0.3, markersize=3)
        text = label
        if spec.fit and len(mx) >= 2:
            slope, icpt = loglog_fit(mx, my)
            fits.append(Fit(path.name, label, slope, icpt, len(mx)))
            text = f"{label}: slope {slope:.2f}"
            ax.plot(mx, 10 ** icpt * mx ** slope, "--", color=color, linewidth=0.8)
        ax.plot(mx, my, "o-", color=color, label=text, markersize=4)
    ax.set_xscale("log" if spec.logx else "linear")
    ax.set_yscale("log" if spec.logy else "linear")
    grid_x = sorted({xs[i] for i in keep})
    if spec.logx and 0 < len(grid_x) <= 10:  # a few swept values: label them, not log-axis minor ticks
        ax.set_xticks(grid_x, [f"{v:g}" for v in grid_x])
        ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel(spec.xlabel or spec.x)
    ax.set_ylabel(spec.ylabel or spec.y)
    ax.set_title(spec.title or f"{sweep.name}", fontsize=9)
    ax.grid(True, which="both", linewidth=0.3, alpha=0.5)
    if groups:
        ax.legend(fontsize=7)
    if left_out:
        ax.text(0.99, 0.01, f"{left_out} run(s) not completed or without a value: not shown", fontsize=6,
                ha="right", va="bottom", transform=ax.transAxes)
    fig.tight_layout()
    fig.savefig(path)
    return fits


def make_report(sweep: Sweep, table_path, out_dir) -> tuple[list[Path], list[Fit]]:
    """Draw every ``[[report.plot]]`` of ``sweep`` from its table into ``out_dir``: (PNG paths, fits)."""
    table = read_table(Path(table_path))
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths, fits = [], []
    for i, spec in enumerate(sweep.plots):
        path = out / f"{sweep.name}_{i}_{_slug(spec.y)}_vs_{_slug(spec.x)}.png"
        fits += plot_one(spec, table, sweep, keypath.join("report.plot", i), path)
        paths.append(path)
    return paths, fits

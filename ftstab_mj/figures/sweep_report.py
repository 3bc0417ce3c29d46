"""The sweep report: one PNG per ``[[report.plot]]`` of the sweep file, and log-log slopes.

Each figure shows column ``y`` against column ``x`` for the completed runs, one series per value of
column ``by``: every run as a faint dot, the median over the runs sharing an x (Monte Carlo draws)
as a line, labelled "median" when there are several. With ``fit = true`` the slope of
log10(median y) against log10(x), fitted by least squares per series, is in the legend and in the
returned fits, but only for a series that is a power law: at least MIN_FIT_POINTS distinct x (a
line through two points always fits) and r^2 >= MIN_R2 on log-log, r^2 = 1 - sum(res^2) / sum((log10
y - mean)^2) with res the residuals of the fit. Otherwise the figure and the fit say "not a power
law" with r^2 and no slope is drawn. Runs that did not complete, or whose value is missing or not
positive on a log axis, are left out and counted on the figure. A title too wide for the figure is
wrapped onto more lines.

Drawn with matplotlib's object API (``Figure`` + Agg canvas): no pyplot, no global state.
"""

from __future__ import annotations

import difflib
import math
import re
import textwrap
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ftstab_mj.config import keypath
from ftstab_mj.config.errors import SweepError
from ftstab_mj.simulation.records import COMPLETED
from ftstab_mj.studies.sweep.spec import PlotSpec, Sweep
from ftstab_mj.studies.sweep.table import read_table


MIN_FIT_POINTS = 3  # distinct x values: fewer cannot tell a power law from anything else
MIN_R2 = 0.99  # on log-log: below it the medians bend away from one line (a floor, a knee, a jump)


@dataclass(frozen=True)
class Fit:
    """Least-squares line log10(y) = slope * log10(x) + intercept through a series' medians, with
    its r^2 on log-log; slope and intercept are None when the series is not a power law (power_law
    False: fewer than MIN_FIT_POINTS points or r^2 < MIN_R2)."""

    plot: str  # the PNG file name
    series: str  # "by = value", or "all runs"
    slope: float | None
    intercept: float | None
    points: int  # distinct x values fitted
    r2: float | None = None  # None with fewer than MIN_FIT_POINTS points
    power_law: bool = True

    @property
    def why_not(self) -> str:
        """Why no slope was fitted ("" when one was)."""
        if self.power_law:
            return ""
        if self.r2 is None:
            return f"{self.points} points: a line through fewer than {MIN_FIT_POINTS} always fits"
        return f"not a power law: r^2 = {self.r2:.3f} < {MIN_R2:g} on log-log"


def loglog_fit(x, y) -> tuple[float, float]:
    """(slope, intercept) of the least-squares line through (log10 x, log10 y); x, y > 0, >= 2 points."""
    return tuple(float(c) for c in np.polyfit(np.log10(x), np.log10(y), 1))


def loglog_r2(x, y, slope: float, intercept: float) -> float:
    """r^2 of the line log10 y = slope log10 x + intercept (1 when y is constant and the line is exact)."""
    lx, ly = np.log10(x), np.log10(y)
    res = ly - (slope * lx + intercept)
    tot = float(np.sum((ly - ly.mean()) ** 2))
    ss = float(np.sum(res ** 2))
    return 1.0 - ss / tot if tot > 0 else (1.0 if ss == 0 else 0.0)


def fit_series(plot: str, series: str, x, y) -> Fit:
    """The Fit of one series' medians (x, y > 0), refused when it is not a power law (see the module)."""
    if len(x) < MIN_FIT_POINTS:
        return Fit(plot, series, None, None, len(x), None, False)
    slope, icpt = loglog_fit(x, y)
    r2 = loglog_r2(x, y, slope, icpt)
    if r2 < MIN_R2:
        return Fit(plot, series, None, None, len(x), r2, False)
    return Fit(plot, series, slope, icpt, len(x), r2, True)


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


def _fit_title(ax, title: str, renderer) -> None:
    """Set the axes title and lay the figure out, the title wrapped onto as many lines as it takes
    to lie inside the figure (it is centred on the axes, not on the figure)."""
    fig_w = ax.figure.bbox.width
    for width in range(len(title), 9, -2):  # characters per line, fewer until the title fits
        ax.set_title(textwrap.fill(title, width), fontsize=9)
        ax.figure.tight_layout()
        ext = ax.title.get_window_extent(renderer)
        if ext.x0 >= 0.01 * fig_w and ext.x1 <= 0.99 * fig_w:
            return


def draw_plot(spec: PlotSpec, table: dict, sweep: Sweep, where: str, name: str):
    """(matplotlib Figure, fits) of one ``[[report.plot]]``; ``name`` is the PNG file name the fits cite."""
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
    canvas = FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    fits = []
    groups = sorted({by[i] for i in keep}, key=lambda v: (type(v).__name__, v))  # one type per column but None
    for n, g in enumerate(groups):
        idx = [i for i in keep if by[i] == g]
        x, y = np.array([xs[i] for i in idx], float), np.array([ys[i] for i in idx], float)
        label = f"{spec.by} = {g}" if spec.by else "all runs"
        color = f"C{n % 10}"
        mx, my = _medians(x, y)
        text = label
        if len(mx) < len(x):  # several runs per x: show them all, faint; the line is their median
            ax.plot(x, y, ".", color=color, alpha=0.3, markersize=3)
            text = f"{label}, median"
        if spec.fit:
            fit = fit_series(name, label, mx, my)
            fits.append(fit)
            if fit.power_law:
                text = f"{text}: slope {fit.slope:.2f}"
                ax.plot(mx, 10 ** fit.intercept * mx ** fit.slope, "--", color=color, linewidth=0.8)
            else:
                text = f"{text}: no slope ({'r$^2$ = ' + format(fit.r2, '.2f') if fit.r2 is not None else 'too few points'})"
        ax.plot(mx, my, "o-", color=color, label=text, markersize=4)
    ax.set_xscale("log" if spec.logx else "linear")
    ax.set_yscale("log" if spec.logy else "linear")
    grid_x = sorted({xs[i] for i in keep})
    if spec.logx and 0 < len(grid_x) <= 10:  # a few swept values: label them, not log-axis minor ticks
        ax.set_xticks(grid_x, [f"{v:g}" for v in grid_x])
        ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel(spec.xlabel or spec.x)
    ax.set_ylabel(spec.ylabel or spec.y)
    ax.grid(True, which="both", linewidth=0.3, alpha=0.5)
    if groups:
        ax.legend(fontsize=7)
    if left_out:
        ax.text(0.99, 0.01, f"{left_out} run(s) not completed or without a value: not shown", fontsize=6,
                ha="right", va="bottom", transform=ax.transAxes)
    _fit_title(ax, spec.title or f"{sweep.name}", canvas.get_renderer())  # (lays the figure out)
    return fig, fits


def plot_one(spec: PlotSpec, table: dict, sweep: Sweep, where: str, path: Path) -> list[Fit]:
    """Draw one figure to ``path``; return its fits (empty without ``fit``)."""
    fig, fits = draw_plot(spec, table, sweep, where, path.name)
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

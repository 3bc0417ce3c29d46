"""The figures of ``ftstab compare``: small multiples over time, and accuracy against the grid with a
slope only where the points are a power law.

* :func:`time_figure`: one row per law, u on the left and |z_1| (log) on the right, every panel of a
  column sharing its axes with the others (so the laws are compared on one scale and none hides
  another), the law's label in each row.
* :func:`accuracy_figure`: max |z_1| and max |z_r| over the final window against the grid value,
  log-log, one line per law; a law's legend entry (below the axes) states its slope only when the fit is a power law
  (at least 3 grid values and r^2 >= 0.99 on log-log, the rule of ``sweep --report``:
  ftstab_mj.figures.sweep_report.fit_series) and otherwise says why not (r^2, or too few points).

Every axis label carries its unit. Shapes: ``series[label]`` holds arrays t, u, z1 of one length.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ftstab_mj.figures.sweep_report import fit_series
from ftstab_mj.simulation.records import COMPLETED

GRID_UNITS = {"sim.period": "control period, s", "sim.physics_step": "s", "sim.duration": "s"}


def grid_label(grid_path: str) -> str:
    """The x label of a grid axis with its unit: "sim.period (control period, s)"; a disturbance or gain
    amplitude is in chain units."""
    unit = GRID_UNITS.get(grid_path)
    if unit is None:
        unit = "chain units, m/s^r or rad/s^r" if "disturbance" in grid_path else "as in the scenario"
    return f"{grid_path} ({unit})"


def z_unit(i: int) -> str:
    """The unit of z_i on a chain of positions: m or rad, per s^(i-1)."""
    return "m or rad" if i == 1 else ("m/s or rad/s" if i == 2 else f"m/s^{i - 1} or rad/s^{i - 1}")


def _order(rows):
    return list(dict.fromkeys(row["label"] for row in rows))


def accuracy_fits(rows: list[dict], grid_path: str, i: int) -> dict:
    """{label: Fit} of max |z_i| against the grid value (completed rows with a positive value)."""
    fits = {}
    for label in _order(rows):
        pts = sorted((row[grid_path], row.get(f"final_abs_z{i}")) for row in rows
                     if row["label"] == label and row["status"] == COMPLETED)
        pts = [(x, y) for x, y in pts if y is not None and y > 0]
        fits[label] = (pts, fit_series("accuracy", label, np.array([p[0] for p in pts], dtype=float),
                                       np.array([p[1] for p in pts], dtype=float)))
    return fits


def _figure(**kw):
    """A matplotlib Figure on the Agg canvas (the object API: no pyplot, ~0.1 s of imports less, no global state)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(**kw)
    FigureCanvasAgg(fig)
    return fig


def accuracy_figure(name: str, rows: list[dict], grid_path: str):
    """The accuracy figure (matplotlib Figure): panels max |z_1| and, when r > 1, max |z_r|."""
    import matplotlib
    import matplotlib.ticker  # noqa: F401 - matplotlib.ticker below

    r = sum(1 for k in rows[0] if k.startswith("final_abs_z"))
    idx = (1, r) if r > 1 else (1,)
    labels = _order(rows)
    legend_h = 0.5 + 0.14 * len(labels)  # inches below the axes for one legend line per law
    height = 3.6 + legend_h
    fig = _figure(figsize=(6.0 * len(idx), height))
    axes = fig.subplots(1, len(idx), squeeze=False)
    fig.subplots_adjust(left=0.08, right=0.98, top=1.0 - 0.7 / height, bottom=(legend_h + 0.55) / height, wspace=0.3)
    colors = matplotlib.colormaps["tab20" if len(labels) > 10 else "tab10"]
    for ax, i in zip(axes[0], idx):
        for j, (label, (pts, fit)) in enumerate(accuracy_fits(rows, grid_path, i).items()):
            if not pts:
                continue
            text = f"{label}: slope {fit.slope:.2f}" if fit.power_law else f"{label}: no slope ({fit.why_not})"
            ax.loglog(*zip(*pts), "os^vD"[j % 5] + "-", ms=3.5, lw=1, color=colors(j % colors.N), label=text)
        ax.set_xlabel(grid_label(grid_path))
        ax.set_ylabel(f"max |z_{i}|, final window ({z_unit(i)})")
        xs = sorted({row[grid_path] for row in rows if row.get(grid_path) is not None})
        ax.set_xticks(xs, [f"{x:g}" for x in xs], fontsize=7)  # the grid's own values: no colliding labels
        ax.xaxis.set_minor_locator(matplotlib.ticker.NullLocator())
        ax.set_title(f"z_{i}")
        ax.grid(True, which="both", alpha=0.3)
        # below the axes, under the x label: the legend never covers data
        ax.legend(fontsize=6, loc="upper left", bbox_to_anchor=(0.0, -0.55 / 3.6 - 0.12), frameon=False)
    fig.suptitle(f"{name}: final accuracy against {grid_path} (slope only where r^2 >= 0.99 on log-log)")
    return fig


def time_figure(name: str, series: dict, where: str = "", r: int = 2):
    """Small multiples: one row per law, u | |z_1|, shared axes per column (matplotlib Figure)."""
    n = len(series)
    fig = _figure(figsize=(11, 1.0 + 1.25 * n))
    axes = fig.subplots(n, 2, sharex=True, sharey="col", squeeze=False)
    for (label, s), (au, az) in zip(series.items(), axes):
        au.plot(s["t"], s["u"], lw=0.5, color="C0")
        az.semilogy(s["t"], np.maximum(s["z1"], 1e-16), lw=0.7, color="C1")
        au.set_title(label, fontsize=8, loc="left", pad=2)
        for ax in (au, az):
            ax.grid(True, alpha=0.3)
            ax.tick_params(labelsize=7)
    for au, az in axes:
        au.set_ylabel(f"u (m/s^{r})", fontsize=7)
        az.set_ylabel("|z_1| (m)", fontsize=7)
    axes[-1][0].set_xlabel("t (s)")
    axes[-1][1].set_xlabel("t (s)")
    fig.suptitle(f"{name}: u and |z_1| per law{where} (shared axes per column)", fontsize=10)
    fig.tight_layout()
    return fig


def limit_cycle_figure(name: str, rows: list[dict]):
    """Measured against predicted chattering (matplotlib Figure), one point per run with a
    describing-function prediction: z_1's amplitude (m) and frequency (Hz), measured on the y axis,
    predicted on the x axis, the line y = x and the +-20 % band; None when no row has a prediction."""
    pts = [r for r in rows if r.get("df_frequency") and r.get("z1_osc_frequency") and r.get("z1_osc_amplitude")]
    if not pts:
        return None
    fig = _figure(figsize=(10, 4.2))
    axes = fig.subplots(1, 2)
    labels = _order(pts)
    for ax, (pred, meas, what) in zip(axes, (("df_z1_amplitude", "z1_osc_amplitude", "z_1 amplitude (m or rad)"),
                                             ("df_frequency", "z1_osc_frequency", "frequency (Hz)"))):
        for j, label in enumerate(labels):
            mine = [r for r in pts if r["label"] == label]
            ax.loglog([r[pred] for r in mine], [r[meas] for r in mine], "os^vD"[j % 5], ms=5, label=label)
        lo = min(min(r[pred], r[meas]) for r in pts) / 1.5
        hi = max(max(r[pred], r[meas]) for r in pts) * 1.5
        ax.plot([lo, hi], [lo, hi], "k-", lw=0.8)
        ax.fill_between([lo, hi], [0.8 * lo, 0.8 * hi], [1.2 * lo, 1.2 * hi], color="0.85", label="+-20 %")
        ax.set_xlabel(f"describing function: {what}")
        ax.set_ylabel(f"measured: {what}")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle(f"{name}: chattering measured against the describing-function prediction")
    fig.tight_layout()
    return fig


def draw_figures(name: str, rows: list[dict], grid_path: str | None, grid, series: dict, out: Path,
                 where: str = "") -> list[Path]:
    """Write ``<name>_accuracy.png`` (with a grid of >= 2 values), ``<name>_limit_cycle.png`` (when a
    loop has an actuator lag: :func:`limit_cycle_figure`) and ``<name>_time.png``; their paths."""
    paths = []
    r = sum(1 for k in rows[0] if k.startswith("final_abs_z")) if rows else 0
    if grid_path and len(grid) >= 2 and r:
        fig = accuracy_figure(name, rows, grid_path)
        paths.append(Path(out) / f"{name}_accuracy.png")
        fig.savefig(paths[-1], dpi=110, bbox_inches="tight")
    fig = limit_cycle_figure(name, rows) if rows else None
    if fig is not None:
        paths.append(Path(out) / f"{name}_limit_cycle.png")
        fig.savefig(paths[-1], dpi=100, bbox_inches="tight")
    if series:
        fig = time_figure(name, series, where, r=max(r, 1))
        paths.append(Path(out) / f"{name}_time.png")
        fig.savefig(paths[-1], dpi=90, bbox_inches="tight")
    return paths

"""``ftstab compare COMPARE.toml``: several control laws on one base scenario, side by side.

A comparison file names a base scenario, the laws (each a whole controller table, so no parameter of
another law is left behind) and optionally one grid axis (the control period or a disturbance
amplitude)::

    name = "cart_r2"                       # names DIR/<name>.csv, .parquet, _slopes.csv, _*.png
    description = "one line"
    scenario = "../cart_r2_robust.toml"    # the base scenario, relative to this file
    steps_per_period = 10                  # with a sim.period grid: physics_step = period / N

    [set]                                  # overrides of every run (key paths of `ftstab run --set`)
    "sim.duration" = 10.0

    [grid]                                 # optional, one key path
    "sim.period" = [5e-4, 1e-3, 2e-3, 4e-3]

    [[laws]]
    label = "robust"
    controller = { law = "robust", k = -0.2, gains = [1.0, 2.0], phibar = 1.0, gamma_m = 0.5 }

    [[laws]]
    label = "levant_qc"
    controller = { law = "levant_qc", alpha = 5.0 }

Every law replaces ``loops.<loop>.controller`` of every loop of the base (``loop = "cart"`` picks
one). The rows (laws x grid values) run on the sweep engines (serial or a local process pool) and
give one table, laws as rows, written as CSV and Parquet, with the metrics of ``ftstab run``
(ftstab_mj.metrics.run_metrics): law-independent settling time settle_time_z1 (s), final accuracy max |z_i| over
the final window (chain units), effort integral of u^2 (u^2 s), max |u|, the four chattering indices
and, where a time bound applies, whether it was beaten. With a ``sim.period`` grid the log-log slope
of each max |z_i| against the period is fitted per law (least squares on log10) and drawn.
Figures (ftstab_mj.figures.compare_report, drawn by the command line): ``<name>_accuracy.png`` (max
|z_1| and max |z_r| against the grid value, log-log, a slope only through a power law) and
``<name>_time.png`` (u and |z_1| against time, one row per law, at the first grid value).
Bad input: one line (SweepError: file, key path, expected, found) before any run.
"""

from __future__ import annotations

import csv
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ftstab_mj.config import keypath
from ftstab_mj.config.errors import ScenarioError, SweepError, UsageError, describe
from ftstab_mj.simulation.records import COMPLETED
from ftstab_mj.scenario.loader import apply_override, resolve_relative_paths, scenario_with
from ftstab_mj.scenario.schema import identifier, one_line
from ftstab_mj.scenario.shipped import SCENARIO_DIR, find_scenario
from ftstab_mj.config.tomlfile import read_toml

TERMINAL_WIDTH = 100  # characters of the printed table (the files hold every column)
TERMINAL_DROPS = ("effort_sq", "chattering_du_dt_var", "chattering_zero_crossings", "chattering_band_rms")
SERIES_POINTS = 4000  # samples kept per law for the time plot (evenly strided)
INDICES = (("chattering", "chattering_tv"), ("chattering_du_dt_var", "chattering_du_dt_var"),
           ("chattering_zero_crossings", "chattering_zero_crossings"), ("chattering_band_rms", "chattering_band_rms"))


@dataclass(frozen=True)
class LawEntry:
    label: str
    controller: dict


@dataclass(frozen=True)
class Comparison:
    """A validated comparison file (module docstring); ``scenario`` resolved against the file."""

    name: str
    description: str
    scenario: Path
    source: str
    laws: tuple[LawEntry, ...]
    set: tuple[tuple[str, object], ...] = ()
    grid_path: str | None = None
    grid: tuple = ()
    steps_per_period: int | None = None
    loop: str | None = None


def _error(source, path, expected, found):
    return SweepError(source, path or "(top level)", expected, found)


def load_comparison(path) -> Comparison:
    """Read and validate a comparison file; SweepError (one line) on any problem."""
    src = str(path)
    raw = read_toml(path, "comparison file (.toml)", SweepError)
    keys = ("name", "description", "scenario", "steps_per_period", "loop", "set", "grid", "laws")
    for k in raw:
        if k not in keys:
            raise _error(src, k, "one of the keys " + ", ".join(keys), f"unknown key {k!r}")
    for k in ("name", "description", "scenario", "laws"):
        if k not in raw:
            raise _error(src, k, "a value", "nothing: the key is required")
    for k, check in (("name", identifier), ("description", one_line), ("scenario", None), ("loop", None)):
        if k in raw:
            v = raw[k]
            if not isinstance(v, str) or (check and check(v)):
                raise _error(src, k, check(v) if isinstance(v, str) and check else "a string", describe(v))
    scenario = Path(os.path.normpath(Path(path).parent / raw["scenario"]))
    if not scenario.is_file():
        raise _error(src, "scenario", "an existing scenario file, relative to the comparison file",
                     f"{raw['scenario']!r} (no such file: {scenario})")
    spp = raw.get("steps_per_period")
    if spp is not None and (isinstance(spp, bool) or not isinstance(spp, int) or spp < 1):
        raise _error(src, "steps_per_period", "an integer >= 1", describe(spp))
    fixed = raw.get("set", {})
    if not isinstance(fixed, dict):
        raise _error(src, "set", "a table of key path = value", describe(fixed))
    for k in fixed:
        if keypath.parse(k) is None:
            raise _error(src, f'set."{k}"', "a scenario key path like sim.duration", repr(k))
    grid = raw.get("grid", {})
    if not isinstance(grid, dict) or len(grid) > 1:
        raise _error(src, "grid", "a table with one key path = [values]", describe(grid))
    grid_path, values = next(iter(grid.items()), (None, ()))
    if grid_path is not None and keypath.parse(grid_path) is None:
        raise _error(src, f'grid."{grid_path}"', "a scenario key path like sim.period", repr(grid_path))
    if grid_path is not None:
        ok = isinstance(values, list) and values and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0 for v in values)
        if not ok:
            raise _error(src, f'grid."{grid_path}"', "a non-empty array of numbers > 0", describe(values))
        twice = sorted({float(v) for v in values if sum(float(w) == float(v) for w in values) > 1})
        if twice:  # W1: the slope fit would count such a point twice (a weighted fit nobody asked for)
            raise _error(src, f'grid."{grid_path}"', "distinct values (a value given twice counts twice in the "
                         "log-log slope)", "repeated " + ", ".join(f"{v:g}" for v in twice))
    if spp is not None and grid_path != "sim.period":
        raise _error(src, "steps_per_period", 'a [grid] over "sim.period" (it sets physics_step = period / N)',
                     f"grid over {grid_path!r}")
    laws = raw["laws"]
    if not isinstance(laws, list) or not laws:
        raise _error(src, "laws", "an array of tables [[laws]] with label and controller", describe(laws))
    entries, seen = [], set()
    for i, body in enumerate(laws):
        p = f"laws[{i}]"
        if not isinstance(body, dict) or set(body) - {"label", "controller"} or not {"label", "controller"} <= set(body):
            raise _error(src, p, "a table with exactly the keys label and controller", describe(body))
        label, ctrl = body["label"], body["controller"]
        if not isinstance(label, str) or one_line(label) or label in seen:
            raise _error(src, f"{p}.label", "a one-line label, different for every law", describe(label))
        if not isinstance(ctrl, dict) or "law" not in ctrl:
            raise _error(src, f"{p}.controller", "a controller table with its law", describe(ctrl))
        seen.add(label)
        entries.append(LawEntry(label, dict(ctrl)))
    return Comparison(raw["name"], raw["description"], scenario, src, tuple(entries), tuple(fixed.items()),
                      grid_path, tuple(values), spp, raw.get("loop"))


@dataclass(frozen=True)
class CompareTask:
    """Runs one row (law, grid value) of a comparison: picklable for the process engine.
    ``base``: raw base scenario data with [set] applied; ``loops``: the loops whose controller is replaced."""

    base: dict
    source: str
    loops: tuple
    grid_path: str | None
    steps_per_period: int | None
    series: bool = True

    def scenario(self, index, params):
        """The validated scenario of one row: typed values set on the base (a table replaces a table)."""
        label, controller, value, _ = params
        values = [(f"loops.{name}.controller", controller) for name in self.loops]
        if self.grid_path is not None:
            values.append((self.grid_path, value))
            if self.steps_per_period:
                values.append(("sim.physics_step", value / self.steps_per_period))
        return scenario_with(self.base, values, f"{self.source} (row {index}: {label})")

    def __call__(self, index: int, params) -> dict:
        from ftstab_mj.scenario.run import run_scenario

        run = run_scenario(self.scenario(index, params), keep_samples=bool(self.series and params[3]))  # a series reads u, z
        out = {"status": run.result.status, "error": "" if run.result.status == COMPLETED else run.result.message,
               "metrics": run.metrics}
        if self.series and params[3]:
            rec = run.result.loops[self.loops[0]]
            stride = max(1, len(rec["t"]) // SERIES_POINTS)
            out["series"] = {"t": rec["t"][::stride].tolist(), "u": rec["u"][::stride].tolist(),
                             "z1": np.abs(rec["z"][::stride, 0]).tolist()}
        return out


def prepare(cmp: Comparison, overrides=()) -> tuple[CompareTask, list]:
    """The task and the rows [(index, (label, controller, grid value, keep series))]; every row's
    scenario is validated here, before any run (a bad law table is a one-line error naming laws[i])."""
    src = str(cmp.scenario)
    raw = read_toml(cmp.scenario, "scenario file (.toml)")
    resolve_relative_paths(raw, Path(src).parent)  # its model and plugins are relative to it
    for path, value in cmp.set:
        keypath.assign(raw, keypath.parse(path), value, f"{src} ({cmp.source} [set]: {path})")
    for text in overrides:
        apply_override(raw, text, src)
    loop_names = tuple(raw.get("loops", {}))
    if cmp.loop is not None and cmp.loop not in loop_names:
        raise _error(cmp.source, "loop", "a loop of the base scenario (" + ", ".join(loop_names) + ")", repr(cmp.loop))
    task = CompareTask(raw, cmp.source, (cmp.loop,) if cmp.loop else loop_names, cmp.grid_path, cmp.steps_per_period)
    values = cmp.grid or (None,)
    rows = []
    for li, law in enumerate(cmp.laws):
        for gi, value in enumerate(values):
            params = (law.label, law.controller, value, gi == 0)
            try:
                task.scenario(len(rows), params)
            except ScenarioError as exc:
                where = f"laws[{li}].controller" if ".controller" in exc.path else (
                    f'grid."{cmp.grid_path}"' if cmp.grid_path else "set")
                raise _error(cmp.source, where, exc.expected, f"{exc.found} (at {exc.path})") from None
            rows.append((len(rows), params))
    return task, rows


def table_row(params, result: dict, loop: str, grid_path: str | None) -> dict:
    """One row of the comparison table from a run's result (metrics of ``loop``)."""
    label, controller, value, _ = params
    row = {"label": label, "law": controller["law"], "discretization": controller.get("discretization", "")}
    if grid_path:
        row[grid_path] = value
    m = (result.get("metrics") or {}).get("loops", {}).get(loop, {})
    row.update(status=result.get("status", "lost"), error=result.get("error", ""),
               settle_time_z1=m.get("settle_time_z1"), settle_time_V1=m.get("settle_time"),
               time_bound=m.get("time_bound"), bound_applies=m.get("bound_applies"), beat_bound=m.get("beat_bound"))
    for i, v in enumerate(m.get("final_abs_z_max") or []):
        row[f"final_abs_z{i + 1}"] = v
    row.update(effort_sq=m.get("effort_sq"), u_max_abs=m.get("u_max_abs"))
    if m.get("clamp"):  # the plant's actuator clamps: what it received, beside the law's u_max_abs
        row.update(u_applied_max_abs=m.get("u_applied_max_abs"), chattering_applied=m.get("chattering_applied"),
                   saturated_fraction=m.get("saturated_fraction"))
    for key, col in INDICES:
        row[col] = m.get(key)
    row.update(oscillation_columns(m))
    row["elapsed_s"] = result.get("elapsed_s")
    return row


def oscillation_columns(m: dict) -> dict:
    """The limit cycle columns of a loop's metrics m: measured z_1 amplitude (m) and frequency (Hz),
    averaged power, and the describing-function prediction (None without an actuator lag)."""
    pred = m.get("limit_cycle_predicted") or {}
    return {"z1_osc_amplitude": m.get("z1_osc_amplitude"), "z1_osc_frequency": m.get("z1_osc_frequency"),
            "averaged_power": m.get("averaged_power"), "df_z1_amplitude": pred.get("amplitude_z1"),
            "df_frequency": pred.get("frequency")}


def engine_for(workers: int, engine: str | None = None) -> str:
    """The sweep engine of ``ftstab compare --workers N [--engine E]``: batch (N threads of this process)
    when asked, else a local process pool when N > 1, else serial; UsageError for --engine serial with N > 1."""
    if workers > 1 and engine == "serial":
        raise UsageError("--engine serial: expected no --workers (one process runs everything)")
    if engine == "batch":
        return "batch"
    return "processes" if workers > 1 else "serial"


def assemble(cmp: Comparison, task, items, results: dict) -> tuple[list[dict], dict, list[str]]:
    """(rows, series, columns) of the comparison table from the engine's ``results`` ({row: result}) of
    ``items`` (:func:`prepare`): one :func:`table_row` per item (a run the engine lost is a row of status
    "lost"), the time series of each law that has one ({label: series}: the first grid value's), and
    the columns printed, in order."""
    rows, series = [], {}
    for i, p in items:
        res = results.get(i) or {"status": "lost", "error": "the worker running it died", "metrics": {}}
        rows.append({"row": i, **table_row(p, res, task.loops[0], cmp.grid_path)})
        if res.get("series"):
            series[p[0]] = res["series"]
    columns = ["label"] + ([cmp.grid_path] if cmp.grid_path else []) + [
        "status", "settle_time_z1", *[k for k in rows[0] if k.startswith("final_abs_z")], "effort_sq", "u_max_abs",
        "chattering_tv", "chattering_du_dt_var", "chattering_zero_crossings", "chattering_band_rms", "beat_bound"]
    return rows, series, columns


def terminal_columns(columns: list[str]) -> list[str]:
    """The columns printed on a terminal: the table's without those that only the files need to hold
    (effort and three of the four chattering indices; the total variation of u stays)."""
    return [c for c in columns if c not in TERMINAL_DROPS]


def lost_line(rows: list[dict], what: str = "run") -> str | None:
    """None when no row was lost by the engine, else the one line an exit status 1 comes with, naming the rows
    (a table with lost rows is not the comparison asked for: issue 44, W4). Rows are dicts with "row" and
    "status" (compare's and montecarlo's tables)."""
    lost = [row["row"] for row in rows if row.get("status") == "lost"]
    if not lost:
        return None
    shown = ", ".join(map(str, lost[:20])) + (f" and {len(lost) - 20} more" if len(lost) > 20 else "")
    return (f"error: {len(lost)} {what}(s) lost by dead worker processes (rows {shown}); the table marks them "
            f"'lost', run the command again for them")


def fit_slopes(rows: list[dict], grid_path: str) -> list[dict]:
    """Per law and per z_i: the least-squares slope of log10 max |z_i| against log10 of the grid value
    (completed rows with a positive accuracy only; None with fewer than 2 points)."""
    out = []
    r = sum(1 for k in rows[0] if k.startswith("final_abs_z")) if rows else 0
    for label in dict.fromkeys(row["label"] for row in rows):
        mine = [row for row in rows if row["label"] == label and row["status"] == COMPLETED]
        fit = {"label": label}
        for i in range(1, r + 1):
            pts = [(row[grid_path], row.get(f"final_abs_z{i}")) for row in mine]
            pts = [(x, y) for x, y in pts if y is not None and y > 0]
            by_x = {}
            for x, y in pts:  # one point per grid value (the geometric mean of duplicates: the fit is in logs)
                by_x.setdefault(x, []).append(y)
            pts = [(x, float(np.exp(np.mean(np.log(ys))))) for x, ys in by_x.items()]
            fit[f"slope_z{i}"] = (float(np.polyfit(np.log10([p[0] for p in pts]), np.log10([p[1] for p in pts]), 1)[0])
                                  if len(pts) >= 2 else None)
        out.append(fit)
    return out


def write_csv(rows: list[dict], path: Path) -> Path:
    names = list(dict.fromkeys(k for row in rows for k in row))
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, names)
        w.writeheader()
        for row in rows:
            w.writerow({k: ("" if row.get(k) is None else row.get(k)) for k in names})
    tmp.replace(path)
    return path


def _fmt(v) -> str:
    if v is None or v == "":
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.3g}"
    return str(v)


def format_rows(rows: list[dict], columns: list[str], width: int | None = None, keep: int = 1) -> str:
    """A fixed-width text table of ``columns`` (laws as rows). With ``width`` (characters), the columns
    are wrapped into blocks no wider than it (unless one column alone is), each block repeating the first
    ``keep`` columns (the label, the grid value) so every line still says whose row it is."""
    cells = [[_fmt(row.get(c)) for c in columns] for row in rows]
    widths = [max(len(c), *(len(r[j]) for r in cells)) for j, c in enumerate(columns)]

    def block(idx):
        line = lambda vals: "  ".join(vals[j].ljust(widths[j]) if j == 0 else vals[j].rjust(widths[j])
                                      for j in idx).rstrip()
        return "\n".join([line(columns)] + [line(r) for r in cells])

    if width is None:
        return block(range(len(columns)))
    head, blocks, cur = list(range(min(keep, len(columns)))), [], []
    used = sum(widths[j] + 2 for j in head)
    for j in range(len(head), len(columns)):
        if cur and used + widths[j] > width:
            blocks.append(head + cur)
            cur, used = [], sum(widths[j] + 2 for j in head)
        cur.append(j)
        used += widths[j] + 2
    blocks.append(head + cur)
    return "\n\n".join(block(idx) for idx in blocks)


def write_markdown(sections: list[tuple[str, list[dict], list[str]]], path: Path, title: str = "") -> Path:
    """A Markdown file of one table per (heading, rows, columns) section, values as printed (3 digits)."""
    esc = lambda text: text.replace("|", "\\|")
    out = [f"# {esc(title)}", ""] if title else []
    for heading, rows, columns in sections:
        out += [f"## {esc(heading)}", "", "| " + " | ".join(map(esc, columns)) + " |",
                "|" + "---|" * len(columns)]
        out += ["| " + " | ".join(esc(_fmt(row.get(c))) for c in columns) + " |" for row in rows]
        out.append("")
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text("\n".join(out), encoding="utf-8")
    tmp.replace(path)
    return path


def find_comparison(arg: str) -> Path:
    """``arg`` as a path, else the shipped comparison scenarios/compare/<arg>.toml (as ``sweep`` finds its own)."""
    return find_scenario(arg, SCENARIO_DIR / "compare")

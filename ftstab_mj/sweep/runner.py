"""A sweep row as a scenario run: the base scenario + the row's overrides, run like ``ftstab run``.

The row's (key path, value) pairs go through the scenario loader's own ``--set`` machinery
(:func:`ftstab_mj.scenario.apply_override` on the raw TOML data, then the full validation), so a
varied parameter gets exactly the checks of the file, and a bad combination fails that row with the
loader's one-line message. Metrics are those of ``ftstab run`` (ftstab_mj.metrics.compute_metrics).
"""

from __future__ import annotations

import copy
import json
from dataclasses import dataclass
from pathlib import Path

from ftstab_mj.errors import ScenarioError, SweepError
from ftstab_mj.records import COMPLETED, INTERRUPTED
from ftstab_mj.scenario import apply_override, scenario_from_dict, scenario_to_dict
from ftstab_mj.scenario.loader import parse_override
from ftstab_mj.sweep.expand import draw_value, grid_values
from ftstab_mj.sweep.spec import Sweep, key_label
from ftstab_mj.tomlfile import read_toml


def toml_literal(value) -> str:
    """``value`` (bool, int, float, str, list, dict) written as a TOML value, for a ``--set`` text."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)  # repr of a float is a valid TOML float (1e-05, inf, nan included)
    if isinstance(value, str):
        return json.dumps(value)  # a TOML basic string
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_literal(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{json.dumps(k)} = {toml_literal(v)}" for k, v in value.items()) + "}"
    raise TypeError(f"no TOML form for {value!r}")  # a value of the sweep file is always one of the above


def override_text(path: str, value) -> str:
    return f"{path}={toml_literal(value)}"


@dataclass(frozen=True)
class ScenarioTask:
    """Runs one row: ``base`` (raw TOML data of the base scenario, fixed overrides applied) + the row's
    overrides. Picklable. ``logs``: directory for each run's ``<row>.mcap`` and ``<row>.rrd``, or None."""

    base: dict
    source: str  # the sweep file, prefix of every error
    logs: str | None = None

    def __call__(self, index: int, params) -> dict:
        from ftstab_mj.scenario.run import run_scenario

        raw = copy.deepcopy(self.base)
        where = {}
        src = f"{self.source} (row {index})"
        for path, value in params:
            text = override_text(path, value)
            where[apply_override(raw, text, src)] = text
        sc = scenario_from_dict(raw, src, where)
        sinks = ()
        if self.logs:
            from ftstab_mj.logs import McapSink, RerunSink

            Path(self.logs).mkdir(parents=True, exist_ok=True)
            stem = Path(self.logs) / f"row{index:05d}"
            sinks = (McapSink(stem.with_suffix(".mcap")), RerunSink(stem.with_suffix(".rrd")))
        run = run_scenario(sc, sinks)
        status = run.result.status
        if status == INTERRUPTED:  # the run loop caught Ctrl-C: not a result of this row, stop the sweep
            raise KeyboardInterrupt
        return {"status": status, "error": "" if status == COMPLETED else run.result.message, "metrics": run.metrics}


def _has_path(data, parts) -> bool:
    """Whether the key path (parts of parse_override) exists in ``data``."""
    node = data
    for part in parts:
        if isinstance(part, int):
            if not isinstance(node, list) or part >= len(node):
                return False
        elif not isinstance(node, dict) or part not in node:
            return False
        node = node[part]
    return True


def _unknown_key(raw: dict, path: str, value, source: str) -> bool:
    """Whether setting ``path`` (absent from the resolved base) is refused by the loader as an unknown
    key (a typo). A key the schema knows but the base leaves out (an optional field) is fine."""
    trial = copy.deepcopy(raw)
    text = override_text(path, value)
    apply_override(trial, text, source)
    try:
        scenario_from_dict(trial, source, {path: text})
    except ScenarioError as exc:
        return exc.path == path and exc.found.startswith("unknown key")
    return False


def prepare(sweep: Sweep, overrides=(), logs_dir=None) -> tuple[ScenarioTask, dict]:
    """The task of every row and the identity of the sweep (the base every run starts from).

    Applies the sweep's [set] then ``overrides`` (the command line's --set texts) to the base
    scenario and validates it: an invalid base is an error before any run. Checks that every varied
    key path is in the resolved base or is a key the schema knows (a typo would fail every run).
    """
    src = str(sweep.scenario)
    raw = read_toml(sweep.scenario, "scenario file (.toml)")
    where = {}
    for text in [override_text(p, v) for p, v in sweep.set] + list(overrides):
        where[apply_override(raw, text, src)] = text
    resolved = scenario_to_dict(scenario_from_dict(raw, src, where))
    varied = [(a.label(p.path), p.path) for a in sweep.axes for p in a.params]
    first = {p.path: grid_values(p)[0] for a in sweep.axes for p in a.params}
    first.update({d.path: draw_value(d, sweep.seed, 0) for d in sweep.draws})
    for label, path in varied + [(key_label("draw", d.path), d.path) for d in sweep.draws]:
        parts, _, _ = parse_override(f"{path}=0", sweep.source)
        if not _has_path(resolved, parts) and _unknown_key(raw, path, first[path], src):
            raise SweepError(sweep.source, label,
                             f"a key path of the base scenario {sweep.scenario.name}", repr(path))
    return ScenarioTask(raw, sweep.source, None if logs_dir is None else str(logs_dir)), {"base": raw}

"""A sweep row as a scenario run: the base scenario + the row's values, run like ``ftstab run``.

The row's (key path, value) pairs are set as typed values on the raw data of the base scenario
(:func:`ftstab_mj.scenario.loader.scenario_with`: no TOML text in between), then the scenario is
validated as a file is, so a varied parameter gets exactly the checks of the file (the base's tables
the row does not touch are read once per sweep, the checks across fields made for every row). A table value
replaces the table at its path: a grid over ``loops.cart.controller`` with whole controller tables
switches laws cleanly (each table holds its own law's parameters only).

Every row is validated by :func:`prepare` before anything runs: a bad combination is bad input
(SweepError, exit 2), never a failed row. Metrics are those of ``ftstab run``. A row is not
validated twice where that can be avoided: the scenarios :func:`prepare` validated are kept in this
process (:data:`_PREPARED`, at most KEEP_PREPARED rows) for the runs made here (serial engine) and in
worker processes forked from it (engine.py); a spawned or Dask worker gets them with its chunk of
rows (:meth:`ScenarioTask.carrying`: ~1.4 KB a row, where validating again costs ~0.4 ms of CPU).
"""

from __future__ import annotations

import uuid
from pathlib import Path
import weakref
from dataclasses import dataclass, field, replace

from ftstab_mj.config import keypath
from ftstab_mj.config.errors import ScenarioError, SweepError
from ftstab_mj.simulation.records import COMPLETED, INTERRUPTED
from ftstab_mj.scenario.loader import apply_override, resolve_relative_paths, scenario_from_dict, scenario_with
from ftstab_mj.studies.sweep.spec import Sweep
from ftstab_mj.config.tomlfile import read_toml, value_text


def row_notes(index: int, params) -> dict[str, str]:
    """{key path: "row 3: sim.period = 0.002"}: what an error names after the sweep file."""
    return {path: f"row {index}: {path} = {_short(value_text(value))}" for path, value in params}


def _short(text: str) -> str:
    return text if len(text) <= 60 else text[:57] + "..."


# {task token: {row: (params, validated Scenario)}}: what prepare() validated, for the runs made in this
# process or in a process forked from it after prepare(); emptied as rows run, dropped with the task
_PREPARED: dict[str, dict[int, tuple]] = {}
KEEP_PREPARED = 20_000  # rows whose validated scenario is kept (~2 KB each); the others are validated again to run


@dataclass(frozen=True)
class ScenarioTask:
    """Runs one row: ``base`` (raw TOML data of the base scenario, fixed overrides applied) + the row's
    values. Picklable. ``logs``: directory for each run's MCAP log ``<row>.mcap``, or None.
    ``token``: names this task's prepared scenarios in :data:`_PREPARED` ("" for none); ``carried``:
    {row: (params, validated Scenario)} this copy of the task brings along (:meth:`carrying`)."""

    base: dict
    source: str  # the sweep file, prefix of every error
    logs: str | None = None
    token: str = ""
    carried: dict = field(default_factory=dict, compare=False, repr=False)

    def scenario(self, index: int, params):
        """The validated scenario of row ``index``; ScenarioError naming the sweep file and the row."""
        return scenario_with(self.base, params, self.source, row_notes(index, params))

    def carrying(self, indices) -> ScenarioTask:
        """This task with the scenarios :func:`prepare` validated for rows ``indices`` in it, for a worker
        that does not share this process's memory (spawned, Dask): it runs them as they are."""
        kept = _PREPARED.get(self.token, {})
        return replace(self, carried={i: kept[i] for i in indices if i in kept})

    def __call__(self, index: int, params) -> dict:
        from ftstab_mj.scenario.run import run_scenario

        kept = self.carried.get(index) or _PREPARED.get(self.token, {}).pop(index, None)
        sc = kept[1] if kept is not None and kept[0] == params else self.scenario(index, params)
        sinks = ()
        if self.logs:
            from ftstab_mj.logs.run_logs import open_run_logs

            sinks = open_run_logs(self.logs, f"row{index:05d}").sinks()  # a refused path: this row fails
        run = run_scenario(sc, sinks)
        status = run.result.status
        if status == INTERRUPTED:  # the run loop caught Ctrl-C: not a result of this row, stop the sweep
            raise KeyboardInterrupt
        return {"status": status, "error": "" if status == COMPLETED else run.result.message, "metrics": run.metrics}


def warm() -> None:
    """Import batch_env.WORKER_MODULES: a Dask worker does it as it starts (:func:`dask_setup`), while the
    parent validates the rows, instead of when its first row arrives (a local cluster's workers
    inherit them from their forkserver: engine.py)."""
    import importlib

    from ftstab_mj.studies.batch_env import WORKER_MODULES

    for name in WORKER_MODULES:
        importlib.import_module(name)


def dask_setup(worker) -> None:
    """Dask's preload hook: the sweep engine starts its LocalCluster with ``preload=[this module]``."""
    warm()


def prepare(sweep: Sweep, rows, overrides=(), logs_dir=None) -> tuple[ScenarioTask, dict]:
    """The task of every row and the identity of the sweep (the base every run starts from).

    Sets the sweep's [set] values then ``overrides`` (the command line's --set texts) on the base
    scenario and validates it (ScenarioError naming the base file), then validates every row of
    ``rows`` (expand.Row; SweepError naming the sweep file and the row): all before any run or file.
    """
    src = str(sweep.scenario)
    raw = read_toml(sweep.scenario, "scenario file (.toml)")
    resolve_relative_paths(raw, Path(src).parent)  # its model and plugins are relative to it
    notes = {}
    for path, value in sweep.set:
        note = f"{sweep.source} [set]: {path} = {_short(value_text(value))}"
        keypath.assign(raw, keypath.parse(path), value, f"{src} ({note})")
        notes[path] = note
    for text in overrides:
        notes[apply_override(raw, text, src)] = f"--set {text}"
    scenario_from_dict(raw, src, notes)
    task = ScenarioTask(raw, sweep.source, None if logs_dir is None else str(logs_dir), uuid.uuid4().hex)
    kept = {}
    for row in rows:
        try:
            sc = task.scenario(row.index, row.params)
        except ScenarioError as exc:
            raise SweepError(exc.source, exc.path, exc.expected, exc.found) from None
        if len(kept) < KEEP_PREPARED:
            kept[row.index] = (row.params, sc)
    _PREPARED[task.token] = kept
    weakref.finalize(task, _PREPARED.pop, task.token, None)  # the kept scenarios live as long as the task
    return task, {"base": raw}

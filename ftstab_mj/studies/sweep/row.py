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

import math
import threading
import uuid
from pathlib import Path
import weakref
from dataclasses import dataclass, field, replace

from ftstab_mj.config import keypath
from ftstab_mj.config.errors import ScenarioError, SweepError
from ftstab_mj.config.limits import MAX_STATE
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


# {task token: _States or None (the task's states take the full path)}: each thread's prepared simulation
_STATES = threading.local()
BATCH_SAMPLES = 20_000  # samples of a state's batch (~3 MB on the cart): a run of up to 20 s at 1 ms in one


@dataclass(frozen=True)
class StatesTask:
    """A Monte Carlo's row task on the plant: row ``index`` is the scenario of ``full`` (a ScenarioTask)
    with ``loops.<loop>.z0`` = params' one value; the result is ``full``'s, the loop's metrics restricted
    to :data:`~ftstab_mj.metrics.run_metrics.GUARANTEE_METRICS` (what a Monte Carlo keeps), bit for bit.

    Only z0 changes from one state to the next, so each thread (of an engine's worker) validates the
    scenario once and builds its simulation once (:class:`_States`), then runs every state it is given
    on it, reset to that z0 (Simulation.reset). Where that cannot give the full path's row, each state
    is the full path's run (``full(index, params)``): a scenario of several loops, a tracked reference
    (z0 is relative to ref(t)), a simulation on the Python control path (not resettable), a z0 the file's
    checks refuse (the row then fails with their message, as it would)."""

    full: ScenarioTask
    loop: str
    token: str = field(default_factory=lambda: uuid.uuid4().hex)

    def carrying(self, indices) -> StatesTask:
        return replace(self, full=self.full.carrying(indices))

    def __call__(self, index: int, params) -> dict:
        states = _thread_states(self, index, params)
        (_, z), = params
        if states is None or not states.takes(z):
            return self.full(index, params)
        return states.run(z)


def _thread_states(task: StatesTask, index: int, params):
    """This thread's :class:`_States` of ``task`` (made from row ``index`` on first use; None: the full path)."""
    kept = getattr(_STATES, "by_token", None)
    if kept is None or task.token not in kept:
        try:
            states = _States.of(task, index, params)
        except ScenarioError:
            return None  # this state is refused (the full path says so): the next state prepares them
        _STATES.by_token = kept = {task.token: states}  # one Monte Carlo at a time per thread: the last one's dropped
    return kept[task.token]


class _States:
    """One validated scenario and its simulation, run again from each state's z0."""

    def __init__(self, sc, sim):
        self.sc, self.sim = sc, sim
        self.r = sim.plant.r

    @classmethod
    def of(cls, task: StatesTask, index: int, params):
        """The prepared states of ``task`` (row ``index`` validated as the full path would; ScenarioError where
        that row is refused), or None where they must take the full path (see StatesTask)."""
        from ftstab_mj.plants import make_plant
        from ftstab_mj.scenario.plugins import ensure
        from ftstab_mj.simulation.run_loop import Simulation

        sc = task.full.scenario(index, params)  # ScenarioError: this state is refused
        ref = getattr(sc.loops[0], "reference", None)
        if len(sc.loops) != 1 or sc.loops[0].name != task.loop or (ref is not None and not ref.constant):
            return None
        ensure(sc)
        s = sc.sim
        sim = Simulation(make_plant(sc.plant.model, sc.plant.params), sc.loops, period=s.period,
                         physics_step=s.physics_step, integrator=s.integrator, divergence_limit=s.divergence_limit)
        if sim.run_info().kernel != "native":
            sim.release()
            return None
        return cls(sc, sim)

    def takes(self, z) -> bool:
        """Whether z0 passes the checks the scenario file's loader makes of it (r finite numbers, |z0_i| <= 1e9):
        the only field that changes from state to state."""
        return (isinstance(z, (list, tuple)) and len(z) == self.r
                and all(isinstance(x, float) and math.isfinite(x) and abs(x) <= MAX_STATE for x in z))

    def run(self, z) -> dict:
        """The row of the state z0 = ``z``: ``ScenarioTask``'s result with the guarantee's metrics only."""
        from ftstab_mj.metrics.run_metrics import GUARANTEE_METRICS
        from ftstab_mj.scenario.run import record
        from ftstab_mj.simulation.run_loop import Run

        sim, s = self.sim, self.sc.sim
        sim.reset([z])
        # the whole run as one batch up to BATCH_SAMPLES (the samples and metrics do not depend on the batches:
        # fewer batches, less of the per-batch work in Python)
        run = Run(sim, s.duration, batch_size=BATCH_SAMPLES, metric_settings=self.sc.metrics)
        result, metrics = record(run, (), metrics=True, selection=GUARANTEE_METRICS)
        if result.status == INTERRUPTED:  # as ScenarioTask: not a result of this row, stop the Monte Carlo
            raise KeyboardInterrupt
        return {"status": result.status, "error": "" if result.status == COMPLETED else result.message,
                "metrics": metrics}

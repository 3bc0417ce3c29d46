"""Turn a validated :class:`Scenario` into a plant and control loops, and run it with ftstab_mj.simulation.run_loop.

``run_scenario(scenario, sinks)`` is the one way a scenario is run: ``ftstab run`` calls it with
the log sinks, ``ftstab replay --verify`` with the scenario read back from a log
(``run_scenario_dict``). Same scenario, same seed: bit-identical samples.
"""

from __future__ import annotations

from pathlib import Path

import sys
import time
from dataclasses import dataclass

from ftstab_mj.simulation import interrupts
from ftstab_mj.config.errors import LogWriteError
from ftstab_mj.simulation.records import FAILED, INTERRUPTED
from ftstab_mj.scenario.loader import scenario_from_dict, scenario_to_dict
from ftstab_mj.scenario.schema import Scenario


@dataclass
class ScenarioRun:
    """A finished run: the scenario, the sim's RunResult (status, message, info, and the samples when
    kept) and the metrics handed to the sinks (ftstab_mj.metrics.run_metrics.MetricsStream of the batches)."""

    scenario: Scenario
    result: object  # ftstab_mj.simulation.run_loop.RunResult
    metrics: dict


def record(run, sinks=(), metrics: bool = False, progress=None, selection: tuple | None = None):
    """Drive ``run`` (a ftstab_mj.simulation.run_loop.Run) to its end with every sink observing it: open with
    run.info, write each batch, then close with the status and, with ``metrics``, the metrics streamed
    from the batches (ftstab_mj.metrics.run_metrics.MetricsStream; {} without). Returns (RunResult, metrics dict).
    With ``metrics`` the loops' certificates are computed first, before any sink is opened
    (metrics.run_certificates; progress(text) now and then while one is computed). ``selection``: only
    those metrics of each loop (MetricsStream's; a Monte Carlo keeps run_metrics.GUARANTEE_METRICS).

    A signal (Ctrl-C, SIGTERM, SIGHUP: ftstab_mj.simulation.interrupts) ends the run "interrupted" (the
    samples of the batch cut short are written, metrics computed, sinks closed). It never cuts the
    logs: opening them, handing a batch to them all (and keeping it for the metrics), and closing
    them are each done whole (interrupts.critical), and once the run is over (or stopping) later
    signals wait until the logs are closed. So the logs hold the same samples, and their metrics
    are those of the samples. Any other exception (the controller's CallbackError, a sink's
    LogWriteError) closes the sinks "failed" after writing what was recorded, and is re-raised.
    """
    from ftstab_mj.metrics.run_metrics import MetricsStream, run_certificates

    if metrics:  # before any log is opened (inside interrupts.critical() a signal would wait for it)
        run_certificates(run.info, progress)
    stream = MetricsStream(run.info, run.n_total, selection) if metrics else None
    opened = []

    def emit(batch):  # in the run's critical block: the stream and the logs get each batch whole
        if stream is not None and len(batch):
            stream.update(batch.loops)
        _write(opened, batch)

    with interrupts.run_scope():
        try:
            with interrupts.critical():  # every log opened, or none of them
                for sink in sinks:
                    sink.open(run.info)
                    opened.append(sink)
            with run.sim.installed():
                while not run.finished:
                    run.step(emit)
            interrupts.hold()  # the run is over: from here a signal waits until the logs are closed
        except KeyboardInterrupt as exc:
            run.interrupted(interrupts.interruption(exc), emit)
        except BaseException as exc:  # keep the samples, close, re-raise
            interrupts.hold()
            message = str(exc) if isinstance(exc, LogWriteError) else f"{type(exc).__name__}: {exc}"
            healthy = [s for s in opened if not (isinstance(exc, LogWriteError) and getattr(s, "path", None) == exc.path)]
            try:
                _write(healthy, run.stop(FAILED, message), quiet=True)
            finally:
                _close(opened, FAILED, {}, message, quiet=True)
            raise
        result = run.result()
        try:
            final = stream.result(result.status) if stream else {}
        except BaseException as exc:  # the logs must still end with a status, never without /metrics
            _close(opened, FAILED, {}, f"metrics could not be computed: {type(exc).__name__}: {exc}", quiet=True)
            raise
        _close(opened, result.status, final, result.message)
    return result, final


def _write(sinks, batch, quiet: bool = False) -> None:
    """Hand a batch to every sink; a signal meanwhile is raised once all have it (interrupts.critical:
    a SIGHUP in the middle of the MCAP write left a summary counting a batch the file lacked).
    quiet (the run is already failing): a sink that fails is passed over, the others still get it."""
    if len(batch):
        with interrupts.critical():
            for sink in sinks:
                try:
                    sink.write(batch)
                except Exception:  # noqa: BLE001 - quiet: the run's own error is the one reported
                    if not quiet:
                        raise


def _close(sinks, status, metrics, message, quiet: bool = False) -> None:
    """Close every sink (a signal meanwhile is held); the first error raised by a close is re-raised
    after all are closed (quiet: not at all, the run's own error being the one reported)."""
    first = None
    with interrupts.critical():
        for sink in sinks:
            try:
                sink.close(status, metrics, message)
            except Exception as exc:  # noqa: BLE001 - keep closing the others
                first = first or exc
    if first is not None and not quiet:
        raise first


def run_scenario(sc: Scenario, sinks=(), keep_samples: bool = False, batch_size: int = 1000,
                 progress=None) -> ScenarioRun:
    """Run the scenario; every sink observes it and is closed with the metrics (streamed: memory
    does not grow with the run). keep_samples: also keep every sample in ``result`` (RunResult.loops).
    batch_size: samples handed to the sinks at once (smaller for a run paced to the clock; the
    samples do not depend on it). progress(text): a status line while a loop's certificate is
    computed, before the first sample (``ftstab run`` shows it on a terminal).

    Raises ftstab_mj.config.errors.CallbackError when the controller raised (sinks closed as "failed").
    """
    from ftstab_mj.plants import make_plant
    from ftstab_mj.scenario.plugins import ensure
    from ftstab_mj.simulation.run_loop import Run, Simulation

    ensure(sc)  # a scenario received whole (a Dask worker) brings its plugins' laws and plants here
    s = sc.sim
    sim = Simulation(make_plant(sc.plant.model, sc.plant.params), sc.loops, period=s.period,
                     physics_step=s.physics_step, integrator=s.integrator, divergence_limit=s.divergence_limit)
    run = Run(sim, s.duration, batch_size, scenario_dict=scenario_to_dict(sc), metric_settings=sc.metrics,
              keep_samples=keep_samples)
    result, metrics = record(run, sinks, metrics=True, progress=progress)
    sim.release()  # its MjData serves the next run of this model (a sweep's next row)
    return ScenarioRun(sc, result, metrics)


def run_scenario_dict(raw: dict, sinks=(), source: str = "<recorded scenario>", keep_samples: bool = False) -> ScenarioRun:
    """Validate a resolved scenario dict (e.g. a log's /scenario message) and run it."""
    return run_scenario(scenario_from_dict(raw, source), sinks, keep_samples)


def verify_log(log):
    """``ftstab replay --verify``: re-run the scenario recorded in ``log`` (a logs.reader.LogData) and
    compare it with the log bit for bit (a logs.verify.Verification)."""
    from ftstab_mj.config.errors import LogError
    from ftstab_mj.simulation.interrupts import Interrupted, last_signal
    from ftstab_mj.logs.verify import StreamingComparison, rerun_scenario
    from ftstab_mj.logs.scene import check_untrusted_model
    from ftstab_mj.plants import PLANTS
    from ftstab_mj.plants.user import recorded_model
    from ftstab_mj.scenario.plugins import load_entry_points, load_plugins

    scenario = rerun_scenario(log)
    # the plugins the log pins (by absolute path and sha256) register their laws and plants first
    load_entry_points()
    if scenario.get("plugins"):
        load_plugins(scenario["plugins"], Path.cwd(), lambda key, expected, found: LogError(
            f"{log.path}: /scenario {key}: expected {expected}, found {found}"))
    plant = scenario.get("plant")
    model = plant.get("model") if isinstance(plant, dict) else None
    user_model = isinstance(model, str) and model.endswith(".xml") and bool(log.info.model_xml)
    comparison = StreamingComparison(log)  # the re-run compared batch by batch with the log read as it streams
    try:
        if user_model:  # a user model is re-run from the XML the log holds, never from the file it names
            check_untrusted_model(log.info.model_xml, f"{log.path}: /run_info model_xml")
            with recorded_model(model, log.info.model_xml):
                rerun = run_scenario_dict(scenario, sinks=(comparison,), source=f"{log.path} /scenario").result
        elif model not in PLANTS:  # a log is untrusted: re-running it must not read a local file it names
            raise LogError(f"{log.path}: /scenario plant.model: --verify re-runs the registered plants, or a user "
                           f"model from the XML its log holds ({', '.join(PLANTS)}), found {str(model)[:80]!r}; "
                           "re-run that scenario with ftstab run")
        else:
            rerun = run_scenario_dict(scenario, sinks=(comparison,), source=f"{log.path} /scenario").result
        if rerun.status == INTERRUPTED:  # stopped by a signal: nothing to compare (not a difference)
            raise last_signal() or Interrupted()
        return comparison.verification(rerun)
    finally:
        comparison.release()


class ProgressSink:
    """A sink that shows how far a run is, on a terminal, once it has lasted more than ``after`` s.

    Writes ``name: t = 3.20 / 10.00 s (32%)`` over itself (carriage return) at most every 0.2 s of
    wall time. Silent when the stream is not a terminal (logs and pipes stay clean).
    """

    def __init__(self, name: str, duration: float, stream=None, after: float = 0.5):
        self.name, self.duration, self.after = name, float(duration), after
        self.stream = stream if stream is not None else sys.stderr
        self._shown = False

    def open(self, info) -> None:
        self._start = self._last = time.monotonic()

    def write(self, batch) -> None:
        now = time.monotonic()
        if now - self._start < self.after or now - self._last < 0.2 or not self.stream.isatty():
            return
        self._last = now
        t = float(next(iter(batch.loops.values()))["t"][-1])
        self.stream.write(f"\r{self.name}: t = {t:.2f} / {self.duration:.2f} s ({100 * t / self.duration:3.0f}%)")
        self.stream.flush()
        self._shown = True

    def close(self, status: str, metrics: dict, message: str = "") -> None:
        if self._shown:
            self.stream.write("\n")
            self.stream.flush()

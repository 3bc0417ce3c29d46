"""Turn a validated :class:`Scenario` into a plant and control loops, and run it with ftstab_mj.sim.

``run_scenario(scenario, sinks)`` is the one way a scenario is run: ``ftstab run`` calls it with
the log sinks, ``ftstab replay --verify`` with the scenario read back from a log
(``run_scenario_dict``). Same scenario, same seed: bit-identical samples.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass

from ftstab_mj.scenario.loader import scenario_from_dict, scenario_to_dict
from ftstab_mj.scenario.schema import Scenario


@dataclass
class ScenarioRun:
    """A finished run: the scenario, the sim's RunResult (status, message, info, samples) and the
    metrics handed to the sinks (ftstab_mj.metrics.compute_metrics of the samples)."""

    scenario: Scenario
    result: object  # ftstab_mj.sim.RunResult
    metrics: dict


def run_scenario(sc: Scenario, sinks=()) -> ScenarioRun:
    """Run the scenario; every sink observes it and is closed with the metrics.

    Raises ftstab_mj.errors.CallbackError when the controller raised (sinks closed as "failed").
    """
    from ftstab_mj.metrics import compute_metrics
    from ftstab_mj.plants import make_plant
    from ftstab_mj.sim import simulate

    plant = make_plant(sc.plant.model, sc.plant.params)
    computed = {}

    def metrics(info, samples, status):  # computed once, for the sinks and for the caller
        computed["metrics"] = compute_metrics(info, samples, status)
        return computed["metrics"]

    result = simulate(plant, sc.loops, duration=sc.sim.duration, period=sc.sim.period,
                      physics_step=sc.sim.physics_step, integrator=sc.sim.integrator, sinks=tuple(sinks),
                      divergence_limit=sc.sim.divergence_limit, scenario_dict=scenario_to_dict(sc),
                      metric_settings=sc.metrics, metrics=metrics)
    return ScenarioRun(sc, result, computed["metrics"])


def run_scenario_dict(raw: dict, sinks=(), source: str = "<recorded scenario>") -> ScenarioRun:
    """Validate a resolved scenario dict (e.g. a log's /scenario message) and run it."""
    return run_scenario(scenario_from_dict(raw, source), sinks)


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

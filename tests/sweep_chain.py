"""Sweep tasks for the tests of the sweep engine: one on the ideal chain (no MuJoCo, no scenario file), and
a scenario row task that refuses to validate a row itself.

Parameters (key paths of the rows): ``r`` (2 or 3), ``period`` (s), ``amplitude`` (of a sine
phi, chain units), ``k`` (Hong's degree; k > 0 is rejected by HongController: a failing row).
Picklable, importable by worker processes (the tests run from the repository root).
"""

import os
from dataclasses import dataclass, fields

import numpy as np

from ftstab_mj.control import HongController, RobustLaw
from ftstab_mj.plants.disturbances import Signal
from ftstab_mj.simulation.ideal_chain import simulate_chain
from ftstab_mj.studies.sweep.row import ScenarioTask

GAINS = {2: (1.0, 2.0), 3: (1.0, 1.7, 5.0)}
DEGREE = {2: -0.2, 3: -0.1}


@dataclass(frozen=True)
class ChainTask:
    duration: float = 1.0  # s of simulated time

    def __call__(self, index, params) -> dict:
        p = dict(params)
        r = int(p.get("r", 2))
        law = RobustLaw(HongController(r, p.get("k", DEGREE[r]), GAINS[r]), phibar=1.0, gamma_m=1.0)
        z0 = np.zeros(r)
        z0[0] = 0.5
        run = simulate_chain(law, z0, p.get("period", 1e-2), self.duration,
                             phi=Signal("sine", amplitude=p.get("amplitude", 0.5), freq=1.0))
        tail = run.z[int(0.8 * len(run.t)):, 0]
        return {"status": "completed", "error": "",
                "metrics": {"final_abs_z1": float(np.max(np.abs(tail))), "V1_final": float(run.V1[-1]),
                            "z_final": [float(x) for x in run.z_final]}}


@dataclass(frozen=True)
class WhereTask(ChainTask):
    """A :class:`ChainTask` whose metrics also say which process ran the row (``pid``)."""

    def __call__(self, index, params) -> dict:
        out = super().__call__(index, params)
        out["metrics"]["pid"] = os.getpid()
        return out


@dataclass(frozen=True)
class NoValidationTask(ScenarioTask):
    """A :class:`ScenarioTask` whose rows fail if it validates one itself: where it runs, it runs only the
    scenarios prepare() validated in the parent (inherited by a fork, or carried with the chunk)."""

    @classmethod
    def of(cls, task: ScenarioTask) -> "NoValidationTask":
        return cls(**{f.name: getattr(task, f.name) for f in fields(task)})

    def scenario(self, index, params):
        raise AssertionError(f"row {index} validated again in process {os.getpid()}")


@dataclass(frozen=True)
class StopOnceTask(ChainTask):
    """A :class:`ChainTask` whose row ``row`` sends ``signal`` (SIGSTOP: a worker stopped mid-sweep; SIGKILL: one
    that dies) to its own process the first time it runs anywhere (``marker``, a file it creates, says it
    did); run again, that row runs as ChainTask's."""

    row: int = 3
    signal: str = "SIGSTOP"
    marker: str = ""

    def __call__(self, index, params) -> dict:
        import signal

        if index == self.row:
            try:
                os.close(os.open(self.marker, os.O_CREAT | os.O_EXCL))
            except FileExistsError:
                pass
            else:
                os.kill(os.getpid(), getattr(signal, self.signal))
        return super().__call__(index, params)


@dataclass(frozen=True)
class KillAlwaysTask(ChainTask):
    """A :class:`ChainTask` whose row ``row`` sends ``signal`` to its own process (SIGKILL: a row that crashes its
    worker; SIGSTOP: one that stops it) every time it runs, after adding a line to ``marker`` (so the file counts
    how often it ran)."""

    row: int = 3
    marker: str = ""
    signal: str = "SIGKILL"

    def __call__(self, index, params) -> dict:
        import signal

        if index == self.row:
            with open(self.marker, "a") as f:
                f.write(f"{os.getpid()}\n")
            os.kill(os.getpid(), getattr(signal, self.signal))
        return super().__call__(index, params)


@dataclass(frozen=True)
class WhereScenarioTask(ScenarioTask):
    """A :class:`ScenarioTask` whose metrics also say which process ran the row (``pid``)."""

    def __call__(self, index, params) -> dict:
        out = super().__call__(index, params)
        out["metrics"] = dict(out["metrics"], pid=os.getpid())
        return out

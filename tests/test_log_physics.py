"""Logs of real MuJoCo runs: samples consistent with the physics, every way a run can end leaves a log."""

import json
from dataclasses import dataclass

import numpy as np
import pytest

from conftest import record_run, run_cli
from ftstab_mj.control import HongController, NominalLaw, RobustLaw
from ftstab_mj.plants.disturbances import Signal
from ftstab_mj.config.errors import CallbackError
from ftstab_mj.logs import McapSink, RerunSink
from ftstab_mj.logs.reader import read_log
from ftstab_mj.plants import make_plant
from ftstab_mj.simulation.records import DIVERGED, FAILED, INTERRUPTED
from ftstab_mj.scenario import LoopSpec

HONG = HongController(2, -0.2, (1.0, 2.0))


def test_logged_cart_samples_match_the_chain_dynamics(tmp_path):
    # Euler, u held over the period h = N dt, phi and gamma held per physics step:
    #   z_r(k+1) - z_r(k) = sum_s dt (phi(t_k + s dt) + gamma(t_k + s dt) u_k)
    # so it differs from h (phi_k + gamma_k u_k) by at most (h^2 / 2) (L_phi + |u_k| L_gamma), L the
    # Lipschitz constants of the sines (2 pi f A), plus rounding.
    h, dt = 0.005, 0.001
    phi = Signal("sine", amplitude=0.8, freq=0.5)
    gamma = Signal("sine", offset=1.0, amplitude=0.4, freq=0.3, phase=1.0)
    loops = [LoopSpec("cart", controller=RobustLaw(HONG, phibar=1.0, gamma_m=0.5), disturbance=phi, gain=gamma, z0=(1.0, 0.0))]
    path = tmp_path / "cart.mcap"
    record_run(make_plant("cart", {"mass": 2.0}), loops, duration=3.0, period=h, physics_step=dt,
               sinks=[McapSink(path)], batch_size=200, metrics=True)
    a = read_log(path).loops["cart"]
    assert len(a["t"]) == 600
    # the robust law's estimates are its constants (laws.py: same meaning for every law)
    assert np.all(a["phi_hat"] == 1.0 / 0.5) and np.all(a["gamma_hat"] == 1.0 / 0.5)
    dzr = np.diff(a["z"][:, 1])
    predicted = h * (a["phi"] + a["gamma"] * a["u"])[:-1]
    L_phi, L_gamma = 2 * np.pi * 0.5 * 0.8, 2 * np.pi * 0.3 * 0.4
    tol = h * h / 2 * (L_phi + np.abs(a["u"][:-1]) * L_gamma) + 1e-12
    err = np.abs(dzr - predicted)
    assert np.all(err <= tol), float(np.max(err / tol))
    assert np.max(err) > 0.05 * np.max(tol)  # the bound is of the right order, not vacuous


def _run(tmp_path, loops, duration=1.0, **kw):
    mcap, rrd = tmp_path / "run.mcap", tmp_path / "run.rrd"
    result = record_run(make_plant("cart"), loops, duration=duration, period=0.01, physics_step=0.01,
                        sinks=[McapSink(mcap), RerunSink(rrd)], batch_size=20, metrics=True, **kw)
    return result, mcap, rrd


def _replay(mcap):
    res = run_cli("replay", mcap, "--json")
    assert res.returncode == 0, res.stderr
    return json.loads(res.stdout)


def test_diverged_run_leaves_a_complete_log_that_says_so(tmp_path):
    # A constant push of 50 m/s^2 against the nominal law leaves |z| <= 3 (divergence limit) fast.
    loops = [LoopSpec("cart", controller=NominalLaw(HONG), disturbance=Signal("constant", 50.0), z0=(1.0, 0.0))]
    result, mcap, _ = _run(tmp_path, loops, divergence_limit=3.0)
    assert result.status == DIVERGED
    log = read_log(mcap)
    assert log.complete and log.recorded["status"] == DIVERGED and "divergence limit" in log.recorded["message"]
    assert log.n_samples == result.n_samples < 100
    assert _replay(mcap) == log.recorded["metrics"]


@dataclass(frozen=True)
class _CtrlC:
    """A sink that raises KeyboardInterrupt (as Ctrl-C does) on its third batch."""

    calls: list

    def open(self, info):
        pass

    def write(self, batch):
        self.calls.append(len(batch))
        if len(self.calls) == 3:
            raise KeyboardInterrupt

    def close(self, status, metrics, message=""):
        self.calls.append(status)


def test_interrupted_run_is_finalized_with_its_status(tmp_path):
    loops = [LoopSpec("cart", controller=NominalLaw(HONG), z0=(1.0, 0.0))]
    calls = []
    mcap = tmp_path / "run.mcap"
    result = record_run(make_plant("cart"), loops, duration=1.0, period=0.01, physics_step=0.01,
                        sinks=[McapSink(mcap), _CtrlC(calls)], batch_size=20, metrics=True)
    assert result.status == INTERRUPTED and calls[-1] == INTERRUPTED
    log = read_log(mcap)
    assert log.complete and log.recorded["status"] == INTERRUPTED and log.n_samples == 60
    assert _replay(mcap) == log.recorded["metrics"]


@dataclass(frozen=True)
class _Broken(NominalLaw):
    """Hong's law that raises once |x| < 0.95 m (a bug in a user's controller)."""

    def evaluate(self, z, state):
        if abs(z[0]) < 0.95:
            raise ZeroDivisionError("bug in the controller")
        return super().evaluate(z, state)


def test_failed_run_leaves_a_readable_log_with_status_failed(tmp_path):
    loops = [LoopSpec("cart", controller=_Broken(HONG), z0=(1.0, 0.0))]
    with pytest.raises(CallbackError):
        _run(tmp_path, loops)
    mcap = tmp_path / "run.mcap"
    log = read_log(mcap)
    assert log.complete and log.recorded["status"] == FAILED and "bug in the controller" in log.recorded["message"]
    assert log.n_samples > 0 and np.all(np.abs(log.loops["cart"]["z"][:, 0]) >= 0.95)
    res = run_cli("replay", mcap)
    assert res.returncode == 0 and "recorded metrics: none (run failed" in res.stdout
    assert _replay(mcap)["status"] == FAILED
    assert res.stdout.splitlines()[1].startswith(f"status {FAILED},")

"""The chattering indices of metrics.py on signals whose value is known in closed form."""

import numpy as np
import pytest

from ftstab_mj.metrics.run_metrics import band_rms, chattering, compute_metrics, du_dt_variance, zero_crossing_rate
from ftstab_mj.simulation.records import COMPLETED, LOOP_FIELDS, LoopInfo, MetricSettings, RunInfo
from synthetic_runs import HONG2


def test_alternating_control_indices():
    """u = a (-1)^k, m samples of period h: du/dt alternates +-d, d = 2a/h, over m - 1 (odd) steps, so
    its mean is d/(m-1) and its variance d^2 (1 - 1/(m-1)^2); m - 1 sign changes; the whole signal
    sits at the Nyquist frequency 1/(2h) with RMS a."""
    m, h, a = 200, 1e-3, 0.5
    u = a * (-1.0) ** np.arange(m)
    assert chattering(u, h) == pytest.approx((m - 1) * 2 * a / (m * h), rel=1e-12)
    assert du_dt_variance(u, h) == pytest.approx((2 * a / h) ** 2 * (1 - 1 / (m - 1) ** 2), rel=1e-12)
    assert zero_crossing_rate(u, h) == pytest.approx((m - 1) / (m * h), rel=1e-12)
    assert band_rms(u, h, (10.0, 1000.0)) == pytest.approx(a, rel=1e-12)  # Nyquist 500 Hz is inside
    assert band_rms(u, h, (10.0, 400.0)) == pytest.approx(0.0, abs=1e-12)


def test_band_rms_of_sinusoids_is_their_rms_inside_the_band_only():
    """A sinusoid of amplitude A at a bin frequency has RMS A / sqrt(2); two in different bands separate."""
    m, h = 1000, 1e-3  # 1 s window: bins every 1 Hz
    t = np.arange(m) * h
    u = 0.7 + 2.0 * np.sin(2 * np.pi * 3.0 * t) + 0.3 * np.cos(2 * np.pi * 120.0 * t + 0.4)
    assert band_rms(u, h, (10.0, 1000.0)) == pytest.approx(0.3 / np.sqrt(2), rel=1e-10)
    assert band_rms(u, h, (0.0, 10.0)) == pytest.approx(2.0 / np.sqrt(2), rel=1e-10)  # the mean is never counted
    assert band_rms(u, h, (0.0, 500.0)) == pytest.approx(np.sqrt(2.0 ** 2 + 0.3 ** 2) / np.sqrt(2), rel=1e-10)


def test_smooth_and_constant_controls():
    h = 1e-3
    t = np.arange(1000) * h
    ramp = 3.0 * t - 1.0
    assert du_dt_variance(ramp, h) == pytest.approx(0.0, abs=1e-9)
    assert zero_crossing_rate(ramp, h) == pytest.approx(1.0 / (1000 * h))  # one sign change in 1 s
    assert zero_crossing_rate(np.array([1.0, 0.0, -1.0, 0.0, 0.0, -2.0]), h) == pytest.approx(1 / (6 * h))
    assert du_dt_variance(np.array([1.0]), h) == 0.0 and band_rms(np.array([1.0]), h, (0, 10)) == 0.0


def test_indices_are_in_the_run_metrics_with_the_scenario_band():
    n, h, a = 100, 0.01, 0.5  # Nyquist 50 Hz
    info = RunInfo(scenario={}, loops=(LoopInfo("a", 2, "nominal", dict(HONG2), {}, 0.0, 1.0, 1.0),), period=h,
                   physics_step=h, metric_settings=MetricSettings(chatter_band=(1.0, 20.0)))
    arrays = {f: np.zeros(n) for f in LOOP_FIELDS}
    arrays.update(t=np.arange(n) * h, z=np.zeros((n, 2)), u=a * (-1.0) ** np.arange(n))
    m = compute_metrics(info, {"a": arrays}, COMPLETED)["loops"]["a"]
    assert m["chattering_zero_crossings"] == pytest.approx(19 / (20 * h))
    assert m["chattering_du_dt_var"] == pytest.approx((2 * a / h) ** 2 * (1 - 1 / 19 ** 2))  # 20 samples
    assert m["chattering_band_rms"] == pytest.approx(0.0, abs=1e-12)  # all of it at 50 Hz, outside (1, 20)
    assert RunInfo.from_dict(info.to_dict()) == info  # the band survives the log's JSON round trip


def test_settle_time_z1_is_the_settle_time_of_abs_z1():
    n, h = 100, 0.01
    z = np.zeros((n, 2))
    z[:, 0] = np.where(np.arange(n) < 37, 0.5, 2e-4)
    z[50, 0] = -2e-3  # one excursion beyond 1 mm (the default settle_z1)
    info = RunInfo(scenario={}, loops=(LoopInfo("a", 2, "nominal", dict(HONG2), {}, 0.0, 1.0, 1.0),), period=h,
                   physics_step=h)
    arrays = {f: np.zeros(n) for f in LOOP_FIELDS}
    arrays.update(t=np.arange(n) * h, z=z)
    assert compute_metrics(info, {"a": arrays}, COMPLETED)["loops"]["a"]["settle_time_z1"] == pytest.approx(0.51)

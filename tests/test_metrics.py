"""Metrics: definitions on hand-made arrays, and the paper's guarantees on runs of the ideal chain."""

import json

import numpy as np
import pytest

from ftstab_mj.control import HongController, certify, theorem3_bounds
from ftstab_mj.plants.disturbances import Signal
from ftstab_mj.metrics.run_metrics import bound_applies, compute_metrics, format_table
from metrics_reference import settle_time
from ftstab_mj.simulation.records import COMPLETED, DIVERGED, LOOP_FIELDS, LoopInfo, MetricSettings, RunInfo
from synthetic_runs import ADAPTIVE, HONG2, synthetic_run


def _info(law="nominal", period=0.01, settings=MetricSettings()):
    loop = LoopInfo("a", 2, law, dict(HONG2), {}, 0.0, 1.0, 1.0)
    return RunInfo(scenario={}, loops=(loop,), period=period, physics_step=period, metric_settings=settings)


def _arrays(n, period=0.01, **given):
    a = {f: np.zeros(n) for f in LOOP_FIELDS}
    a["t"] = np.arange(n) * period
    a["z"] = np.zeros((n, 2))
    a.update(given)
    return a


def test_settle_time_is_first_sample_after_the_last_one_above_the_level():
    t = np.arange(6) * 0.5
    assert settle_time(t, np.array([1, 0.5, 1e-5, 2e-4, 1e-5, 1e-6]), 1e-4) == 2.0
    assert settle_time(t, np.array([1e-6] * 6), 1e-4) == 0.0  # never above
    assert settle_time(t, np.array([1, 1e-5, 1e-5, 1e-5, 1e-5, 2e-4]), 1e-4) is None  # above at the end
    assert settle_time(t, np.array([1, 1e-5, 1e-5, np.nan, 1e-5, 1e-5]), 1e-4) == 2.0  # NaN counts as above


def test_effort_and_chattering_of_an_alternating_control():
    n, h, a = 100, 0.01, 0.5
    u = a * (-1.0) ** np.arange(n)
    m = compute_metrics(_info(period=h), {"a": _arrays(n, h, u=u)}, COMPLETED)["loops"]["a"]
    assert m["effort_abs"] == pytest.approx(a * n * h, rel=1e-12)
    assert m["effort_sq"] == pytest.approx(a * a * n * h, rel=1e-12)
    assert m["u_max_abs"] == a
    # final window: the last 20 % = 20 samples, 19 jumps of 2a, over 20 h seconds
    assert m["final_window_start"] == pytest.approx(0.8 * n * h)
    assert m["chattering"] == pytest.approx(19 * 2 * a / (20 * h), rel=1e-12)


def test_final_accuracy_is_the_max_over_the_final_window_only():
    n, h = 100, 0.01
    z = np.zeros((n, 2))
    z[:80] = 10.0  # outside the final window: ignored
    z[80:, 0] = np.linspace(-3e-3, 1e-3, 20)
    z[80:, 1] = 2e-2 * (-1.0) ** np.arange(20)
    m = compute_metrics(_info(period=h), {"a": _arrays(n, h, z=z)}, COMPLETED)["loops"]["a"]
    assert m["final_abs_z_max"] == [pytest.approx(3e-3), pytest.approx(2e-2)]


def test_nominal_run_settles_before_theorem1_bound():
    # Theorem 1: the unperturbed chain reaches the origin before V1(z0)^(1-a)/(c(1-a)); the sampled
    # run (h = 1 ms) must settle to V1 <= 1e-4 before that bound.
    info, loops, _, _ = synthetic_run("nominal", z0=(1.0, -0.5), duration=7.0, with_model=False)
    m = compute_metrics(info, loops, COMPLETED)["loops"]["cart"]
    cert = certify(HongController(**HONG2))
    assert m["time_bound"] == pytest.approx(cert.time_bound(m["V1_initial"]), rel=1e-12)
    assert m["bound_applies"] is True
    assert m["settle_time"] is not None and m["settle_time"] <= m["time_bound"] < 7.0
    assert m["beat_bound"] is True


def test_bound_applies_only_when_the_robust_assumptions_cover_the_true_bounds():
    robust = {"phibar": 0.5, "gamma_m": 0.8}

    def loop(law, params, phibar, g_m, g_M):
        return LoopInfo("a", 2, law, dict(HONG2), params, phibar, g_m, g_M)

    assert bound_applies(loop("robust", robust, 0.5, 0.8, 2.0))
    assert not bound_applies(loop("robust", robust, 0.6, 0.8, 2.0))
    assert not bound_applies(loop("robust", robust, 0.5, 0.7, 2.0))
    assert bound_applies(loop("nominal", {}, 0.0, 1.0, 1.0))
    assert not bound_applies(loop("nominal", {}, 0.1, 1.0, 1.0))
    assert not bound_applies(loop("adaptive", ADAPTIVE, 0.0, 1.0, 1.0))


def test_adaptive_run_respects_theorem3_bounds():
    # Theorem 3 with the true bounds (|phi| <= 0.5, gamma in [0.8, 1.2]): limsup V1 <= Delta,
    # liminf V1 <= eps, limsup phi_hat <= the bound. 12 s is long enough for V1 to enter the eps-ball.
    phi = Signal("sine", amplitude=0.5, freq=0.5)
    gamma = Signal("sine", offset=1.0, amplitude=0.2, freq=0.3)
    info, loops, _, _ = synthetic_run("adaptive", phi=phi, gamma=gamma, duration=12.0, with_model=False)
    m = compute_metrics(info, loops, COMPLETED)["loops"]["cart"]
    th = m["theorem3"]
    b = theorem3_bounds(certify(HongController(**HONG2)), 0.5, 0.8, **{k: ADAPTIVE[k] for k in
                                                                       ("kappa", "delta", "rate", "eps")})
    assert (th["Phibar"], th["Delta"], th["phi_hat_limsup"]) == (b.Phibar, b.Delta, b.phi_hat_limsup)
    assert th["Delta_held"] and th["phi_hat_bound_held"] and th["eps_reached"]
    assert m["eps_entry_time"] is not None and m["V1_max_after_entry"] <= b.Delta
    assert m["phi_hat_max"] >= m["phi_hat_final"] >= 0.0
    assert m["bound_applies"] is False and m["beat_bound"] is None


def test_nonfinite_samples_count_as_nan_and_metrics_stay_json():
    # The MCAP log stores non-finite floats as null, read back as NaN: live (inf) and replay (NaN)
    # must give the same metrics, and the dict must be strict JSON.
    n = 50
    u = np.linspace(1, 2, n)
    V1 = np.linspace(1, 0, n)
    live = _arrays(n, u=u.copy(), V1=V1.copy())
    live["u"][-1], live["V1"][-1] = np.inf, -np.inf
    replay = _arrays(n, u=u.copy(), V1=V1.copy())
    replay["u"][-1], replay["V1"][-1] = np.nan, np.nan
    m_live = compute_metrics(_info(), {"a": live}, DIVERGED)
    assert m_live == compute_metrics(_info(), {"a": replay}, DIVERGED)
    text = json.dumps(m_live, allow_nan=False)
    assert json.loads(text) == m_live
    assert m_live["status"] == DIVERGED and m_live["loops"]["a"]["settle_time"] is None


def test_format_table_shows_every_loop_metric():
    info, loops, _, _ = synthetic_run("adaptive", duration=1.0, with_model=False)
    m = compute_metrics(info, loops, COMPLETED)
    text = format_table(m)
    assert text.splitlines()[0].startswith("status completed, 1000 samples")
    for key in m["loops"]["cart"]:
        if key not in ("theorem3", "law"):
            assert key in text
    assert "Delta_held" in text


def test_the_workspace_check_reads_every_bound_the_plant_states():
    """A plant whose guarantee needs |z_4| and |z_5| bounded (the flexible joint at r = 5) states them;
    leaving either is named, so the time bound is not claimed for such a run."""
    from types import SimpleNamespace

    from ftstab_mj.metrics.run_metrics import workspace_left

    ws = {"z1_min": -1.0, "z1_max": 1.0, "z2_abs_max": 1.0, "z3_abs_max": 1.0, "z4_abs_max": 1.0,
          "z5_abs_max": 1.0, "u_abs_max": 10.0}
    loop = SimpleNamespace(workspace=ws)
    z = np.zeros((3, 5))
    assert workspace_left(loop, z, np.zeros(3)) == ""
    z[1, 3], z[2, 4] = 2.0, -3.0
    assert workspace_left(loop, z, np.zeros(3)) == "|z_4| reached 2 > 1; |z_5| reached 3 > 1"
    del ws["z4_abs_max"]  # a bound the plant does not state is not checked
    assert workspace_left(loop, z, np.zeros(3)) == "|z_5| reached 3 > 1"

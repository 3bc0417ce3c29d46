"""The loop stages on their own (ftstab_mj/loop_stages): Levant's differentiator against its accuracy
theory on a known signal, the sensor and actuator models against their definitions.

Differentiator tolerance. The fitted exponents are asserted within 0.1 of the theory. The exponents
that must be told apart differ by 1 (sampling: tau^(n-i+1)) or by 1/(n+1) >= 1/3 (noise:
eps^((n-i+1)/(n+1)), n <= 2), so 0.1 identifies the exponent; what moves a fit away from it is
the other error term (sampling at the smallest noise, rounding at the smallest tau) and, with
random noise, the spread of a sampled maximum. Measured: noise-free slopes within 0.05 of
n-i+1 for n = 1..3 (both variants); noisy slopes 0.92/0.46 (n = 1), 0.95/0.64/0.31 (n = 2).
"""

import math

import numpy as np
import pytest

from ftstab_mj.config.errors import ParameterError
from ftstab_mj.simulation.stages import ActuatorModel, LevantDifferentiator, SensorModel
from ftstab_mj.simulation.stages.differentiator import nonrecursive_lambdas

L = 2.0  # f = sin t: |f^(n+1)| <= 1 < L


def differentiate(D, taus, eps, T, seed=0):
    """Run D on f = sin(t) + eps * U(-1, 1) sampled at each tau (one run per tau, all the eps of a
    run batched along a leading axis); max |z_i - f^(i)| over the second half of [0, T], shape
    (len(taus) * len(eps), n + 1), tau-major."""
    n, eps = D.order, np.atleast_1d(np.asarray(eps, dtype=float))
    errs = []
    for tau in np.atleast_1d(taus):
        K = int(round(T / tau))
        t = np.arange(K) * tau
        y = np.sin(t)[:, None] + eps * np.random.default_rng(seed).uniform(-1.0, 1.0, (K, len(eps)))
        s = D.initial_state(y[0])
        est = np.empty((K, len(eps), n + 1))
        for k in range(K):
            est[k] = D.estimate(s)
            s = D.step(s, y[k], tau)
        true = np.stack([np.sin(t + i * np.pi / 2) for i in range(n + 1)], axis=1)[:, None, :]
        tail = t >= T / 2
        errs.append(np.max(np.abs(est[tail] - true[tail]), axis=0))
    return np.concatenate(errs)


def slopes(x, errs):
    return np.array([np.polyfit(np.log(x), np.log(errs[:, i]), 1)[0] for i in range(errs.shape[1])])


def test_nonrecursive_coefficients_are_the_recursive_ones_substituted():
    # n = 2 and 3 as tabulated in the literature for the non-recursive form (1.1, 2.12, 2) and (1.1, 3.06, 4.16, 3)
    assert np.allclose(nonrecursive_lambdas((1.1, 1.5, 2.0)), (1.1, 1.5 * math.sqrt(2.0), 2.0))
    assert np.allclose(nonrecursive_lambdas((1.1, 1.5, 2.0, 3.0)), (1.1, 3.06, 4.16, 3.0), atol=5e-3)


@pytest.mark.parametrize("n,filter_order", [(1, 0), (2, 0), (3, 0), (2, 1)])
def test_noise_free_error_of_the_ith_derivative_scales_as_tau_to_the_n_minus_i_plus_1(n, filter_order):
    taus = 1e-3 * 2.0 ** np.arange(4)
    errs = differentiate(LevantDifferentiator(n, L, filter_order), taus, 0.0, T=20.0)
    fitted = slopes(taus, errs)
    assert np.all(np.abs(fitted - np.arange(n + 1, 0, -1)) < 0.1), fitted


@pytest.mark.parametrize("n", [1, 2])
def test_error_with_noise_scales_as_eps_to_the_n_minus_i_plus_1_over_n_plus_1(n):
    # tau small enough that the sampling term L tau^(n+1) is far below the smallest eps
    eps = 10.0 ** np.arange(-4.0, 1.0)
    errs = differentiate(LevantDifferentiator(n, L), 2.5e-4, eps, T=10.0)
    fitted = slopes(eps, errs)
    theory = np.arange(n + 1, 0, -1) / (n + 1)
    assert np.all(np.abs(fitted - theory) < 0.1), fitted


def test_filtering_variant_averages_sampled_noise_out_where_the_plain_one_cannot():
    # Levant & Livne 2020: the filtering differentiator's error is driven by the noise's local
    # average, which for independent samples shrinks as the sampling gets faster; the plain
    # differentiator's error is set by the noise amplitude whatever the sampling.
    errs = {}
    for nf in (0, 1):
        errs[nf] = differentiate(LevantDifferentiator(1, L, nf), [1e-3, 2.5e-4], 0.1, T=10.0)
    plain, filt = errs[0], errs[1]
    assert np.all(filt[1] < 0.9 * filt[0])  # faster sampling: filtered error down (measured 0.58, 0.84)
    assert np.all(np.abs(plain[1] / plain[0] - 1.0) < 0.1)  # plain: unchanged (measured within 3 %)
    assert np.all(filt < plain)


def test_differentiator_rejects_bad_parameters():
    for args in [(-1, 1.0), (2.5, 1.0), (2, 0.0), (2, math.inf), (3, 1.0, 3), (True, 1.0)]:
        with pytest.raises(ParameterError):
            LevantDifferentiator(*args)


# -- sensor --------------------------------------------------------------------------------------

def test_ideal_sensor_reads_the_state_bit_for_bit():
    s = SensorModel()
    z = np.array([0.123456789, -9.87654321e-7])
    assert s.ideal and s.reading(z, 17).tobytes() == z.tobytes()


def test_sensor_noise_is_a_pure_function_of_seed_stream_and_sample():
    s = SensorModel(measured="position", noise=(0.01,), seed=3)
    z = np.zeros(2)
    a = [s.reading(z, k)[0] for k in range(5000)]
    # read again out of order (as after a restore) and through a fresh model: the same numbers
    b = [SensorModel(measured="position", noise=(0.01,), seed=3).reading(z, k)[0] for k in range(4999, -1, -1)][::-1]
    assert a == b
    assert max(map(abs, a)) <= 0.01 and min(a) < -0.0099 and max(a) > 0.0099  # uniform on [-a, a]
    assert s.reading(z, 10, stream=1)[0] != s.reading(z, 10, stream=0)[0]  # loops draw independently
    g = [SensorModel(measured="position", noise=(0.01,), noise_kind="gaussian").reading(z, k)[0] for k in range(20000)]
    assert abs(np.std(g) / 0.01 - 1.0) < 0.03  # std 1 +- 3 sigma of the estimate (1/sqrt(2 * 20000) ~ 0.5 %)


def test_quantization_rounds_to_the_nearest_count_per_channel():
    s = SensorModel(quantum=(0.01, 0.0))
    y = s.reading(np.array([0.01234, 0.01234]), 0)
    assert y[0] == pytest.approx(0.01) and y[1] == 0.01234
    assert s.reading(np.array([-0.0151, 1.0]), 0)[0] == pytest.approx(-0.02)


def test_delay_returns_the_reading_taken_d_samples_earlier():
    s = SensorModel(delay=3)
    readings = [np.array([float(k), -float(k)]) for k in range(10)]
    line = s.initial_state(readings[0])
    got = []
    for y in readings:
        out, line = s.delayed(line, y)
        got.append(out)
    assert np.array_equal(np.array(got)[3:], np.array(readings)[:-3])
    assert np.array_equal(np.array(got)[:3], np.array(readings[:1] * 3))  # the first reading until then


def test_sensor_rejects_bad_parameters_and_mismatched_channels():
    for kw in [dict(measured="velocity"), dict(noise_kind="pink"), dict(noise=(-1.0,)), dict(delay=1.5),
               dict(delay=-1), dict(quantum=(math.nan,))]:
        with pytest.raises(ParameterError):
            SensorModel(**kw)
    with pytest.raises(ParameterError, match="sensor.noise"):
        SensorModel(noise=(0.1,)).check(2)
    SensorModel(measured="position", noise=(0.1,)).check(3)


# -- actuator ------------------------------------------------------------------------------------

def test_default_actuator_is_the_identity_bit_for_bit():
    a = ActuatorModel()
    u = 0.1234567890123
    uc = a.command(u, a.initial_state(), 0.01)
    steps, state = a.steps(uc, a.initial_state(), 0.001, 10)
    assert a.ideal and uc == u and np.all(steps == u)


def test_saturation_dead_zone_and_rate_limit():
    a = ActuatorModel(u_max=2.0, dead_zone=0.5)
    st = a.initial_state()
    assert a.command(0.4, st, 0.01) == 0.0 and a.command(-1.5, st, 0.01) == -1.0 and a.command(9.0, st, 0.01) == 2.0
    assert bool(a.saturated(2.6)) and not bool(a.saturated(2.4))
    r = ActuatorModel(rate_max=10.0)  # 0.1 per period of 0.01 s
    st, got = r.initial_state(), []
    for _ in range(5):
        uc = r.command(1.0, st, 0.01)
        _, st = r.steps(uc, st, 0.001, 10)
        got.append(uc)
    assert np.allclose(got, [0.1, 0.2, 0.3, 0.4, 0.5])


def test_lag_is_the_exact_first_order_response_to_a_held_command_averaged_over_each_step():
    tau, h = 0.05, 0.001
    a = ActuatorModel(tau=tau)
    st = a.initial_state()
    values = []
    for _ in range(20):  # a unit step held for 20 periods of 10 steps of 1 ms
        steps, st = a.steps(1.0, st, h, 10)
        values.append(steps)
    t = np.arange(201) * h
    # mean over [t_j, t_j + h] of 1 - exp(-t / tau), from the integral of the exact response
    integral = t + tau * np.exp(-t / tau)
    assert np.allclose(np.concatenate(values), np.diff(integral) / h, rtol=0, atol=1e-12)
    assert st[1] == pytest.approx(1.0 - math.exp(-0.2 / tau), abs=1e-14)
    # a lag much shorter than the step is (to rounding) no lag at all
    assert np.allclose(ActuatorModel(tau=1e-9).steps(0.7, np.zeros(2), h, 3)[0], 0.7, rtol=0, atol=1e-6)


def test_second_order_lag_is_two_exact_lags_in_cascade_averaged_over_each_step():
    # unit step into 1/(tau s + 1)^2: x(t) = 1 - (1 + t/tau) exp(-t/tau), integral t - 2 tau + (t + 2 tau) exp(-t/tau)
    tau, h = 0.02, 0.001
    a = ActuatorModel(tau=tau, lag_order=2)
    st, values = a.initial_state(), []
    for _ in range(30):
        steps, st = a.steps(1.0, st, h, 10)
        values.append(steps)
    t = np.arange(301) * h
    integral = t - 2 * tau + (t + 2 * tau) * np.exp(-t / tau)
    assert np.allclose(np.concatenate(values), np.diff(integral) / h, rtol=0, atol=1e-12)
    assert st[2] == pytest.approx(1.0 - (1.0 + 0.3 / tau) * math.exp(-0.3 / tau), abs=1e-13)


def test_actuator_rejects_bad_parameters():
    for kw in [dict(u_max=0.0), dict(u_max=-1.0), dict(rate_max=math.nan), dict(tau=-0.1), dict(tau=math.inf),
               dict(dead_zone=True), dict(tau=0.1, lag_order=3)]:
        with pytest.raises(ParameterError):
            ActuatorModel(**kw)

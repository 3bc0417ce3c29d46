"""The describing-function prediction of chattering (control/describing.py) against closed forms and
against the measured limit cycle (metrics/oscillation.py) on the cart with a lagged actuator."""

import math
import warnings

import numpy as np
import pytest

from ftstab_mj import api
from ftstab_mj.control.describing import describing_function, harmonic_balance
from ftstab_mj.control.law import law_class
from ftstab_mj.metrics.oscillation import oscillation


def _law(name, **values):
    cls = law_class(name)
    params = {p.name: p.default for p in cls.all_params() if not p.required}
    params.update(values)
    return cls.from_params(2, params)


def test_twisting_describing_function_and_limit_cycles_match_their_closed_forms():
    # N = -4 (r1 + j r2) / (pi a); with 1/(tau s + 1)^n the phase condition n atan(w tau) = atan(r2 / r1)
    # gives w, and a = 4 |r1 + j r2| |G(jw)| / (pi w^2) (harmonic balance on 1 / s^2)
    tw = _law("twisting", r1=5.0, r2=3.0)
    N = describing_function(tw, 0.1, 10.0)
    assert N == pytest.approx(-4 * (5 + 3j) / (math.pi * 0.1), rel=2e-3)  # O(1 / 256) quadrature
    tau = 0.02
    for n in (1, 2):
        w = math.tan(math.atan(3 / 5) / n) / tau
        a = 4 * math.hypot(5, 3) * (1 + (w * tau) ** 2) ** (-n / 2) / (math.pi * w * w)
        lc = harmonic_balance(tw, tau, n)
        assert lc.frequency == pytest.approx(w / (2 * math.pi), rel=1e-3)
        assert lc.amplitude_z1 == pytest.approx(a, rel=2e-3)


def test_super_twisting_describing_function_matches_boiko_fridman():
    # on s = A sin: N_s = 1.1128 k1 / sqrt(A) - j 4 k2 / (pi A w) (Boiko & Fridman 2005; 1.1128 =
    # (4 / pi) int_0^(pi/2) sin^(3/2)); the law adds -c z_2 and acts on s = z_2 + c z_1 = (c + j w) z_1
    # (the state v run along the harmonic: the stateful path of describing_function)
    st = _law("super_twisting", surface=(3.0,), k1=2.0, k2=5.0)
    a, w, c = 1e-3, 40.0, 3.0
    A = abs(c + 1j * w) * a
    N_s = 2.0 * 1.1128 / math.sqrt(A) - 1j * 4 * 5.0 / (math.pi * A * w)
    expected = -c * 1j * w - N_s * (c + 1j * w)
    # first order in 1 / 128 samples per period: v's explicit step lags it by half a sample (pi / 128 = 2.5 %)
    assert describing_function(st, a, w) == pytest.approx(expected, rel=math.pi / 128)


def test_oscillation_of_a_sinusoid_and_a_square_wave():
    h = 1e-3
    t = np.arange(20000) * h
    rng = np.random.default_rng(0)
    x = 0.3 + 2e-3 * np.sin(2 * np.pi * 7.3 * t) + 1e-5 * rng.standard_normal(len(t))
    o = oscillation(x, h)
    assert o["frequency"] == pytest.approx(7.3, rel=2e-3) and o["amplitude"] == pytest.approx(2e-3, rel=2e-2)
    sq = 4.0 * np.sign(np.sin(2 * np.pi * 11.0 * t + 0.1))
    o = oscillation(sq, h)
    assert o["frequency"] == pytest.approx(11.0, rel=2e-3) and o["amplitude"] == pytest.approx(4.0)
    assert oscillation(np.full(100, 1.0), h)["frequency"] is None
    # a slow motion 5x larger under the oscillation: about the mean it is taken for the signal; about
    # the moving average over one cycle it leaves 0.01 (1 - sinc(pi 0.5 / 14)) = 2.1e-5, 1 % of it
    fast = 2e-3 * np.sin(2 * np.pi * 14.0 * t)
    slow = 0.01 * np.sin(2 * np.pi * 0.5 * t)
    assert oscillation(fast + slow, h)["frequency"] == pytest.approx(0.5, rel=0.05)
    o = oscillation(fast + slow, h, cycle=1 / 14.0)
    assert o["frequency"] == pytest.approx(14.0, rel=2e-3) and o["amplitude"] == pytest.approx(2e-3, rel=2e-2)



def test_an_oscillation_whose_square_overflows_is_not_measured_and_warns_nothing():
    """A diverged run's u (finite, ~1e300): its RMS is beyond the largest float, so no band [-H, H]
    exists to cross; None (as for a non-finite signal), and no NumPy overflow warning on stderr."""
    t = np.arange(4000) * 1e-3
    x = 1e300 * np.sin(2 * np.pi * 7.3 * t)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any RuntimeWarning fails the test
        assert oscillation(x, 1e-3) == {"amplitude": None, "frequency": None}
    assert oscillation(1e-150 * x, 1e-3)["frequency"] == pytest.approx(7.3, rel=2e-3)  # 1e150: squares fit


def test_oscillation_amplitude_is_the_median_half_peak_to_peak_of_its_cycles():
    # an independent reference: the median over the cycles between successive upward crossings of
    # (max - min) / 2, cycle by cycle in Python; cycles of unequal amplitude, so the median picks one
    h = 1e-3
    t = np.arange(6000) * h
    x = (1.0 + 0.5 * np.sin(2 * np.pi * 0.3 * t)) * np.sin(2 * np.pi * 9.0 * t)
    y = x - np.mean(x)
    H = 0.25 * math.sqrt(float(np.dot(y, y)) / len(y))
    idx = np.flatnonzero((y > H) | (y < -H))
    high = y[idx] > H
    up = idx[1:][high[1:] & ~high[:-1]]
    ref = np.median([0.5 * (y[i:j].max() - y[i:j].min()) for i, j in zip(up[:-1], up[1:])])
    assert len(up) > 40 and oscillation(x, h)["amplitude"] == ref


def test_the_amplitude_s_median_is_numpy_s_bit_for_bit():
    """oscillation's median (partition, not np.median's generic path) equals np.median bit for bit on
    odd and even lengths, signed zeros, infinities, NaN and magnitudes from subnormal to 1e308."""
    import warnings

    from ftstab_mj.metrics.oscillation import _median

    rng = np.random.default_rng(7)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # np.median's warning on NaN
        for n in [*range(1, 40), 1000, 1001]:
            for _ in range(40):
                x = rng.standard_normal(n) * 10.0 ** rng.uniform(-320, 308)
                u = rng.random()
                if u < 0.3:
                    x = np.round(x, 1)  # ties and signed zeros
                elif u < 0.45:
                    x[rng.random(n) < 0.5] = rng.choice([0.0, -0.0, np.inf, -np.inf, np.nan])
                assert np.float64(_median(x)).tobytes() == np.float64(np.median(x)).tobytes(), x


CASES = {  # law / actuator pairs: the chattering of each is a DF limit cycle (docs/chattering.md)
    "twisting, one 20 ms lag": {"loops.cart.controller": {"law": "twisting", "r1": 5.0, "r2": 3.0},
                                "loops.cart.actuator.tau": 0.02, "loops.cart.actuator.lag_order": 1},
    "robust, two 10 ms lags": {"loops.cart.actuator.tau": 0.01, "loops.cart.actuator.lag_order": 2},
    "super-twisting, two 10 ms lags": {"loops.cart.controller": {"law": "super_twisting", "surface": [3.0], "L": 8.0},
                                       "loops.cart.actuator.tau": 0.01, "loops.cart.actuator.lag_order": 2},
}


@pytest.mark.parametrize("case", list(CASES))
def test_measured_limit_cycle_within_20_percent_of_the_describing_function(case):
    # the cart without disturbance and with gamma = 1, as the harmonic balance assumes; 6 s: the
    # final window (the last 20 %) holds tens of cycles after the transient from x = 1 m
    over = {"loops.cart.disturbance.amplitude": 0.0, "loops.cart.gain.amplitude": 0.0, "sim.duration": 6.0,
            **CASES[case]}
    m = api.run("cart_r2_actuator_lag", overrides=over, keep_samples=False).metrics["loops"]["cart"]
    pred = m["limit_cycle_predicted"]
    assert pred is not None
    assert m["z1_osc_frequency"] == pytest.approx(pred["frequency"], rel=0.2)
    assert m["z1_osc_amplitude"] == pytest.approx(pred["amplitude_z1"], rel=0.2)
    assert m["u_osc_frequency"] == pytest.approx(m["z1_osc_frequency"], rel=0.02)  # one oscillation
    # the averaged power of the first harmonic, A^2 w / pi, within the same 20 % (squared: 44 %)
    ap = pred["amplitude_z1"] ** 2 * 2 * pred["frequency"]
    assert m["averaged_power"] == pytest.approx(ap, rel=0.44)


def test_compare_draws_the_prediction_beside_the_measurement(tmp_path):
    from ftstab_mj.figures.compare_report import draw_figures, limit_cycle_figure

    rows = [{"label": "robust", "status": "completed", "final_abs_z1": 1e-4, "final_abs_z2": 1e-2,
             "z1_osc_amplitude": 1.9e-4, "z1_osc_frequency": 14.3, "df_z1_amplitude": 1.93e-4, "df_frequency": 14.2},
            {"label": "linear", "status": "completed", "final_abs_z1": 1e-6, "final_abs_z2": 1e-6,
             "z1_osc_amplitude": None, "z1_osc_frequency": None, "df_z1_amplitude": None, "df_frequency": None}]
    fig = limit_cycle_figure("c", rows)
    (ax_a, ax_f) = fig.axes
    assert [tuple(line.get_xydata()[0]) for line in ax_a.lines[:1]] == [(1.93e-4, 1.9e-4)]  # x predicted, y measured
    assert [tuple(line.get_xydata()[0]) for line in ax_f.lines[:1]] == [(14.2, 14.3)]
    paths = draw_figures("c", rows, None, [], {}, tmp_path)
    assert [p.name for p in paths] == ["c_limit_cycle.png"]
    assert limit_cycle_figure("c", rows[1:]) is None  # no loop with a lag: no figure

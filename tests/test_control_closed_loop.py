"""The laws in closed loop on the exact ideal chain (issue "Controller core", tests of sections 4-6)."""

from math import factorial

import numpy as np
import pytest

from ftstab_mj.control import (AdaptiveLaw, HongController, NominalLaw, RobustLaw, advance_phi_hat, certify,
                               theorem3_bounds)
from ftstab_mj.plants.disturbances import Signal
from ftstab_mj.config.errors import ParameterError
from ftstab_mj.control.chain import chain_transition
from ftstab_mj.simulation.ideal_chain import simulate_chain

CERTIFIED = {2: (-0.2, (1.0, 2.0)), 3: (-0.1, (1.0, 1.7, 5.0))}  # the certificate's reference table


def hong(r):
    k, gains = CERTIFIED[r]
    return HongController(r, k, gains)


# --- the ideal chain itself -------------------------------------------------------------------

@pytest.mark.parametrize("r", [1, 2, 3, 5])
def test_chain_transition_is_exact(r):
    """Phi(h) is the flow of the chain: Phi(a) Phi(b) = Phi(a + b), and from rest under a constant
    input w, z_i(t) = w t^(r-i+1) / (r-i+1)! exactly (a polynomial, so no step-size error)."""
    Pa, _ = chain_transition(r, 0.3)
    Pb, _ = chain_transition(r, 0.45)
    Pab, _ = chain_transition(r, 0.75)
    np.testing.assert_allclose(Pa @ Pb, Pab, rtol=1e-14, atol=1e-15)
    w, h, n = 1.7, 0.01, 250
    Phi, G = chain_transition(r, h)
    z = np.zeros(r)
    for _ in range(n):
        z = Phi @ z + G * w
    t = n * h
    np.testing.assert_allclose(z, [w * t ** (r - i) / factorial(r - i) for i in range(r)], rtol=1e-10)


def test_simulate_chain_batch_equals_single_runs():
    law = RobustLaw(hong(2), 0.5, 0.8)
    z0 = np.array([[1.0, 0.0], [-0.3, 0.7], [0.0, -2.0]])
    batch = simulate_chain(law, z0, 1e-2, 2.0, Signal("sine", 0.0, 0.5, freq=1.0), Signal("constant", 1.0))
    for i in range(3):
        one = simulate_chain(law, z0[i], 1e-2, 2.0, Signal("sine", 0.0, 0.5, freq=1.0), Signal("constant", 1.0))
        np.testing.assert_allclose(batch.z[:, i], one.z, rtol=1e-12, atol=1e-14)


def test_same_inputs_bit_identical():
    law = AdaptiveLaw(hong(2), 1.0, 0.5, 2.0, 0.5, 0.05)
    args = (law, np.array([1.0, 0.0]), 1e-3, 1.0, Signal("random", 0.0, 1.0, freq=5.0, seed=3))
    a, b = simulate_chain(*args), simulate_chain(*args)
    assert np.array_equal(a.z, b.z) and np.array_equal(a.phi_hat, b.phi_hat)


# --- nominal: finite time, within the certificate's bound --------------------------------------

@pytest.mark.parametrize("r", [2, 3])
def test_nominal_settles_before_certificate_bound(r):
    """phi = 0, gamma = 1: V1 reaches ~0 and the measured settling time is below T(z0) of Theorem 1."""
    h = hong(r)
    cert = certify(h)
    assert cert.certified
    z0 = np.zeros(r)
    z0[0] = 1.0
    T_bound = cert.time_bound(h.V1(z0))
    run = simulate_chain(NominalLaw(h), z0, 1e-3, 1.5 * T_bound)
    settled = run.V1 <= 1e-10
    assert settled[-1], f"V1 did not reach ~0: final {run.V1[-1]:.3g}"
    t_settle = run.t[np.nonzero(~settled)[0][-1] + 1]
    assert t_settle < T_bound, f"settled at {t_settle:.3f} s, bound {T_bound:.3f} s"
    # Along the trajectory, the comparison lemma behind T(z0): dV1/dt <= -c V1^alpha integrates to
    # V1(t)^(1-alpha) <= V1(0)^(1-alpha) - c (1-alpha) t (an exponential decay would violate it).
    # Slack 1e-3: the control is held over each 1 ms period, so the sampled law lags the continuous one.
    a = cert.alpha
    lhs = run.V1 ** (1 - a) + cert.c * (1 - a) * np.minimum(run.t, t_settle)
    assert np.all(lhs <= h.V1(z0) ** (1 - a) + 1e-3), f"max excess {np.max(lhs - h.V1(z0) ** (1 - a)):.3g}"


# --- robust: neighbourhood shrinking with the control period ------------------------------------

ROBUST_CASES = {
    "sine": (Signal("sine", 0.0, 1.0, freq=1.3), Signal("sine", 1.0, 0.5, freq=0.7)),
    "steps": (Signal("step", -0.5, 1.0, t_step=2.0), Signal("step", 0.5, 1.0, t_step=3.0)),
    "worst_case_gamma_max": (Signal("worst_case", 0.0, 1.0), Signal("constant", 1.5)),
}
PERIODS = (2e-3, 1e-3, 5e-4)


@pytest.mark.parametrize("case", sorted(ROBUST_CASES))
@pytest.mark.parametrize("r", [2, 3])
def test_robust_neighbourhood_shrinks_with_period(r, case):
    """|phi| <= 1, gamma in [0.5, 1.5]; robust law with phibar = 1, gamma_m = 0.5.

    Expected order: the discontinuous term makes z_r' jump by O(phibar + gamma_M |u|) inside each
    held period, so z_r chatters with an amplitude proportional to the period: slope 1 on a log-log
    plot of max |z_r| (final window) against the period. The lower integrators are integrals of
    z_r and shrink at least as fast (slope >= 1 up to the non-asymptotic spread measured here:
    0.97 to 2.4 over these cases). Asserted: z_r slope within 1 +- 0.1, z_1 slope >= 0.9, and
    the neighbourhood at the smallest period is small.
    """
    phi, gamma = ROBUST_CASES[case]
    law = RobustLaw(hong(r), phibar=1.0, gamma_m=0.5)
    T = 8.0 if r == 2 else 12.0
    z0 = np.zeros(r)
    z0[0] = 1.0
    acc = []
    for period in PERIODS:
        run = simulate_chain(law, z0, period, T, phi, gamma)
        assert np.all(np.abs(run.phi) <= 1.0) and np.all((run.gamma >= 0.5) & (run.gamma <= 1.5))
        acc.append(np.abs(run.z[run.t >= T - 2.0]).max(axis=0))
    acc = np.array(acc)
    slope = [np.polyfit(np.log(PERIODS), np.log(acc[:, i]), 1)[0] for i in range(r)]
    assert 0.9 <= slope[-1] <= 1.1, f"z_r slope {slope[-1]:.3f}, accuracies {acc[:, -1]}"
    assert slope[0] >= 0.9, f"z_1 slope {slope[0]:.3f}, accuracies {acc[:, 0]}"
    assert acc[-1, 0] < 1e-4 and acc[-1, -1] < 5e-3


@pytest.mark.parametrize("r", [2, 3])
def test_robust_at_its_bounds_under_worst_case_is_the_nominal_chain(r):
    """gamma = gamma_m and phi = phibar sign(dV1/dz_r): since sign(u0) = -sign(dV1/dz_r) (Hong's law
    opposes the gradient), gamma u + phi = u0 + phibar sign(u0) - phibar sign(u0) = u0 exactly, so the run is
    the nominal law on the unperturbed chain, sample for sample, up to floating-point rounding."""
    z0 = np.zeros(r)
    z0[0] = 1.0
    T = 6.0 if r == 2 else 10.0
    robust = simulate_chain(RobustLaw(hong(r), phibar=1.0, gamma_m=0.5), z0, 1e-3, T,
                            Signal("worst_case", 0.0, 1.0), Signal("constant", 0.5))
    nominal = simulate_chain(NominalLaw(hong(r)), z0, 1e-3, T)
    np.testing.assert_allclose(robust.z, nominal.z, rtol=0, atol=1e-9)
    assert np.all(robust.phi * robust.dV1_dzr >= 0)  # the worst case pushes V1 up


# --- adaptive: Theorem 3 ------------------------------------------------------------------------

@pytest.mark.parametrize("r, params", [
    (2, dict(kappa=1.0, delta=0.5, rate=2.0, eta=0.5, eps=0.05)),
    (2, dict(kappa=1.0, delta=0.2, rate=1.0, eta=0.5, eps=0.01)),
    (3, dict(kappa=1.0, delta=0.2, rate=1.0, eta=0.5, eps=0.01)),
])
def test_adaptive_theorem3(r, params):
    """Bounds unknown to the controller (true phibar = 1, gamma in [0.5, 1.5]): V1 enters the
    eps-ball, keeps coming back to it (liminf V1 <= eps), stays below Delta after the first entry
    (limsup V1 <= Delta), phi_hat stays within Theorem 3's limsup bound and never goes negative."""
    h = hong(r)
    law = AdaptiveLaw(h, **params)
    phi, gamma = Signal("sine", 0.0, 1.0, freq=0.5), Signal("sine", 1.0, 0.5, freq=0.3)
    z0 = np.zeros(r)
    z0[0] = 1.0
    run = simulate_chain(law, z0, 1e-3, 30.0, phi, gamma)
    b = theorem3_bounds(certify(h), phibar=1.0, gamma_m=0.5, kappa=params["kappa"], delta=params["delta"],
                        rate=params["rate"], eps=params["eps"])
    inside = run.V1 <= params["eps"]
    assert inside.any(), "V1 never entered the eps-ball"
    first = int(np.argmax(inside))
    assert run.V1[run.t >= 20.0].min() <= params["eps"]  # still visits the ball late in the run
    assert run.V1[first:].max() <= b.Delta
    assert run.phi_hat.min() >= 0.0
    assert run.phi_hat.max() <= b.phi_hat_limsup
    if params["eps"] == 0.01:  # small eps: the disturbance pushes V1 out and phi_hat brings it back
        entries = int(np.sum(inside[1:] & ~inside[:-1]))
        assert entries >= 3, f"only {entries} entries into the eps-ball"


def test_adaptation_is_what_keeps_V1_in_the_eps_ball():
    """Control experiment for the test above: the same law with adaptation switched off (rate
    1e-9, phi_hat stays ~0) against rate 1. Over the last 10 s, adaptation keeps V1 inside the
    eps-ball most of the time and lowers its peaks (measured: 69 % vs 29 % of the time, max V1
    0.072 vs 0.099); asserted with margins: > 60 % vs < 40 %, and a lower maximum."""
    h = hong(2)
    late = {}
    for rate in (1e-9, 1.0):
        law = AdaptiveLaw(h, kappa=1.0, delta=0.2, rate=rate, eta=0.5, eps=0.01)
        run = simulate_chain(law, np.array([1.0, 0.0]), 1e-3, 30.0, Signal("sine", 0.0, 1.0, freq=0.5),
                             Signal("sine", 1.0, 0.5, freq=0.3))
        late[rate] = run.V1[run.t >= 20.0]
    inside = {rate: float(np.mean(v <= 0.01)) for rate, v in late.items()}
    assert inside[1.0] > 0.6 and inside[1e-9] < 0.4, inside
    assert late[1.0].max() < late[1e-9].max()


# --- phi_hat integration -------------------------------------------------------------------------

def test_advance_phi_hat_exact_cases():
    law = AdaptiveLaw(hong(2), kappa=1.0, delta=0.5, rate=2.0, eta=0.5, eps=0.1)
    # V1 >= eps: nu = 1, a ramp at `rate`.
    assert advance_phi_hat(law, 0.2, 1.0, 0.01) == pytest.approx(1.02, rel=1e-15)
    # V1 <= eps/2: nu = 0, phi' = -phi^eta reaches 0 at t* = phi0^(1-eta)/(1-eta) = 2 for phi0 = 1.
    phi, t, h = 1.0, 0.0, 1e-3
    while phi > 0.0:
        phi = advance_phi_hat(law, 0.01, phi, h)
        t += h
    assert t == pytest.approx(2.0, abs=1.5 * h)
    assert phi == 0.0  # exactly zero, never negative (a naive Euler step chatters below 0)


def test_advance_phi_hat_transition_band_matches_fine_reference():
    law = AdaptiveLaw(hong(2), kappa=1.0, delta=0.5, rate=2.0, eta=0.5, eps=0.1)
    V1 = np.array([0.06, 0.075, 0.09])  # 0 < nu < 1
    phi0 = np.array([0.0, 0.5, 3.0])
    got = advance_phi_hat(law, V1, phi0, 0.01)
    ref = phi0.copy()
    for _ in range(100_000):  # explicit Euler, 1e-7 s steps: error ~1e-7
        ref = ref + 1e-7 * law.phi_hat_rate(V1, ref)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-6)


def test_nonadaptive_laws_have_constant_estimates():
    h = hong(2)
    out = RobustLaw(h, 0.8, 0.5).output(np.array([0.3, -0.1]))
    assert out.gamma_hat == 2.0 and out.phi_hat == pytest.approx(1.6)
    assert out.u == pytest.approx(2.0 * out.u0 + 1.6 * np.sign(out.u0))
    assert NominalLaw(h).output(np.array([0.3, -0.1])).u == h.u0(np.array([0.3, -0.1]))


@pytest.mark.parametrize("make, name", [
    (lambda h: RobustLaw(h, -1.0, 0.5), "phibar"),
    (lambda h: RobustLaw(h, 1.0, 0.0), "gamma_m"),
    (lambda h: AdaptiveLaw(h, 0.0, 0.5, 1.0, 0.5, 0.1), "kappa"),
    (lambda h: AdaptiveLaw(h, 1.0, -0.5, 1.0, 0.5, 0.1), "delta"),
    (lambda h: AdaptiveLaw(h, 1.0, 0.5, 0.0, 0.5, 0.1), "rate"),
    (lambda h: AdaptiveLaw(h, 1.0, 0.5, 1.0, 1.0, 0.1), "eta"),
    (lambda h: AdaptiveLaw(h, 1.0, 0.5, 1.0, 0.0, 0.1), "eta"),
    (lambda h: AdaptiveLaw(h, 1.0, 0.5, 1.0, 0.5, -0.1), "eps"),
])
def test_law_parameter_validation(make, name):
    with pytest.raises(ParameterError) as err:
        make(hong(2))
    assert err.value.name == name

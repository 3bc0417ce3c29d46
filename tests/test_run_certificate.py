"""The certificate a run uses: its guaranteed T(z0) (outward rounded), its work limit, its pins."""

import mpmath as mp
import numpy as np
import pytest

from ftstab_mj.control import HongController, certify
from ftstab_mj.control.certificate import CERTIFIED, Certificate, V1_enclosure


def _certified(k: float, c: float) -> Certificate:
    """A certified full-form Certificate with c_lower = c for the homogeneity degree k."""
    return Certificate(form="full", c=c, alpha=(2.0 + 2.0 * k) / (2.0 + k), c_prime=None, alpha_prime=None,
                       certified=True, samples=100, seed=0, status=CERTIFIED, c_lower=c, c_upper=c, k=k)


def test_the_time_bound_is_above_the_exact_formula_and_the_float_one_is_not():
    """T = V^(1-alpha) / (c (1-alpha)) with alpha = (2+2k)/(2+k) for the float k taken exactly,
    against mpmath at 60 digits: Certificate.time_bound is never below it and within 1e-13 of it
    (outward rounding costs a few ulps: 1 - alpha is enclosed from the rational k, the power has a
    16-ulp margin plus 746 times the exponent's width); the plain float formula falls below the exact
    value in some of these cases, so it is not a guaranteed bound."""
    mp.mp.dps = 60
    rng = np.random.default_rng(5)
    ks = np.concatenate([[-0.2, -0.1, -0.05, -0.02, -0.01, -1e-3, -1e-6, -0.3, -0.45], -rng.uniform(1e-4, 0.16, 40)])
    cs = [0.0175, 0.6104035660530578, 1.3265, 4.5, 1e-3] + list(rng.uniform(1e-3, 10.0, 10))
    Vs = np.concatenate([[1e-8, 0.3, 1.0, 14.499456786671667, 1e6], 10.0 ** rng.uniform(-6, 6, 10)])
    below_float = 0
    worst = 0.0
    for k in ks:
        for c in cs:
            cert = _certified(float(k), float(c))
            T = cert.time_bound(Vs)
            kk = mp.mpf(float(k))
            oma = 1 - (2 + 2 * kk) / (2 + kk)
            for V, t in zip(Vs, T):
                exact = mp.power(mp.mpf(float(V)), oma) / (mp.mpf(float(c)) * oma)
                assert t >= exact, (k, c, V, t, exact)
                worst = max(worst, float((t - exact) / exact))
                a = cert.alpha
                below_float += float(V) ** (1.0 - a) / (c * (1.0 - a)) < exact
    assert worst < 1e-13, worst
    assert below_float > 0, "the float formula was never below the exact value: the test shows nothing"


def test_the_time_bound_of_an_enclosure_bounds_every_value_in_it():
    cert = _certified(-0.05, 0.61)
    from ftstab_mj.control.interval import Iv

    T = cert.time_bound(Iv(np.array([2.0]), np.array([3.0])))
    assert T[0] >= cert.time_bound(3.0) > cert.time_bound(2.0)
    assert cert.time_bound(np.array([1.0, 2.0])).shape == (2,) and isinstance(cert.time_bound(1.0), float)
    not_certified = Certificate(form="full", c=-1.0, alpha=cert.alpha, c_prime=None, alpha_prime=None,
                                certified=False, samples=100, seed=0, status="not certified", k=-0.05)
    assert not_certified.time_bound(1.0) == np.inf
    assert _certified(0.0, 1.0).time_bound(1.0) == np.inf  # k = 0: exponential, not finite-time


@pytest.mark.parametrize("r, k, gains", [(1, -0.3, (2.0,)), (2, -0.2, (1.0, 2.0)), (3, -0.1, (1.0, 1.7, 5.0)),
                                          (4, -0.05, (0.82723, 1.5168, 3.1113, 100.0)),
                                          (5, -0.01, (0.65, 1.2, 1.62, 12.63, 1000.0))])
def test_the_v1_enclosure_holds_the_controllers_v1_and_is_tight(r, k, gains):
    """V1_enclosure (the recursion of hong_terms in intervals) against HongController.V1 (the textbook
    chain, floats: an independent implementation): it holds it at 2000 states, among them states with
    zero components (where rebuilding z from s would be Hoelder-loose), and is within 1e-10 relative."""
    h = HongController(r, k, gains)
    z = np.random.default_rng(r).uniform(-1.0, 1.0, size=(2000, r)) * 10.0 ** np.random.default_rng(r).uniform(-3, 1, (2000, 1))
    z[:10, 1:] = 0.0
    z[10:20, 0] = 0.0
    E = V1_enclosure(r, k, gains, z)
    V = h.V1(z)
    assert np.all((E.lo <= V) & (V <= E.hi))
    pos = V > 0  # r = 1 with z_1 = 0: V1 = 0
    assert np.max((E.hi - E.lo)[pos] / V[pos]) < 1e-10 and np.all(E.hi[~pos] < 1e-300)


# -- pins: what the branch and bound guarantees, not its bits ------------------------------------

def _metrics_with(cert_of, duration=2.0):
    """The metrics of a synthetic adaptive r = 2 run (constant phi = 0.5: Theorem 3's Delta depends on
    c') whose certificate is cert_of(r, k, gains, form)."""
    from synthetic_runs import synthetic_run

    from ftstab_mj import metrics as mt
    from ftstab_mj.disturbances import Signal

    info, loops, _, _ = synthetic_run("adaptive", duration=duration, with_model=False, phi=Signal("constant", 0.5))
    saved = mt._certificate
    mt._certificate = cert_of
    try:
        return info, mt.compute_metrics(info, loops, "completed")
    finally:
        mt._certificate = saved


def test_a_pin_accepts_another_converged_branch_and_bound_and_rejects_a_wrong_bracket():
    """Pinned from the default certificate (stopping gap 2e-3), the expectations hold for the
    certificate of a B&B that stops at 1e-5 (another run of the same guarantee: c_lower, c_upper,
    c', T(z0), Delta and phi_hat_limsup all move, within the ranges), and fail when c_lower is
    1 % low (then T(z0) and phi_hat_limsup too), when c_upper is 1 % high (not converged), and when
    c' is 5 % high (then Delta)."""
    from dataclasses import replace

    from ftstab_mj.certificate_cache import cached_certify
    from ftstab_mj.expectations import check_metrics, pin_expectations

    info, pinned_from = _metrics_with(lambda r, k, g, form: cached_certify(r, k, g, form))
    pins = pin_expectations(pinned_from, info)
    assert all(o.ok for o in check_metrics(pinned_from, pins))
    spec = pins["loops"]["cart"]["certificate"]["c_lower"]
    assert set(spec) == {"min", "max"} and "theorem3" in pins["loops"]["cart"]

    tight = certify(HongController(2, -0.2, (1.0, 2.0)), rtol=1e-5)
    _, m = _metrics_with(lambda r, k, g, form: tight)
    new, old = m["loops"]["cart"], pinned_from["loops"]["cart"]
    assert new["certificate"]["c_lower"] != old["certificate"]["c_lower"]
    assert new["time_bound"] != old["time_bound"] and new["theorem3"]["Delta"] != old["theorem3"]["Delta"]
    assert new["theorem3"]["phi_hat_limsup"] != old["theorem3"]["phi_hat_limsup"]
    bad = [o.line for o in check_metrics(m, pins) if not o.ok]
    assert not bad, bad

    low = 0.99 * tight.c_lower
    high_cp = 1.05 * tight.c_prime_upper
    for wrong, keys in ((replace(tight, c=low, c_lower=low, c_upper=0.99 * tight.c_upper),
                         ("certificate.c_lower", "time_bound", "theorem3.phi_hat_limsup")),
                        (replace(tight, c_upper=tight.c_upper * 1.01), ("certificate.c_upper",)),
                        (replace(tight, c_prime=high_cp, c_prime_upper=high_cp, c_prime_lower=high_cp / 1.001),
                         ("certificate.c_prime_upper", "theorem3.Delta"))):
        _, m = _metrics_with(lambda r, k, g, form, w=wrong: w)
        failed = {o.path for o in check_metrics(m, pins) if not o.ok}
        assert {f"loops.cart.{key}" for key in keys} <= failed, failed

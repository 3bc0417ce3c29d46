"""The field's laws (control/laws/twisting.py, terminal.py, fixed_time.py, adaptive_super_twisting.py,
huang_adaptive.py, integral_hosm.py) on the exact ideal chain: what each source promises (a time bound
beaten, a gain condition, an accuracy order, a gain that adapts down or never does), run through the
Law protocol (for_period, evaluate, advance) as the run loop runs it."""

import numpy as np
import pytest

from ftstab_mj.control.hong import sig
from ftstab_mj.control.laws.adaptive_super_twisting import AdaptiveSuperTwisting
from ftstab_mj.control.laws.fixed_time import FixedTime
from ftstab_mj.control.laws.huang_adaptive import HuangAdaptive
from ftstab_mj.control.laws.integral_hosm import IntegralHOSM, min_energy_gains
from ftstab_mj.control.laws.sliding_surface import PlestanAdaptive
from ftstab_mj.control.laws.terminal import Terminal
from ftstab_mj.control.laws.twisting import Twisting
from ftstab_mj.config.errors import ParameterError
from ftstab_mj.simulation.ideal_chain import chain_transition


def zoh_run(law, z0, h, duration, phi, gamma=1.0, stop=None):
    """The chain z_r' = phi(t) + gamma(t) u with u, phi and gamma held over each period h, integrated
    exactly, the law run as the run loop runs it. z0 (r,) or a batch (B, r); phi(t), gamma(t) scalars or
    (B,) (gamma may be a constant). ``stop(Z_k) -> bool`` ends the run early.
    Returns t (n,), z (n, ..., r), u (n, ...), the law's state (n, ..., m) (m >= 1; zeros if none)."""
    law = law.for_period(h)
    z = np.array(z0, dtype=float)
    r = z.shape[-1]
    Phi, G = chain_transition(r, h)
    n = int(round(duration / h))
    x = np.broadcast_to(law.initial_state(), z.shape[:-1] + (law.state_size,)) + 0.0
    t = np.arange(n) * h
    Z, U = np.empty((n,) + z.shape), np.empty((n,) + z.shape[:-1])
    X = np.zeros((n,) + z.shape[:-1] + (max(law.state_size, 1),))
    for k in range(n):
        out = law.evaluate(z, x)
        Z[k], U[k] = z, out.u
        if law.state_size:
            X[k] = x
        if stop is not None and stop(z):
            return t[:k + 1], Z[:k + 1], U[:k + 1], X[:k + 1]
        x = law.advance(z, x, out, h)
        g = gamma(t[k]) if callable(gamma) else gamma
        z = z @ Phi.T + (phi(t[k]) + g * out.u)[..., None] * G
    return t, Z, U, X


def sine(amplitude, freq, offset=0.0):
    return lambda t: offset + amplitude * np.sin(2.0 * np.pi * freq * t)


def first_hit(t, a, level):
    """First time at which a (n, B) is <= level, per column (inf where never)."""
    hit = a <= level
    return np.where(hit.any(axis=0), t[np.argmax(hit, axis=0)], np.inf)


def slope(hs, values):
    return float(np.polyfit(np.log(hs), np.log(values), 1)[0])


# --- twisting ------------------------------------------------------------------------------------

C, KM_LO, KM_HI = 0.5, 0.8, 1.2  # |phi| <= C, gamma in [Km, KM]


def _twisting_disturbances(B):
    """Batch of B = 12 adversaries: 4 disturbances with |phi| <= C x 3 gains in [Km, KM]."""
    phis = [sine(C, 1.0), lambda t: C, lambda t: -C, lambda t: C * np.sign(np.sin(6.0 * np.pi * t))]
    gammas = [KM_LO, KM_HI, 1.0]
    phi = lambda t: np.array([p(t) for p in phis for _ in gammas], dtype=float)  # noqa: E731
    gamma = np.array([g for _ in phis for g in gammas])
    assert B == len(gamma)
    return phi, gamma


def test_twisting_gain_condition_is_levants():
    law = Twisting(2, 3.0, 1.5)
    # (r1 - r2) Km = 1.2 > 0.5; (r1 + r2) Km - C = 3.1 > (r1 - r2) KM + C = 2.3
    assert law.gain_condition(C, KM_LO, KM_HI)
    assert not Twisting(2, 1.0, 0.8).gain_condition(C, KM_LO, KM_HI)  # (r1 - r2) Km = 0.16 < C
    assert not Twisting(2, 3.0, 0.5).gain_condition(C, 0.5, 2.0)  # contraction fails: 1.25 < 5.5
    assert law.time_bound(1.0, 0.5, 0.5, 2.0) == np.inf
    with pytest.raises(ParameterError) as err:
        Twisting(2, 1.0, 2.0)
    assert err.value.name == "r2"
    with pytest.raises(ParameterError):
        Twisting(3, 3.0, 1.5)


@pytest.mark.parametrize("x0", [0.01, 1.0, 100.0])
def test_twisting_reaches_the_origin_before_its_majorant_bound(x0):
    """From (x0, 0), against 12 adversaries with |phi| <= 0.5 and gamma in [0.8, 1.2] (constant +-C,
    a sine, a square wave; gamma at both ends and 1), z_1 is within 1e-3 x0 of 0 before the majorant
    curve's bound K sqrt(x0) / (1 - sqrt(b/a)) (module docstring; 17.2 sqrt(x0) s here). h scales as
    sqrt(x0) (the closed loop is homogeneous with weights (2, 1)). Measured: worst first hit
    0.169 sqrt(x0) s, the bound is ten times conservative (Levant's majorant is)."""
    law = Twisting(2, 3.0, 1.5)
    T = law.time_bound(x0, C, KM_LO, KM_HI)
    assert T == pytest.approx(17.182 * np.sqrt(x0), rel=1e-4)
    phi, gamma = _twisting_disturbances(12)
    z0 = np.tile([x0, 0.0], (12, 1))
    level = 1e-3 * x0
    t, Z, _, _ = zoh_run(law, z0, 1e-4 * np.sqrt(x0), T, phi, gamma, stop=lambda z: np.all(np.abs(z[:, 0]) <= level)
                         or False)
    hits = first_hit(t, np.abs(Z[:, :, 0]), level)
    assert np.all(hits <= T), (hits, T)


def test_twisting_accuracy_orders_with_the_period():
    """Levant 1993: the twisting loop is homogeneous of degree -1 with weights (2, 1), so with u held
    over h, max |z_1| = O(h^2) and max |z_2| = O(h) once settled (slopes within +-0.3)."""
    law = Twisting(2, 3.0, 1.5)
    hs = (1e-3, 2e-3, 4e-3, 8e-3)
    acc = []
    for h in hs:
        t, Z, _, _ = zoh_run(law, (1.0, 0.0), h, 8.0, sine(0.5, 1.0))
        acc.append(np.max(np.abs(Z[t >= 4.0]), axis=0))
    acc = np.array(acc)
    assert abs(slope(hs, acc[:, 0]) - 2.0) <= 0.3, acc
    assert abs(slope(hs, acc[:, 1]) - 1.0) <= 0.3, acc


def test_twisting_without_its_gain_condition_does_not_converge():
    """(r1 - r2) Km < C: against phi = +C the sign(z_1) term cannot turn z_2 back where z_1 > 0 > z_2
    (z_2' = C - (r1 - r2) = 0.3 > 0), so z_1 never comes back to 0 (the condition is needed)."""
    law = Twisting(2, 1.0, 0.8)
    _, Z, _, _ = zoh_run(law, (1.0, 0.0), 1e-3, 10.0, lambda t: C)
    assert np.min(Z[:, 0]) >= 0.5


# --- terminal and fixed time: the motion on the surface and its time -------------------------------

@pytest.mark.parametrize("x0", [0.1, 1.0, 4.0])
def test_terminal_sliding_time_is_feng_yu_mans(x0):
    """Start on s = 0 (z_2 = -sig(beta z_1, q/p)) under phi = 0.5 sin(2 pi t), switching = 1 > 0.5:
    the sliding mode holds and z_1 reaches 1e-3 x0 at t_s(x0) - t_s(1e-3 x0), t_s(x) =
    p |x|^(1 - q/p) / (beta^(q/p) (p - q)) (Feng et al. 2002), within 20 periods (measured <= 14 at
    h = 0.1 ms), so before the bound t_s(x0)."""
    law = Terminal(2, 1.0, 1.4, 1.0)
    h = 1e-4
    level = 1e-3 * x0
    z0 = (x0, -sig(law.beta * x0, 1.0 / law.ratio))
    assert abs(law.surface(np.array(z0))) <= 1e-15 * x0
    t, Z, U, _ = zoh_run(law, z0, h, 1.2 * law.sliding_time(x0), sine(0.5, 1.0),
                         stop=lambda z: abs(z[0]) <= level)
    hit = first_hit(t, np.abs(Z[:, None, 0]), level)[0]
    assert hit <= law.sliding_time(x0)
    assert abs(hit - (law.sliding_time(x0) - law.sliding_time(level))) <= 20 * h


def test_terminal_control_is_nonsingular():
    """u = -beta (q/p) sig(z_2, 2 - p/q) - switching sign(s) is finite everywhere, z_2 = 0 included,
    and |u| <= beta (q/p) |z_2|^(2 - p/q) + switching."""
    law = Terminal(2, 2.0, 1.8, 0.7)
    rng = np.random.default_rng(3)
    z = rng.normal(size=(4000, 2)) * rng.choice([0.0, 1e-6, 1.0, 100.0], size=(4000, 2))
    u = law.evaluate(z).u
    assert np.all(np.isfinite(u))
    assert np.all(np.abs(u) <= law.beta / law.ratio * np.abs(z[:, 1]) ** (2 - law.ratio) + 0.7 + 1e-12)


def test_fixed_time_sliding_phase_ends_before_the_same_bound_from_anywhere():
    """Start on s = 0 at z_1 = 1e-2, 1, 1e2 (z_2 = -Psi(z_1)), phi = 0.5 sin(2 pi t): z_1 reaches 1e-3
    at T(z_1) - T(1e-3), T(x) = 3/sqrt(ab) arctan(sqrt(b/a) |x|^(1/3)) (module docstring), within 20
    periods (measured <= 8 at 0.1 ms), so before 3 pi / (2 sqrt(ab)) = 4.71 s, the same bound for all
    (fixed time), itself below Polyakov's 3/a + 3/b = 6 s. (From z_1 = 1e4 the sampled loop at 0.1 ms
    loses the surface: switching = 1 cannot hold it against the O(h^2) errors of a term of size 1e10.)"""
    law = FixedTime(2, 1.0, 1.0, 1.0)
    assert law.sliding_time_bound() == pytest.approx(1.5 * np.pi) and law.polyakov_bound() == 6.0
    x0 = np.array([1e-2, 1.0, 1e2])
    z0 = np.stack([x0, -(sig(x0, 2 / 3) + sig(x0, 4 / 3))], axis=-1)
    assert np.all(np.abs(law.surface(z0)) <= 1e-12 * x0)
    h, level = 1e-4, 1e-3
    t, Z, _, _ = zoh_run(law, z0, h, law.sliding_time_bound(), sine(0.5, 1.0),
                         stop=lambda z: np.all(np.abs(z[:, 0]) <= level))
    hits = first_hit(t, np.abs(Z[:, :, 0]), level)
    assert np.all(hits <= law.sliding_time_bound()), hits
    np.testing.assert_allclose(hits, law.sliding_time(x0) - law.sliding_time(level), atol=20 * h)


def test_fixed_time_surface_inverse_and_control_are_continuous():
    """G = Psi^-1 in closed form: Psi(G(y)) = y; the nominal term n(z_2) = Psi'(G(z_2)) z_2 is finite
    and -> 0 as z_2 -> 0 (like |z_2|^(1/2)), so u is bounded near the origin."""
    law = FixedTime(2, 0.7, 2.5, 1.0)
    y = np.concatenate([-np.logspace(-12, 6, 50), [0.0], np.logspace(-12, 6, 50)])
    w = law.inverse(y)
    np.testing.assert_allclose(0.7 * sig(w, 2 / 3) + 2.5 * sig(w, 4 / 3), y, rtol=1e-12, atol=1e-300)
    z = np.stack([-law.inverse(y), y], axis=-1)  # on s = 0: u = -n(z_2)
    n = -law.evaluate(z).u
    assert np.all(np.isfinite(n)) and n[50] == 0.0
    small = np.abs(y) <= 1e-8
    assert np.all(np.abs(n[small]) <= 2 * 0.7 / 3 * np.sqrt(np.abs(y[small]) * 0.7) * 1.01 + 1e-300)


# --- adaptive gains: up and down (Shtessel et al.), never down (Huang et al.) ---------------------

def dropping(t):
    """phi with |phi'| <= 4 pi for t < 5 s, ten times smaller after."""
    return np.where(t < 5.0, 2.0, 0.2) * np.sin(2.0 * np.pi * t)


def test_adaptive_super_twisting_gains_rise_then_fall_with_the_disturbance():
    """Shtessel, Taleb & Plestan 2012: alpha grows at omega1 sqrt(gamma1/2) while |s| > mu and falls at
    that rate while |s| < mu (down to alpha_m), beta = 2 epsilon alpha: every step is the law's, to
    rounding. With phi' dropping tenfold at 5 s the gain reached under the large disturbance comes down
    (it adapts to the disturbance, not its worst case: measured peak 5.62, at most 1.94 after 8 s). s
    enters the band |s| < mu before the drop, and keeps returning to it (that is what lowers alpha)."""
    law = AdaptiveSuperTwisting(2, (2.0,), omega1=2.0, gamma1=2.0, mu_band=1e-3, alpha_min=0.05, epsilon=1.0)
    h = 1e-3
    t, Z, U, X = zoh_run(law, (1.0, 0.0), h, 12.0, dropping)
    s = Z[:, 1] + 2.0 * Z[:, 0]
    alpha, v = X[:, 1], X[:, 0]
    rate = 2.0 * np.sqrt(2.0 / 2.0)
    expected = np.where(alpha[:-1] > 0.05, rate * np.sign(np.abs(s[:-1]) - 1e-3), 0.01)
    np.testing.assert_allclose(np.diff(alpha), h * expected, atol=1e-12)
    np.testing.assert_allclose(np.diff(v), -2.0 * 1.0 * np.sign(s[:-1]) * h * 0.5 * (alpha[:-1] + alpha[1:]), atol=1e-12)
    # the disturbance's phase: the gain rises above what phi' = 4 pi needs; after the drop it falls
    peak = np.max(alpha[t < 5.0])
    assert peak > 2.0 and np.max(alpha[t >= 8.0]) < 0.75 * peak, (peak, np.max(alpha[t >= 8.0]))
    assert np.any(np.abs(s[t < 5.0]) < 1e-3) and np.any(np.abs(s[t >= 10.0]) < 1e-3)


def test_huang_gain_never_decreases_and_plestans_does():
    """Huang, Kuo & Chang 2008: K' = Kbar |s| >= 0, so K never decreases and, sampled (|s| = O(h) after
    the reaching phase), keeps growing after the disturbance has dropped tenfold; Plestan's K on the
    same surface, rate and disturbance falls once |s| < eps (slowly: at Kbar |s|). Both keep s small."""
    kw = dict(Kbar=20.0)
    huang = HuangAdaptive(2, (2.0,), **kw)
    plestan = PlestanAdaptive(2, (2.0,), mu=0.05, eps=0.01, **kw)
    h = 1e-3
    t, Z, _, K = zoh_run(huang, (1.0, 0.0), h, 12.0, dropping)
    K = K[:, 0]
    s = Z[:, 1] + 2.0 * Z[:, 0]
    np.testing.assert_allclose(np.diff(K), h * 20.0 * np.abs(s[:-1]), atol=1e-12)
    assert np.all(np.diff(K) >= 0.0)
    assert K[-1] > K[t >= 5.0][0] and K[-1] > 2.0  # still growing; above the first phase's sup |phi| = 2
    _, Zp, _, Kp = zoh_run(plestan, (1.0, 0.0), h, 12.0, dropping)
    assert Kp[-1, 0] < Kp[t >= 5.0][0, 0] < K[-1]  # measured: 10.03 at the drop, 9.35 at 12 s; Huang's 10.87 -> 11.66
    for z in (Z, Zp):
        assert np.max(np.abs(z[t >= 10.0, 1] + 2.0 * z[t >= 10.0, 0])) < 0.05


# --- integral HOSM: no reaching phase, the nominal trajectory, the origin at t_F --------------------

def test_minimum_energy_gains():
    """r = 2: u = -(6 z_1 + 4 T z_2) / T^2 (the classical double-integrator result); r = 3: 60, 36, 9.
    In closed loop the undisturbed chain arrives at 0 at T (exactly in continuous time)."""
    np.testing.assert_allclose(min_energy_gains(2), [6.0, 4.0], rtol=1e-12)
    np.testing.assert_allclose(min_energy_gains(3), [60.0, 36.0, 9.0], rtol=1e-10)


@pytest.mark.parametrize("r", [2, 3])
def test_integral_hosm_keeps_the_sliding_variable_within_one_step_from_t0(r):
    """Laghrouche, Plestan & Glumineau 2007: s = z_r - z_r(0) - int u_nom is 0 at t = 0, so there is no
    reaching phase: sampled, |s_k| <= h M for every k, M = sup |phi + (gamma - 1) u_nom| + gamma switching
    (one step of s' = phi + (gamma - 1) u_nom - gamma switching sign s from |s| <= h M stays there).
    The chain then follows the nominal closed loop, undisturbed, to O(h): it is within 10 h of the
    undisturbed run's z_1 and arrives at |z_1| <= 10 h at t_F. Measured, r = 2 / 3: max |s| = 0.98 / 0.95 h M,
    deviation 0.16 / 0.04 h, z_1(t_F) = 0.78 / -0.08 h (the undisturbed sampled loop's own, to 1e-3 h)."""
    h, gamma = 1e-3, 1.1
    law = IntegralHOSM(r, 3.0, 1.5, t_hold=0.3)
    phi = sine(0.5, 1.0, 0.2)
    z0 = (1.0,) + (0.0,) * (r - 1)
    t, Z, U, X = zoh_run(law, z0, h, 4.0, phi, gamma)
    s = Z[:, -1] - np.where(X[:, 0] > 0.0, X[:, 1], Z[0, -1])
    u_nom = np.array([law.nominal(z, tau) for z, tau in zip(Z, X[:, 0])])
    M = 0.7 + (gamma - 1.0) * np.max(np.abs(u_nom)) + gamma * 1.5
    assert np.max(np.abs(s)) <= h * M * (1 + 1e-9), (np.max(np.abs(s)), h * M)
    _, Z0, _, _ = zoh_run(law, z0, h, 4.0, lambda t: 0.0)
    before = t <= 3.0
    assert np.max(np.abs(Z[before, 0] - Z0[before, 0])) <= 10 * h
    assert abs(Z[int(round(3.0 / h)), 0]) <= 10 * h


def test_integral_hosm_without_its_switching_term_is_moved_by_the_disturbance():
    """The control experiment: with a tiny switching gain (1e-6) a constant phi = 0.2 pushes the chain
    off the nominal trajectory by more than the 10 h the test above allows (measured 0.091 = 91 h): the
    integral sliding mode is what rejects it."""
    h = 1e-3
    law = IntegralHOSM(2, 3.0, 1e-6, t_hold=0.3)
    t, Z, _, _ = zoh_run(law, (1.0, 0.0), h, 3.0, lambda t: 0.2)
    _, Z0, _, _ = zoh_run(law, (1.0, 0.0), h, 3.0, lambda t: 0.0)
    assert np.max(np.abs(Z[:, 0] - Z0[:, 0])) > 10 * h

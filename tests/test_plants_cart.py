"""The MuJoCo carts against the ideal chain (ideal_chain.py), their sensing, and closed-loop stabilization.

Cross-check derivations (h = physics step, N = steps per control period, inputs held per step):

* r = 2, RK4. Within a step every input (ctrl, gain, qfrc_applied) is constant, so x'' is constant
  and x(t) is a polynomial of degree 2 on the step. RK4 integrates polynomials of degree <= 4
  exactly, so one MuJoCo step IS the chain's exact transition (Phi(h), G(h)) and the two closed
  loops coincide up to round-off: |z_mj - z_ideal| <= (number of steps) * eps * |z| ~ 1e-12.
* r = 3, RK4, no injected disturbance: act' = g u constant on the step, x''' constant, x of degree 3:
  exact again (the accelerometer is read after a fresh forward pass, so x'' has no delay).
  With a disturbance the injected force is held per step (its ramp F_d' = m phi is integrated step by
  step into qfrc_applied), which is a first-order approximation: covered by the next point.
* Euler (the default). MuJoCo's semi-implicit Euler gives, per step, v+ = v + h a,
  x+ = x + h v + h^2 a against the exact x + h v + h^2 a / 2 (r = 3: the same one level up), a
  local defect O(h^2) and a global one O(h): away from the switching region (V1 above a level,
  where the law is smooth) the closed-loop discrepancy is C h + O(h^2), so dividing h by 10 divides
  it by 10 (we accept 8..12: the O(h^2) part). Near the origin the discontinuous law chatters and
  both trajectories stay in an O(period) box, so only the transient is compared.
"""

import numpy as np
import pytest

from ftstab_mj.control import AdaptiveLaw, HongController, RobustLaw, certify, theorem3_bounds
from ftstab_mj.plants.disturbances import Signal
from ftstab_mj.simulation.ideal_chain import simulate_chain
from ftstab_mj.plants import make_plant
from ftstab_mj.scenario import LoopSpec

from ftstab_mj.simulation.run_loop import simulate

HONG = {2: HongController(2, -0.2, (1.0, 2.0)), 3: HongController(3, -0.1, (1.0, 1.7, 5.0))}
Z0 = {2: (1.0, 0.0), 3: (1.0, 0.0, 0.0)}
MODEL = {2: "cart", 3: "cart_integrating"}
PHI = Signal("sine", amplitude=0.5, freq=1.0)
GAMMA = Signal("sine", offset=1.0, amplitude=0.2, freq=0.5)


def _both(r, period, N, integrator, phi=PHI, duration=6.0, mass=2.0):
    """(MuJoCo samples, ideal chain run) for the robust law on the cart with mass `mass`."""
    law = RobustLaw(HONG[r], phibar=0.5, gamma_m=0.8)
    res = simulate(make_plant(MODEL[r], {"mass": mass}), [LoopSpec("cart", controller=law, disturbance=phi, gain=GAMMA, z0=Z0[r])],
                   duration=duration, period=period, physics_step=period / N, integrator=integrator)
    assert res.status == "completed"
    chain = simulate_chain(law, np.array(Z0[r]), period, duration, phi, GAMMA, substeps=N)
    return res.loops["cart"], chain


@pytest.mark.parametrize("period", [0.01, 0.02])
@pytest.mark.parametrize("r, phi", [(2, PHI), (3, Signal("constant", 0.0))])
def test_rk4_cart_is_the_ideal_chain_up_to_round_off(r, phi, period):
    mj, chain = _both(r, period, 10, "rk4", phi=phi)
    assert np.abs(mj["z"] - chain.z).max() < 1e-12
    np.testing.assert_allclose(mj["u"], chain.u, rtol=0, atol=1e-10)
    # the true phi and gamma recorded are the chain's
    np.testing.assert_array_equal(mj["gamma"], chain.gamma)
    np.testing.assert_allclose(mj["phi"], chain.phi, rtol=0, atol=1e-15)


def _transient_discrepancy(mj, chain, level=1e-2):
    """max |z_mj - z_ideal| per component over the samples before the ideal V1 first drops below level."""
    end = int(np.argmax(chain.V1 < level))
    assert end > 50  # the window is a real transient
    return np.abs(mj["z"][:end] - chain.z[:end]).max(axis=0)


@pytest.mark.parametrize("period", [0.01, 0.02])
@pytest.mark.parametrize("r", [2, 3])
def test_euler_cart_converges_to_the_ideal_chain_at_first_order(r, period):
    coarse = _transient_discrepancy(*_both(r, period, 10, "euler", duration=4.0))
    fine = _transient_discrepancy(*_both(r, period, 100, "euler", duration=4.0))
    ratio = coarse / fine
    assert np.all((ratio > 8.0) & (ratio < 12.0)), (coarse, fine)


def test_r3_accelerometer_delay_is_zero_with_refresh_and_one_physics_step_without():
    """Measure the sensing delay of x''. With Euler and N = 1 the actuator state and the injected
    force advance exactly by h (g u) and h m phi per step, so the true x'' obeys
    x''(t_{k+1}) - x''(t_k) = h (phi_k + gamma_k u_k) to round-off. The sensed z3 satisfies this
    recursion shifted by the sensor's delay d (in steps): z3_{k+1} - z3_k = h w_{k-d}."""
    h = 0.002
    law = RobustLaw(HONG[3], phibar=0.5, gamma_m=0.8)
    residual = {}
    for refresh in (True, False):
        res = simulate(make_plant("cart_integrating", {"mass": 2.0, "sensor_refresh": refresh}),
                       [LoopSpec("cart", controller=law, disturbance=PHI, gain=GAMMA, z0=Z0[3])], duration=1.0, period=h, physics_step=h)
        s = res.loops["cart"]
        w = s["phi"] + s["gamma"] * s["u"]
        dz3 = np.diff(s["z"][:, 2])
        residual[refresh] = {d: np.abs(dz3[2:] - h * w[2 - d:len(w) - 1 - d]).max() for d in (0, 1, 2)}
    assert residual[True][0] < 1e-12 and min(residual[True][1], residual[True][2]) > 1e-5
    assert residual[False][1] < 1e-12 and min(residual[False][0], residual[False][2]) > 1e-5


def _settle(t, V1, level):
    """First sample time with V1 <= level (inf if never)."""
    below = np.flatnonzero(V1 <= level)
    return t[below[0]] if len(below) else np.inf


GAIN_UNCERTAINTY = Signal("random", offset=1.0, amplitude=0.2, freq=2.0, seed=5)  # gamma in [0.8, 1.2]
DISTURBANCES = [Signal("random", amplitude=0.4, freq=3.0, seed=2), Signal("worst_case", amplitude=0.4),
                Signal("square", amplitude=0.4, freq=0.7)]


@pytest.mark.parametrize("phi", DISTURBANCES, ids=lambda s: s.kind)
@pytest.mark.parametrize("r", [2, 3])
def test_robust_law_stabilizes_the_cart_within_the_theorem_1_time(r, phi):
    """Bounds assumed by the law (phibar 0.5, gamma_m 0.8) cover the true ones (0.4, [0.8, 1.2]):
    Theorem 2 gives dV1/dt <= -c V1^alpha, so V1 reaches 0 before T = V1(0)^(1-alpha)/(c (1-alpha)).
    Sampled at 5 ms the closed loop reaches a chattering band instead: V1 <= 1e-3 before T and
    stays there over the last 20 % of the run."""
    law = RobustLaw(HONG[r], phibar=0.5, gamma_m=0.8)
    res = simulate(make_plant(MODEL[r], {"mass": 2.0}), [LoopSpec("cart", controller=law, disturbance=phi, gain=GAIN_UNCERTAINTY, z0=Z0[r])],
                   duration=6.0, period=0.005, physics_step=0.001)
    (info,) = res.info.loops
    assert info.true_phibar <= law.phibar and info.true_gamma_m >= law.gamma_m
    s = res.loops["cart"]
    assert np.abs(s["phi"]).max() <= 0.4 and s["gamma"].min() >= 0.8 and s["gamma"].max() <= 1.2
    # the recorded true phi is the injected signal (the worst case with this sample's dV1/dz_r)
    np.testing.assert_array_equal(s["phi"], phi(s["t"], s["dV1_dzr"]) if phi.state_dependent else phi(s["t"]))
    cert = certify(HONG[r])
    T = s["V1"][0] ** (1 - cert.alpha) / (cert.c * (1 - cert.alpha))
    assert _settle(s["t"], s["V1"], 1e-3) <= T
    assert s["V1"][-len(s["V1"]) // 5:].max() <= 1e-3


@pytest.mark.parametrize("phi", DISTURBANCES[:2], ids=lambda s: s.kind)
@pytest.mark.parametrize("r", [2, 3])
def test_adaptive_law_stabilizes_the_cart_without_the_bounds_within_theorem_3(r, phi):
    """The adaptive law knows neither phibar nor gamma_m. Theorem 3 (with the TRUE bounds 0.4 and
    0.8, from RunInfo): liminf V1 <= eps, limsup V1 <= Delta, limsup phi_hat <= its bound; checked
    on the second half of the run."""
    eps = 1e-3
    law = AdaptiveLaw(HONG[r], kappa=1.0, delta=0.1, rate=2.0, eta=0.5, eps=eps)
    res = simulate(make_plant(MODEL[r], {"mass": 2.0}), [LoopSpec("cart", controller=law, disturbance=phi, gain=GAIN_UNCERTAINTY, z0=Z0[r])],
                   duration=12.0, period=0.005, physics_step=0.001)
    (info,) = res.info.loops
    bounds = theorem3_bounds(certify(HONG[r]), info.true_phibar, info.true_gamma_m, law.kappa, law.delta,
                             law.rate, eps)
    s = res.loops["cart"]
    late = slice(len(s["V1"]) // 2, None)
    assert s["V1"][late].min() <= eps
    assert s["V1"][late].max() <= bounds.Delta
    assert s["phi_hat"][late].max() <= bounds.phi_hat_limsup
    assert s["V1"][0] > 100 * bounds.Delta  # it started far outside: the law did the work

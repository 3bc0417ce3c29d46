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

from ftstab_mj.control import HongController, RobustLaw
from ftstab_mj.disturbances import Signal
from ftstab_mj.ideal_chain import simulate_chain
from ftstab_mj.plants import make_plant
from ftstab_mj.sim import LoopSpec, simulate

HONG = {2: HongController(2, -0.2, (1.0, 2.0)), 3: HongController(3, -0.1, (1.0, 1.7, 5.0))}
Z0 = {2: (1.0, 0.0), 3: (1.0, 0.0, 0.0)}
MODEL = {2: "cart", 3: "cart_integrating"}
PHI = Signal("sine", amplitude=0.5, freq=1.0)
GAMMA = Signal("sine", offset=1.0, amplitude=0.2, freq=0.5)


def _both(r, period, N, integrator, phi=PHI, duration=6.0, mass=2.0):
    """(MuJoCo samples, ideal chain run) for the robust law on the cart with mass `mass`."""
    law = RobustLaw(HONG[r], phibar=0.5, gamma_m=0.8)
    res = simulate(make_plant(MODEL[r], {"mass": mass}), [LoopSpec("cart", law, phi, GAMMA, Z0[r])],
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

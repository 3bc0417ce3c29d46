"""The cart on a slide joint (models/cart.xml, models/cart_integrating.xml), a chain of r = 2 or 3 integrators.

Mass m (kg). The actuator gain is m, so with a gain factor g(t) (the LoopSpec's gamma signal):

* "cart" (r = 2): force m g u; injected force F_d = m phi.  x'' = phi + g u: gamma = g, chain units.
  z = (x, x') from the joint position and velocity sensors.
* "cart_integrating" (r = 3): the actuator state act obeys act' = g u and pushes with m act; the
  injected force has rate F_d' = m phi (F_d(0) = 0).  x''' = phi + g u.  z = (x, x', x'') with x''
  from the accelerometer on the cart, never from F_d. MuJoCo evaluates acceleration sensors after
  the control callback, so inside the callback the accelerometer holds the value of the previous
  forward pass: one physics step old. By default (``sensor_refresh = True``) the run loop calls
  mj_forward before each control sample, which makes the reading exact (delay 0) at the cost of one
  forward pass per control period; with ``sensor_refresh = False`` x'' is delayed by one physics
  step (tests/test_plants_cart.py measures both).

Optional physics, off unless asked: ``friction`` (N, dry friction of the slide, MuJoCo frictionloss),
``damping`` (N s/m, viscous). The recorded true phi adds the viscous force (r = 2: -b x'/m); dry
friction is a constraint force solved after the controller runs, so it is not in the recorded
phi but is in the bound true_phibar (+ friction/m). For r = 3 the recorded phi is the injected rate
only (the derivative of friction forces is not a bounded signal). MuJoCo's Euler integrates damping
implicitly, so with damping the recorded phi is exact only to O(h).
"""

from __future__ import annotations

import numpy as np

from ftstab_mj.config.errors import ParameterError
from ftstab_mj.plants.base import Plant, check_keys, load_spec, number, register_plant

PARAMS = ("mass", "friction", "damping", "sensor_refresh")


class CartPlant(Plant):
    """Cart plant; ``integrating`` selects r = 3 (models/cart_integrating.xml)."""

    def __init__(self, model_name: str, params: dict, integrating: bool):
        allowed = PARAMS if integrating else PARAMS[:3]
        check_keys(model_name, params, allowed)
        mass = number(params, "mass", 1.0, positive=True)
        friction = number(params, "friction", 0.0, nonneg=True)
        damping = number(params, "damping", 0.0, nonneg=True)
        refresh = params.get("sensor_refresh", True)
        if not isinstance(refresh, bool):
            raise ParameterError("params.sensor_refresh", "true or false", refresh)
        spec = load_spec("cart_integrating.xml" if integrating else "cart.xml")
        spec.geom("cart").mass = mass
        joint = spec.joint("x")
        joint.frictionloss = friction
        joint.damping = [damping, 0.0, 0.0]
        spec.actuators[0].gainprm[0] = mass
        super().__init__(spec)
        # all the spec's edits of its package file, bit for bit (as hex: -0.0 == 0.0, yet not the same value)
        self.spec_key = (integrating,) + tuple(v.hex() for v in (mass, friction, damping))
        self.model_name = model_name
        self.params = {"mass": mass, "friction": friction, "damping": damping}
        if integrating:
            self.params["sensor_refresh"] = refresh
        self.mass, self.friction, self.damping = mass, friction, damping
        self.exact_chain_twin = not friction and not damping  # the slide is then the chain itself
        self.loop_names = ("cart",)
        self.r = 3 if integrating else 2
        self.integrating = integrating
        self.refresh_before_sample = integrating and refresh
        self.dist_scale = np.array([mass])
        self.body_names = ("cart",)
        self.phi_units = "m/s^3 (injected force rate / mass)" if integrating else "m/s^2 (injected force / mass)"
        self.gamma_units = ("m/s^3 per unit u (actuator force rate / mass)" if integrating
                            else "m/s^2 per unit u (actuator force / mass)")

    def bind(self, m):
        self._pos = self.sensor_block(m, "x").start
        self._vel = self.sensor_block(m, "xdot").start
        self._acc = self.sensor_block(m, "imu").start if self.integrating else None  # x component

    def set_initial(self, m, d, q0, z0):
        d.qpos[0] = q0[0]
        d.qvel[0] = z0[0, 1]
        if self.integrating:  # x''(0) = act - b x'(0)/m with F_d(0) = 0
            d.act[0] = z0[0, 2] + self.damping * z0[0, 1] / self.mass

    def sense(self, d, z):
        s = d.sensordata
        z[0, 0] = s[self._pos]
        z[0, 1] = s[self._vel]
        if self.integrating:
            z[0, 2] = s[self._acc]

    def true_chain(self, m, d, u, gain, phi_inj):
        if self.integrating:
            return phi_inj.copy(), gain.copy()
        # float by float (the run loop's Python path calls this at every sample): the same roundings
        # as the array expression phi_inj - damping qvel / mass, at a third of its cost
        return np.array([phi_inj[0] - self.damping * float(d.qvel[0]) / self.mass]), gain.copy()

    def native_sensing(self, m):
        adr = [self._pos, self._vel] + ([self._acc] if self.integrating else [])
        damping = 0.0 if self.integrating else self.damping  # as true_chain
        return np.array([adr]), np.array([damping]), np.array([self.mass])

    def true_bounds(self, phi_bounds, gamma_bounds):
        (plo, phi_hi), = phi_bounds
        (glo, ghi), = gamma_bounds
        phibar = max(abs(plo), abs(phi_hi)) + (0.0 if self.integrating else self.friction / self.mass)
        if self.damping > 0.0:  # phi holds -b x'/m (r = 2; -b x''/m for r = 3): unbounded without a speed limit
            phibar = float("inf")
        return np.array([phibar]), np.array([glo]), np.array([ghi])


register_plant("cart", lambda name, params: CartPlant(name, params, integrating=False),
               "r = 2, one loop 'cart': a cart on a rail pushed by a force (params: mass, friction, damping)")
register_plant("cart_integrating", lambda name, params: CartPlant(name, params, integrating=True),
               "r = 3, one loop 'cart': the cart with an integrating actuator, force' = u "
               "(params: mass, friction, damping, sensor_refresh)")

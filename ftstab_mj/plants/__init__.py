"""MuJoCo plants that the paper's controllers stabilize: build one from plain values with make_plant.

    plant = make_plant("cart", {"mass": 2.0})

Models (files in models/):
  "cart"              r = 2, one loop "cart"  (params: mass, friction, damping)
  "cart_integrating"  r = 3, one loop "cart"  (params: mass, friction, damping, sensor_refresh)
  "arm"               r = 2, loops "joint0", "joint1": two stacked hinge joints in a vertical plane
                      (params: link_lengths, link_masses, armature, friction, damping; the
                      workspace of the bounds: q_min, q_max, qd_max, u_max, grid)

Signal units differ: the carts take phi and gamma in chain units, the arm takes phi as an injected
joint torque (N m) and gamma as a motor gain factor (plant.phi_units / plant.gamma_units say it).
Bounds in chain units for given signal ranges: plant.true_bounds(phi_bounds, gamma_bounds) ->
(phibar, gamma_m, gamma_M), arrays over the loops; for the arm they hold inside its workspace,
which plant.loop_workspace(i, ref) states and the metrics check for every run ("workspace_left").

An unknown model or parameter raises ParameterError naming it. See base.py for how the run loop
drives a plant (inputs, sensing, userdata) and each module for its physics and units.
"""

from __future__ import annotations

from ftstab_mj.errors import ParameterError
from ftstab_mj.plants.arm import ArmPlant
from ftstab_mj.plants.base import Plant
from ftstab_mj.plants.cart import CartPlant

MODELS = ("cart", "cart_integrating", "arm")


def make_plant(model: str, params: dict | None = None) -> Plant:
    """Build the plant ``model`` (one of MODELS) with ``params`` (defaults for missing keys)."""
    params = {} if params is None else params
    if model == "cart":
        return CartPlant(model, params, integrating=False)
    if model == "cart_integrating":
        return CartPlant(model, params, integrating=True)
    if model == "arm":
        return ArmPlant(model, params)
    raise ParameterError("model", "one of " + ", ".join(MODELS), model)


__all__ = ["MODELS", "Plant", "make_plant"]

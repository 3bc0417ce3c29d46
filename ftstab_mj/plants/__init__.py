"""Layer 3, plants: MuJoCo plants that the laws stabilize; build one from plain values with make_plant.

May import: config, control. (The disturbance signals and MuJoCo's control-callback slot live here too.)

    plant = make_plant("cart", {"mass": 2.0})

A plant is one module of this package (every module is imported) that subclasses base.Plant and
calls ``register_plant(name, build, summary)``; ``ftstab list`` and the scenario's ``plant.model``
then know it. Registered models (files in models/):
  "cart"              r = 2, one loop "cart"  (params: mass, friction, damping)
  "cart_integrating"  r = 3, one loop "cart"  (params: mass, friction, damping, sensor_refresh)
  "arm"               r = 2, loops "joint0", "joint1": two stacked hinge joints in a vertical plane
                      (params: link_lengths, link_masses, armature, friction, damping; the
                      workspace of the bounds: q_min, q_max, qd_max, u_max, grid)
  "arm_integrating"   r = 3, the same arm, its motors integrate the control (torque rate)
  "arm3"              r = 2, loops "joint0".."joint2": three stacked hinge joints
  "ideal_chain"       r = params.r (1..6), one loop "chain": the ideal chain z_r' = phi + gamma u,
                      integrated exactly by the plant (plants/ideal.py: phi, gamma chosen freely)
  "flexible_joint"    r = 4 (r = 5 with params.integrating), one loop "link": a link under gravity
                      driven through a spring by a motor rotor; z is the link's, read from the state
                      (params: inertias, link mass and centre of mass, stiffness, gear, damping; the
                      workspace of the guaranteed bounds: q_min, q_max, qd_max, qdd_max, ..., u_max)
A model that is the path of an MJCF file ("robot.xml") is a user model (plants/user.py): its
loops, joints and actuators come from params["loops"]; r = 2 or 3, or 4 and 5 when the loop's
actuator reaches its joint through a spring (a flexible joint: plants/flexible_joint.py).

Signal units differ: the carts take phi and gamma in chain units, the arm takes phi as an injected
joint torque (N m) and gamma as a motor gain factor (plant.phi_units / plant.gamma_units say it).
Bounds in chain units for given signal ranges: plant.true_bounds(phi_bounds, gamma_bounds) ->
(phibar, gamma_m, gamma_M), arrays over the loops; for the arm they hold inside its workspace,
which plant.loop_workspace(i, ref) states and the metrics check for every run ("workspace_left").

An unknown model or parameter raises ParameterError naming it. See base.py for how the run loop
drives a plant (inputs, sensing, userdata) and each module for its physics and units.
"""

from __future__ import annotations

import importlib
import pkgutil

from ftstab_mj.config.errors import ParameterError
from ftstab_mj.plants.base import PLANTS, Plant, register_plant

for _module in pkgutil.iter_modules(__path__):  # every plant module registers its models
    importlib.import_module(f"{__name__}.{_module.name}")

from ftstab_mj.plants.user import make_user_plant  # noqa: E402 (imported above with the others)

MODELS = tuple(PLANTS)  # the models registered by this package's modules


def make_plant(model: str, params: dict | None = None) -> Plant:
    """Build the registered plant ``model`` with ``params`` (defaults for missing keys)."""
    params = {} if params is None else params
    if model not in PLANTS and isinstance(model, str) and model.endswith(".xml"):
        return make_user_plant(model, params)
    if model not in PLANTS:
        raise ParameterError("model", "one of " + ", ".join(PLANTS) + " or the path of an MJCF file (.xml)", model)
    return PLANTS[model].build(model, params)


__all__ = ["MODELS", "PLANTS", "Plant", "make_plant", "register_plant"]

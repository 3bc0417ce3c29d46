"""The arms: vertical stacks of actuated hinge joints, one control loop per joint (plants/chain.py).

Models: "arm" (models/arm.xml, two links, motors: r = 2), "arm_integrating" (the same arm whose
motors integrate their input: the control sets the torque rate, r = 3), "arm3" (models/arm3.xml,
three links, motors: r = 2). Loops "joint0" (base), "joint1", ...

Parameters (defaults in DEFAULTS, one value per link or one number for all): link_lengths (m),
link_masses (kg), armature (kg m^2, the reflected rotor inertia of geared motors, MuJoCo joint
armature), friction (N m, dry), damping (N m s/rad), and the workspace of the bounds: q_min,
q_max (rad), qd_max (rad/s), u_max (N m; r = 3: N m/s, the torque rate), qdd_max (rad/s^2, r = 3
only), grid (q points per joint), qd_grid (q' points per joint, r = 3 only).
Why armature by default: without it the inertia coupling of these light arms is so strong that no
decentralised robust design closes (the bound on joint 0's phi through joint 1's torque needs more
torque than joint 1 may use, and vice versa); with rotor inertia, as on any geared arm, the
computed bounds are consistent with the default u_max.

Units of the signals: phi is an injected joint torque (N m; r = 3 its rate, N m/s), gamma a motor
gain factor (dimensionless, nominal 1); chain gamma_i = factor x (M^-1)_ii. Chain map, recorded
phi and gamma, sensors and bounds: plants/chain.py and plants/chain_bounds.py. Dry friction is a
constraint force solved after the controller, so it is only in the (r = 2) bound; joint damping
is in the recorded phi, but MuJoCo's Euler integrates damping implicitly (an O(h) difference).
"""

from __future__ import annotations

import mujoco
import numpy as np

from ftstab_mj.config.errors import ParameterError
from ftstab_mj.config.validate import number_problem
from ftstab_mj.plants.base import check_keys, load_spec, register_plant
from ftstab_mj.plants.chain import ChainLoop, ChainPlant
from ftstab_mj.plants.chain_bounds import Workspace

# q grid points per joint of the bound tables, by number of joints (measured on 2 CPUs under load:
# arm 161 -> 1.3 s, arm3 41 -> 5.6 s, arm_integrating 161 (qd_grid 5) -> 6.6 s)
MAX_GRID = {2: 161, 3: 41}
LARGEST_GRID_S = 8
MODELS = {"arm": ("arm.xml", False), "arm_integrating": ("arm.xml", True), "arm3": ("arm3.xml", False)}
DEFAULTS = {
    "arm": {"link_lengths": [0.5, 0.4], "link_masses": [1.0, 0.5], "armature": [0.2, 0.1], "friction": 0.0,
            "damping": 0.0, "q_min": [-0.3, -0.8], "q_max": [0.9, 0.6], "qd_max": [2.0, 3.0], "u_max": [15.0, 5.0],
            "grid": 41},
    "arm_integrating": {"link_lengths": [0.5, 0.4], "link_masses": [1.0, 0.5], "armature": [0.2, 0.1],
                        "friction": 0.0, "damping": 0.0, "q_min": [-0.3, -0.8], "q_max": [0.9, 0.6],
                        "qd_max": [2.0, 3.0], "qdd_max": [6.0, 8.0], "u_max": [60.0, 25.0], "grid": 21, "qd_grid": 5},
    "arm3": {"link_lengths": [0.4, 0.35, 0.3], "link_masses": [1.0, 0.6, 0.4], "armature": [0.3, 0.2, 0.1],
             "friction": 0.0, "damping": 0.0, "q_min": [-0.3, -0.8, -0.8], "q_max": [0.9, 0.6, 0.8],
             "qd_max": [2.0, 3.0, 3.0], "u_max": [25.0, 14.0, 6.0], "grid": 15},
}


def _vector(params, defaults, key, n, positive=False, nonneg=False) -> np.ndarray:
    v = params.get(key, defaults[key])
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        v = [v] * n
    ok = isinstance(v, (list, tuple, np.ndarray)) and len(v) == n
    ok = ok and all(number_problem(x) is None and (x > 0 if positive else x >= 0 if nonneg else True) for x in v)
    if not ok:
        what = f"{n} finite numbers" + (" > 0" if positive else " >= 0" if nonneg else "")
        raise ParameterError(f"params.{key}", what, v)
    return np.array(v, dtype=float)


def _count(params, key, defaults, low, high) -> int:
    v = params.get(key, defaults[key])
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not low <= v <= high:
        raise ParameterError(f"params.{key}", f"an integer in [{low}, {high}] (the bounds evaluate the model at "
                             f"grid^joints configurations: the largest grid takes ~{LARGEST_GRID_S} s)", v)
    return int(v)


class ArmPlant(ChainPlant):
    """An arm of MODELS; loops "joint0" (base), "joint1", ..."""

    def __init__(self, model_name: str, params: dict):
        filename, integrating = MODELS[model_name]
        defaults = DEFAULTS[model_name]
        check_keys(model_name, params, defaults)
        spec = load_spec(filename)
        n = len(spec.joints)
        vec = {k: _vector(params, defaults, k, n, positive=k in ("link_lengths", "link_masses"),
                          nonneg=k in ("armature", "friction", "damping", "qd_max", "u_max", "qdd_max"))
               for k in defaults if k not in ("grid", "qd_grid")}
        if np.any(vec["q_min"] >= vec["q_max"]):
            raise ParameterError("params.q_max", "numbers above q_min", list(vec["q_max"]))
        grid = _count(params, "grid", defaults, 2, MAX_GRID[n])
        qd_grid = _count(params, "qd_grid", defaults, 2, 21) if integrating else None
        for i in range(n):
            g = spec.geom(f"link{i}")
            g.fromto = [0, 0, 0, 0, 0, vec["link_lengths"][i]]
            g.mass = vec["link_masses"][i]
            j = spec.joint(f"joint{i}")
            j.frictionloss = vec["friction"][i]
            j.armature = vec["armature"][i]
            j.damping = [vec["damping"][i], 0.0, 0.0]
            if i + 1 < n:
                spec.body(f"link{i + 1}").pos = [0, 0, vec["link_lengths"][i]]
            if integrating:  # the motor integrates its input: act' = ctrl, torque = act (N m)
                a = spec.actuator(f"joint{i}")
                a.dyntype = mujoco.mjtDyn.mjDYN_INTEGRATOR
        spec.site("tip").pos = [0, 0, vec["link_lengths"][n - 1]]
        loops = [ChainLoop(f"joint{i}", f"joint{i}", f"joint{i}", integrating) for i in range(n)]
        super().__init__(model_name, spec, loops)
        self.params = {k: v.tolist() for k, v in vec.items()}
        self.params["grid"] = grid
        if integrating:
            self.params["qd_grid"] = qd_grid
        self.friction = vec["friction"]
        self.q_min, self.q_max, self.qd_max, self.u_max = vec["q_min"], vec["q_max"], vec["qd_max"], vec["u_max"]
        self.workspace = Workspace(q_min=self.q_min, q_max=self.q_max, qd_max=self.qd_max, u_max=self.u_max,
                                   qdd_max=vec.get("qdd_max"), grid=grid, qd_grid=qd_grid or 5)
        self.phi_units = "N m/s (injected joint torque rate)" if integrating else "N m (injected joint torque)"
        self.gamma_units = "motor gain factor (dimensionless, nominal 1; chain gamma = factor x (M^-1)_ii)"
        self.body_names = tuple(f"link{i}" for i in range(n))


register_plant("arm", ArmPlant, "r = 2, loops 'joint0', 'joint1': two stacked hinge joints in a vertical plane "
               "(params: link_lengths, link_masses, armature, friction, damping; bounds' workspace: "
               "q_min, q_max, qd_max, u_max, grid)")
register_plant("arm_integrating", ArmPlant, "r = 3, loops 'joint0', 'joint1': the arm whose motors integrate the "
               "control (u = torque rate, z_3 = q'' from angular-acceleration sensors; workspace adds qdd_max, qd_grid)")
register_plant("arm3", ArmPlant, "r = 2, loops 'joint0'..'joint2': three stacked hinge joints in a vertical plane "
               "(same params as arm, three values each)")

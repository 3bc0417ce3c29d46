"""The ideal chain as a plant: z_i' = z_{i+1} (i < r), z_r' = phi(t) + gamma(t) u, for r = 1..6.

A mechanism gives a chain longer than 3 only through its structure (plants/flexible_joint.py: a link
driven through a spring, r = 4 or 5, with phi from the spring and gravity); the exact chain, with
phi and gamma chosen freely, for any r, is no MuJoCo model. Here the chain is integrated
exactly by :meth:`IdealChainPlant.step` and MuJoCo only holds and shows the state:

* the model has r bodies "z1".."zr", each on its own slide joint along x (rails 0.3 m apart in y),
  with qpos[i] = z_{i+1} (qpos[0] = ref + z_1): a bar chart of the state in the 3D view, and the
  state saved and restored with the rest (``mjSTATE_INTEGRATION``). qvel stays 0.
* one actuator "u" on the last joint is where the run loop writes ctrl = gamma(t) u, and the
  injected disturbance goes to that joint's qfrc_applied = phi(t) (chain units, dist_scale 1).
* one physics step of length h (``step``, in place of ``mj_step``): ``mj_forward`` (the control
  callback samples there, ftstab_mj/simulation/run_loop.py, and the kinematics of the view are computed), then, with
  w = qfrc_applied + ctrl held over the step, z(t + h) = Phi(h) z(t) + G(h) w with
  Phi_ij = h^(j-i) / (j-i)! (j >= i) and G_i = h^(r-i+1) / (r-i+1)! (ftstab_mj.control.chain.chain_transition),
  which is exact for a piecewise-constant input, and time += h.

So a run is the ideal chain of ftstab_mj.simulation.ideal_chain.simulate_chain with ``substeps`` = physics
steps per period (tests/test_plants_ideal.py compares the two), recorded and logged like any plant.
MuJoCo's accelerations are computed by mj_forward and ignored. The integrator is exact, so
``sim.integrator`` must be "euler" (MuJoCo's integrators play no part); the native callback, which
steps with mj_step in C, does not run this plant (the Python callback does).
"""

from __future__ import annotations

import mujoco
import numpy as np

from ftstab_mj.config.errors import ParameterError
from ftstab_mj.control.chain import chain_transition
from ftstab_mj.plants.base import Plant, check_keys, register_plant

R_MAX = 6  # chain lengths 1..R_MAX (those the certificate handles)

_BODY = """
    <body name="z{i}" pos="0 {y:g} 0">
      <joint name="z{i}" type="slide" axis="1 0 0"/>
      <geom type="sphere" size="0.05" rgba="{rgba}"/>
    </body>"""
_MODEL = """<mujoco model="ideal_chain_r{r}">
  <option gravity="0 0 0"><flag contact="disable"/></option>
  <worldbody>{bodies}
  </worldbody>
  <actuator><general name="u" joint="z{r}"/></actuator>
</mujoco>
"""


def chain_model_xml(r: int) -> str:
    """The MJCF of the display model for chain length r (body and joint "z<i>" at y = 0.3 (i - 1) m)."""
    bodies = "".join(_BODY.format(i=i, y=0.3 * (i - 1), rgba="0.9 0.3 0.2 1" if i == 1 else "0.3 0.5 0.9 1")
                     for i in range(1, r + 1))
    return _MODEL.format(r=r, bodies=bodies)


class IdealChainPlant(Plant):
    """The ideal chain of length ``params["r"]`` (default 2), one loop "chain" (module docstring)."""

    exact_chain_twin = True

    def __init__(self, model_name: str, params: dict):
        check_keys(model_name, params, ("r",))
        r = params.get("r", 2)
        if isinstance(r, bool) or not isinstance(r, int) or not 1 <= r <= R_MAX:
            raise ParameterError("params.r", f"an integer chain length 1..{R_MAX}", r)
        super().__init__(mujoco.MjSpec.from_string(chain_model_xml(r)))
        self.model_name = model_name
        self.params = {"r": r}
        self.r = r
        self.loop_names = ("chain",)
        self.dist_scale = np.array([1.0])
        self.dof_ids = np.array([r - 1], dtype=np.int32)  # qfrc_applied of the last joint holds phi
        self.actuator_ids = np.array([0], dtype=np.int32)
        self.body_names = tuple(f"z{i}" for i in range(1, r + 1))
        self.phi_units = f"chain units (z_{r}' = phi + gamma u)"
        self.gamma_units = "chain units per unit u"

    integrators = ("euler",)  # the name only: the plant integrates exactly, no MuJoCo integrator runs

    def compile(self, physics_step: float, integrator: str = "euler", nuserdata: int = 0):
        self._Phi, self._G = chain_transition(self.r, float(physics_step))
        return super().compile(physics_step, integrator, nuserdata)

    def step(self, m, d) -> None:
        """One physics step: the forward pass (the control callback samples there), then the exact
        transition of the chain with w = qfrc_applied + ctrl held over the step."""
        mujoco.mj_forward(m, d)
        w = d.qfrc_applied[self.r - 1] + d.ctrl[0]
        d.qpos[:] = d.qpos @ self._Phi.T + w * self._G  # as simulate_chain writes it: the same bits
        d.time += m.opt.timestep

    def set_initial(self, m, d, q0, z0):
        d.qpos[0] = q0[0]
        d.qpos[1:] = z0[0, 1:]

    def sense(self, d, z):
        z[0, :] = d.qpos

    def true_chain(self, m, d, u, gain, phi_inj):
        return phi_inj.copy(), gain.copy()

    def true_bounds(self, phi_bounds, gamma_bounds):
        (plo, phi_hi), = phi_bounds
        (glo, ghi), = gamma_bounds
        return np.array([max(abs(plo), abs(phi_hi))]), np.array([glo]), np.array([ghi])


register_plant("ideal_chain", IdealChainPlant,
               f"r = params.r (1..{R_MAX}, default 2), one loop 'chain': the ideal chain z_i' = z_(i+1), "
               "z_r' = phi + gamma u, integrated exactly (MuJoCo only shows it: body z<i> at x = z_i)")

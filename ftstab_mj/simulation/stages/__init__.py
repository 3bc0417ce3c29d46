"""What sits between the plant and the law in a physical loop: sensor, observer, actuator.

Plain NumPy (no MuJoCo import), so each stage is checked on its own against its theory:

* :mod:`.sensor`: what the controller reads (noise, quantization, delay, which components);
* :mod:`.levant`: Levant's robust exact differentiator, which rebuilds the chain state from the
  measured position;
* :mod:`.actuator`: what the plant receives (saturation, dead zone, rate limit, first-order lag).

Per control sample k the loop is a pipeline
``z(k) -> sensor -> z_measured(k) -> observer -> z_hat(k) -> law -> u(k) -> actuator -> u_applied``.
Every stage that has memory keeps it in a flat float array (its *state*), which the run loop
stores in the simulation state so that saving and restoring a run is exact.
"""

from ftstab_mj.simulation.stages.actuator import ActuatorModel
from ftstab_mj.simulation.stages.differentiator import LevantDifferentiator
from ftstab_mj.simulation.stages.sensor import SensorModel

__all__ = ["ActuatorModel", "LevantDifferentiator", "SensorModel"]

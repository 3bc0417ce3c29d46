"""The C twin of the loop stages (kernel.c ft_stage, ftstab_mj/simulation/native/stages.py) against the NumPy
pipeline (loop_stages/pipeline.py), over every stage and option, sample for sample.

Tolerance 1e-12 relative (measured here: bit-identical): both run the same operations in the same order; NumPy's SIMD pow and
libm's pow may differ by one ulp, and the differentiator's discontinuous sign can turn such an ulp
into a different branch only where its argument is within rounding of 0 (not met on these inputs).
"""

import itertools

import numpy as np
import pytest

from ftstab_mj.simulation import native
from ftstab_mj.simulation.stages import ActuatorModel, LevantDifferentiator, SensorModel
from ftstab_mj.simulation.stages.pipeline import LoopStages

pytestmark = pytest.mark.skipif(not native.available(), reason=native.UNAVAILABLE_REASON or "")

SENSORS = {
    "ideal": lambda r: SensorModel(),
    "state_noisy_quantized_delayed": lambda r: SensorModel(noise=(1e-3,) * r, quantum=(1e-4,) + (0.0,) * (r - 1),
                                                           delay=2, seed=5),
    "position_gaussian": lambda r: SensorModel(measured="position", noise=(1e-3,), noise_kind="gaussian", seed=1),
    "position_quantized_delayed": lambda r: SensorModel(measured="position", quantum=(1e-3,), delay=3),
}
RTOL = 1e-12
ACTUATORS = {
    "ideal": ActuatorModel(),
    "all": ActuatorModel(u_max=3.0, rate_max=200.0, tau=0.02, dead_zone=0.1),
    "lag": ActuatorModel(tau=0.005),
    "second_order_lag": ActuatorModel(tau=0.003, lag_order=2, u_max=4.5),
}


@pytest.mark.parametrize("r,sensor,filter_order,actuator",
                         [(r, s, nf, a) for r, s, nf, a in itertools.product((2, 3), SENSORS, (0, 1), ACTUATORS)
                          if nf == 0 or s.startswith("position")])  # the filter order is the observer's
def test_native_stages_equal_the_numpy_pipeline(r, sensor, filter_order, actuator):
    from ftstab_mj.simulation.native import stages as native_stages

    sens = SENSORS[sensor](r)
    observer = LevantDifferentiator(r - 1 + (sensor == "position_gaussian"), 5.0, filter_order) \
        if sens.measured == "position" else None
    st = LoopStages(sens, observer, ACTUATORS[actuator], r=r, period=0.01, N=10, stream=1)
    n = 400
    t = np.arange(n) * 0.01
    z = np.stack([np.sin(3 * t + i) * 0.5 ** i for i in range(r)], axis=1)
    u = 4.0 * np.sign(np.sin(7 * t)) + np.cos(t)
    py_state, c_state = np.full(st.state_size, 7.0), np.full(st.state_size, 7.0)  # junk before sample 0
    zm_py, zh_py, steps_py = [], [], []
    for k in range(n):
        zm, zh = st.measure(z[k], k, py_state)
        ua, steps = st.actuate(u[k], k, py_state, 0.001)
        zm_py.append(zm), zh_py.append(zh), steps_py.append(steps)
    # the C side in two batches (the state carries over; the noise table is per batch)
    zm1, zh1 = native_stages.measure(st, 0, z[:150], c_state)
    zm2, zh2 = native_stages.measure(st, 150, z[150:], c_state)
    c_meas_state = c_state.copy()
    c_state[:] = 7.0
    s1 = native_stages.actuate(st, 0, u[:150], c_state, 0.001)
    s2 = native_stages.actuate(st, 150, u[150:], c_state, 0.001)
    for a, b in ((np.concatenate([zm1, zm2]), zm_py), (np.concatenate([zh1, zh2]), zh_py),
                 (np.concatenate([s1, s2]), steps_py)):
        np.testing.assert_allclose(a, np.array(b), rtol=RTOL, atol=1e-15)
    act = st._slices[2]
    np.testing.assert_allclose(c_state[act], py_state[act], rtol=RTOL, atol=1e-15)
    np.testing.assert_allclose(c_meas_state[:act.start], py_state[:act.start], rtol=RTOL, atol=1e-15)

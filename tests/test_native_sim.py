"""The native control callback (ftstab_mj/native/run.py) against the Python run loop (sim.py).

Same scenario, both paths: every recorded field of every sample and the body poses agree to
1e-12 (relative to max(1, |value|); the only differences are NumPy's SIMD pow vs libm's pow and
one extra rounding in V1, see tests/test_native.py), the statuses and messages are the same, and
the saved simulation state between batches is the same.
"""

import ctypes

import mujoco
import numpy as np
import pytest

from ftstab_mj import native
from ftstab_mj.control import AdaptiveLaw, HongController, RobustLaw
from ftstab_mj.disturbances import Signal
from ftstab_mj.native import run as native_run
from ftstab_mj.plants import make_plant
from ftstab_mj.records import DIVERGED, LOOP_FIELDS
from ftstab_mj.sim import LoopSpec, Simulation, simulate

TOL = 1e-12
pytestmark = pytest.mark.skipif(not native.available(), reason=f"native kernel: {native.UNAVAILABLE_REASON}")

HONG = {2: HongController(2, -0.2, (1.0, 2.0)), 3: HongController(3, -0.1, (1.0, 1.7, 5.0))}


def loop(r, law_kind, phi, z0=None):
    law = RobustLaw(HONG[r], 0.5, 0.8) if law_kind == "robust" else AdaptiveLaw(HONG[r], 1.0, 0.5, 2.0, 0.5, 0.05)
    return LoopSpec("cart", controller=law, disturbance=phi, gain=Signal("sine", 1.0, 0.2, freq=0.5), z0=z0 or ((1.0, 0.0) if r == 2 else (1.0, 0.0, 0.0)))


def assert_same_run(ref, fast):
    assert (fast.status, fast.message) == (ref.status, ref.message)
    assert fast.n_samples == ref.n_samples
    for f in LOOP_FIELDS:
        a, b = ref.loops["cart"][f], fast.loops["cart"][f]
        err = np.max(np.abs(b - a) / np.maximum(1.0, np.abs(a)), initial=0.0)
        assert err <= TOL, f"{f}: max relative difference {err:.3g}"
    np.testing.assert_allclose(fast.body_pos, ref.body_pos, rtol=0, atol=TOL)
    np.testing.assert_allclose(fast.body_quat, ref.body_quat, rtol=0, atol=TOL)


CASES = [  # model, plant params, r, law, phi, steps per period
    ("cart", {"damping": 0.3}, 2, "robust", Signal("sine", 0.0, 0.4, freq=1.0), 1),
    ("cart", {}, 2, "adaptive", Signal("worst_case", 0.0, 0.4), 4),
    ("cart_integrating", {}, 3, "robust", Signal("worst_case", 0.0, 0.4), 1),
    ("cart_integrating", {}, 3, "adaptive", Signal("random", 0.0, 0.4, freq=3.0, seed=1), 3),
    ("cart_integrating", {"sensor_refresh": False}, 3, "robust", Signal("sine", 0.0, 0.4, freq=1.0), 2),
]


@pytest.mark.parametrize("model,params,r,law,phi,N", CASES,
                         ids=[f"{c[0]}-{c[3]}-{c[4].kind}-N{c[5]}{'-norefresh' if c[1].get('sensor_refresh') is False else ''}"
                              for c in CASES])
def test_native_and_python_runs_record_the_same_samples(model, params, r, law, phi, N):
    """2.5 s, in batches that do not divide the run."""
    plant = make_plant(model, params)
    args = (plant, [loop(r, law, phi)], 2.5, N * 1e-3, 1e-3)
    ref = simulate(*args, batch_size=700, native=False)
    fast = simulate(*args, batch_size=700, native=True)
    assert_same_run(ref, fast)
    # not a trivial run: V1 fell tenfold and the discontinuous term switched sign many times
    rec = ref.loops["cart"]
    assert rec["V1"][-1] < 0.1 * rec["V1"][0]
    assert np.count_nonzero(np.diff(np.sign(rec["u0"]))) > 10


@pytest.mark.parametrize("model", ["cart", "cart_integrating"])
def test_saved_state_between_batches_is_the_same(model):
    """After each batch the whole integration state (qpos, qvel, act, ctrl, qfrc_applied, phi_hat in
    userdata, time) is what the Python loop leaves, so save/restore works across both paths."""
    r = 2 if model == "cart" else 3
    sims = [Simulation(make_plant(model), [loop(r, "adaptive", Signal("sine", 0.0, 0.4, freq=1.0))], 2e-3, 1e-3,
                       native=flag) for flag in (False, True)]
    assert sims[0]._native is None and sims[1]._native is not None
    for n in (150, 250):
        states = []
        for sim in sims:
            with sim.installed():
                sim.advance(n)
            states.append(sim.get_state())
        np.testing.assert_allclose(states[1], states[0], rtol=1e-12, atol=1e-12)
    # restore the Python run's state into the native run and continue: the same again
    sims[1].set_state(sims[0].get_state())
    out = []
    for sim in sims:
        with sim.installed():
            out.append(sim.advance(100).loops["cart"]["z"])
    np.testing.assert_allclose(out[1], out[0], rtol=1e-12, atol=1e-12)


def test_divergence_stops_both_paths_at_the_same_sample():
    plant = make_plant("cart")
    args = (plant, [loop(2, "robust", Signal("constant", 0.0), z0=(1.0, 0.0))], 2.0, 1e-3, 1e-3)
    ref = simulate(*args, divergence_limit=0.9, batch_size=300, native=False)
    fast = simulate(*args, divergence_limit=0.9, batch_size=300, native=True)
    assert ref.status == DIVERGED and "beyond the divergence limit 0.9" in ref.message
    assert_same_run(ref, fast)


def test_auto_uses_python_where_the_callback_cannot_run():
    """RK4 calls the callback four times per step: "auto" runs Python, True says why it cannot."""
    plant = make_plant("cart")
    loops = [loop(2, "robust", Signal("sine", 0.0, 0.4, freq=1.0))]
    assert Simulation(plant, loops, 1e-3, 1e-3, integrator="rk4", native="auto")._native is None
    assert Simulation(plant, loops, 1e-3, 1e-3, integrator="euler", native="auto")._native is not None
    with pytest.raises(native.NativeUnavailable, match="one forward pass per step"):
        Simulation(plant, loops, 1e-3, 1e-3, integrator="rk4", native=True)


def test_time_address_is_the_simulation_time():
    m = mujoco.MjModel.from_xml_string("<mujoco><worldbody><body><joint type='slide'/><geom size='.1'/>"
                                       "</body></worldbody></mujoco>")
    d = mujoco.MjData(m)
    d.time = 0.25
    cell = ctypes.c_double.from_address(native_run.time_address(d))
    assert d.time == 0.25 and cell.value == 0.25  # found, and put back
    mujoco.mj_step(m, d, nstep=3)
    assert cell.value == d.time

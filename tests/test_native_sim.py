"""The native control callback (ftstab_mj/simulation/native/run.py) against the Python run loop (sim.py).

Same scenario, both paths: every recorded field of every sample and the body poses agree to
1e-12 (relative to max(1, |value|); the only differences are NumPy's SIMD pow vs libm's pow and
one extra rounding in V1, see tests/test_native.py), the statuses and messages are the same, and
the saved simulation state between batches is the same.
"""

import ctypes

import mujoco
import numpy as np
import pytest

from ftstab_mj.simulation import native
from ftstab_mj.control import AdaptiveLaw, HongController, NominalLaw, RobustLaw
from ftstab_mj.plants.disturbances import Signal
from ftstab_mj.simulation.native import run as native_run
from ftstab_mj.plants import make_plant
from ftstab_mj.plants.base import Plant
from ftstab_mj.simulation.records import DIVERGED, LOOP_FIELDS
from ftstab_mj.scenario import LoopSpec

from ftstab_mj.simulation.run_loop import Simulation, simulate

TOL = 1e-12
pytestmark = pytest.mark.skipif(not native.available(), reason=f"native kernel: {native.UNAVAILABLE_REASON}")

HONG = {2: HongController(2, -0.2, (1.0, 2.0)), 3: HongController(3, -0.1, (1.0, 1.7, 5.0))}


def loop(r, law_kind, phi, z0=None):
    law = RobustLaw(HONG[r], 0.5, 0.8) if law_kind == "robust" else AdaptiveLaw(HONG[r], 1.0, 0.5, 2.0, 0.5, 0.05)
    return LoopSpec("cart", controller=law, disturbance=phi, gain=Signal("sine", 1.0, 0.2, freq=0.5), z0=z0 or ((1.0, 0.0) if r == 2 else (1.0, 0.0, 0.0)))


def assert_same_run(ref, fast):
    assert (fast.status, fast.message) == (ref.status, ref.message)
    assert fast.n_samples == ref.n_samples
    assert fast.loops.keys() == ref.loops.keys()
    for name in ref.loops:
        for f in LOOP_FIELDS:
            a, b = ref.loops[name][f], fast.loops[name][f]
            err = np.max(np.abs(b - a) / np.maximum(1.0, np.abs(a)), initial=0.0)
            assert err <= TOL, f"{name} {f}: max relative difference {err:.3g}"
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


LAWS3 = {"nominal": lambda h: NominalLaw(h), "robust": lambda h: RobustLaw(h, 0.5, 0.8),
         "adaptive": lambda h: AdaptiveLaw(h, 1.0, 0.5, 2.0, 0.5, 0.05)}
GRID = [(integrator, model, N, law) for integrator in ("euler", "implicitfast") for model in ("cart", "cart_integrating")
        for N in (1, 5) for law in LAWS3]


@pytest.mark.parametrize("integrator,model,N,law", GRID, ids=["-".join(map(str, c)) for c in GRID])
def test_twins_agree_over_their_whole_support(integrator, model, N, law):
    """Every combination the native callback takes: {euler, implicitfast} x {cart, cart_integrating}
    x {1, 5} physics steps per period x {nominal, robust, adaptive}; 0.6 s in batches of 70, with a
    sine disturbance and gain (the nominal law without one: it assumes none)."""
    r = 2 if model == "cart" else 3
    phi = Signal("constant", 0.0) if law == "nominal" else Signal("sine", 0.0, 0.4, freq=2.0)
    lp = LoopSpec("cart", controller=LAWS3[law](HONG[r]), disturbance=phi, gain=Signal("sine", 1.0, 0.2, freq=1.5),
                  z0=(0.3,) + (0.0,) * (r - 1))
    args = (make_plant(model), [lp], 0.6, N * 1e-3, 1e-3, integrator)
    ref = simulate(*args, batch_size=70, native=False)
    fast = simulate(*args, batch_size=70, native=True)
    assert_same_run(ref, fast)
    rec = ref.loops["cart"]
    assert ref.n_samples == round(600 / N) and rec["V1"][-1] < 0.5 * rec["V1"][0]  # the controller acted


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


# -- two loops in one native run -------------------------------------------------------------------
TWO_CARTS = """<mujoco><option gravity="0 0 0"/><worldbody>
  <body name="a"><joint name="xa" type="slide" axis="1 0 0"/>
    <geom type="box" size=".1 .1 .1" mass="1" contype="0" conaffinity="0"/></body>
  <body name="b" pos="0 1 0"><joint name="xb" type="slide" axis="1 0 0"/>
    <geom type="box" size=".1 .1 .1" mass="2" contype="0" conaffinity="0"/></body>
</worldbody>
<actuator><motor joint="xa" gear="1"/><motor joint="xb" gear="2"/></actuator>
<sensor><jointpos name="pa" joint="xa"/><jointvel name="va" joint="xa"/>
  <jointpos name="pb" joint="xb"/><jointvel name="vb" joint="xb"/></sensor></mujoco>"""


class TwoCarts(Plant):
    """Two independent carts (1 kg with gear 1, 2 kg with gear 2: both x'' = gain u + phi, chain
    units), loops "a" and "b": the native callback's indexing over loops (sensor map (n, r), records
    (n, k), one law state in userdata for one loop only) against the Python loop's."""

    def __init__(self):
        super().__init__(mujoco.MjSpec.from_string(TWO_CARTS))
        self.model_name, self.params, self.loop_names, self.r = "two_carts", {}, ("a", "b"), 2
        self.dist_scale, self.body_names = np.array([1.0, 2.0]), ("a", "b")

    def bind(self, m):
        self._adr = np.array([[self.sensor_block(m, f"{k}{c}").start for k in "pv"] for c in "ab"])

    def set_initial(self, m, d, q0, z0):
        d.qpos[:2], d.qvel[:2] = q0, z0[:, 1]

    def sense(self, d, z):
        z[:] = d.sensordata[self._adr]

    def true_chain(self, m, d, u, gain, phi_inj):
        return phi_inj.copy(), gain.copy()

    def native_sensing(self, m):
        return self._adr, np.zeros(2), self.dist_scale

    def true_bounds(self, phi_bounds, gamma_bounds):
        phi, g = np.abs(np.array(phi_bounds)).max(axis=1), np.array(gamma_bounds)
        return phi, g[:, 0], g[:, 1]


@pytest.mark.parametrize("integrator,N", [("euler", 1), ("implicitfast", 5)])
def test_a_plant_with_two_loops_runs_natively_as_in_python(integrator, N):
    loops = [LoopSpec("a", controller=RobustLaw(HONG[2], 0.5, 0.8), disturbance=Signal("sine", 0.0, 0.4, freq=2.0),
                      gain=Signal("sine", 1.0, 0.2, freq=1.5), z0=(0.3, 0.0)),
             LoopSpec("b", controller=AdaptiveLaw(HONG[2], 1.0, 0.5, 2.0, 0.5, 0.05),
                      disturbance=Signal("worst_case", 0.0, 0.3), z0=(-0.5, 0.2))]
    args = (TwoCarts(), loops, 0.6, N * 1e-3, 1e-3, integrator)
    ref = simulate(*args, batch_size=70, native=False)
    fast = simulate(*args, batch_size=70, native=True)
    assert_same_run(ref, fast)
    a, b = ref.loops["a"], ref.loops["b"]
    assert not np.array_equal(a["z"], b["z"]) and np.all(a["phi_hat"] == 0.5 / 0.8) and b["phi_hat"][-1] > 0


def test_the_arm_twin():
    """The arm (two loops) runs natively (its readout and true phi through kernel.c's ft_chain): the
    native run agrees with the Python one."""
    from ftstab_mj.plants.arm import ArmPlant  # noqa: F401 - the registered "arm"

    plant = make_plant("arm")
    loops = [LoopSpec(f"joint{i}", controller=RobustLaw(HONG[2], 10.0, 1.0), z0=(0.2, 0.0), ref=0.3 * i)
             for i in range(2)]
    args = (plant, loops, 0.3, 1e-3, 1e-3)
    assert_same_run(simulate(*args, native=False), simulate(*args, native=True))


# -- the buffers the C side writes are checked where they are used ----------------------------------
def _batch_arrays(k=3, n=1, r=2, nbody=1):
    return dict(t=np.zeros(k), inj=np.zeros((k, n)), gain=np.ones((k, n)), force=np.zeros((k, n)),
                ctrl_steps=np.zeros((k, n)), rec_t=np.zeros(k), rec_z=np.zeros((n, k, r)),
                rec=[np.zeros((n, k)) for _ in range(8)], body_pos=np.zeros((k, nbody, 3)),
                body_quat=np.zeros((k, nbody, 4)))


@pytest.mark.parametrize("name,bad,named", [
    ("rec_z", np.zeros((1, 2, 2)), "rec_z"),  # one sample short: the C side would write past it
    ("inj", np.zeros((3, 2))[:, :1], "inj"),  # not contiguous
    ("body_quat", np.zeros((3, 1, 4), dtype=np.float32), "body_quat"),
    ("t", np.zeros(4), "inj"),  # 4 samples announced, the step inputs hold 3
])
def test_a_wrong_buffer_is_refused_before_the_native_batch(name, bad, named):
    sim = Simulation(make_plant("cart"), [loop(2, "robust", Signal("constant", 0.0))], 1e-3, 1e-3, native=True)
    arrays = _batch_arrays()
    arrays[name] = bad
    t0 = sim.data.time
    with pytest.raises(ValueError, match=f"native buffer {named}"):
        sim._native.run_batch(sim.model, sim.data, **arrays)
    assert sim.data.time == t0  # nothing was stepped


def test_the_buffer_check_survives_python_O():
    """A raised check, not an assert: `python -O` keeps it."""
    import subprocess
    import sys

    code = ("import numpy as np, sys; sys.path.insert(0, 'tests'); import test_native_sim as t; "
            "sim = t.Simulation(t.make_plant('cart'), [t.loop(2, 'robust', t.Signal('constant', 0.0))], 1e-3, 1e-3,"
            " native=True); a = t._batch_arrays(); a['rec_z'] = np.zeros((1, 2, 2))\n"
            "try:\n    sim._native.run_batch(sim.model, sim.data, **a)\nexcept ValueError as e:\n    print('refused', e)")
    out = subprocess.run([sys.executable, "-O", "-c", code], capture_output=True, text=True, timeout=120,
                         cwd=str(__import__("pathlib").Path(__file__).resolve().parent.parent))
    assert out.returncode == 0 and out.stdout.startswith("refused native buffer rec_z"), out.stderr


"""The run loop: callback hygiene, errors, outcomes, determinism, save/restore."""

import mujoco
import numpy as np
import pytest

from conftest import record_run
from ftstab_mj.control import AdaptiveLaw, HongController, RobustLaw
from ftstab_mj.plants.disturbances import Signal
from ftstab_mj.config.errors import CallbackError, ParameterError
from ftstab_mj.plants import make_plant
from ftstab_mj.simulation.records import COMPLETED, DIVERGED, FAILED, INTERRUPTED, LOOP_FIELDS
from ftstab_mj.scenario import LoopSpec

from ftstab_mj.simulation.run_loop import Simulation, control_callback, simulate

HONG2 = HongController(2, -0.2, (1.0, 2.0))
HONG3 = HongController(3, -0.1, (1.0, 1.7, 5.0))
ROBUST2 = RobustLaw(HONG2, phibar=0.5, gamma_m=0.8)
ADAPTIVE3 = AdaptiveLaw(HONG3, kappa=1.0, delta=0.1, rate=2.0, eta=0.5, eps=1e-3)


class RecordingSink:
    """A sink that keeps what it is given."""

    def __init__(self):
        self.info, self.batches, self.closed = None, [], None

    def open(self, info):
        self.info = info

    def write(self, batch):
        self.batches.append(batch)

    def close(self, status, metrics, message=""):
        self.closed = (status, metrics, message)

    def field(self, loop, name):
        return np.concatenate([b.loops[loop][name] for b in self.batches])


class FailingLaw:
    """Wraps a law and raises `exc` at the `at`-th evaluation (to test the callback's error path)."""

    def __init__(self, law, at, exc):
        self.law, self.at, self.exc, self.calls = law, at, exc, 0

    def __getattr__(self, name):  # the rest of the law protocol: the wrapped law's
        return getattr(self.law, name)

    def for_period(self, h):  # keep wrapping the law the run loop will use
        self.law = self.law.for_period(h)
        return self

    def evaluate(self, z, state):
        self.calls += 1
        if self.calls == self.at:
            raise self.exc
        return self.law.evaluate(z, state)


def _cart_loops(law=ROBUST2, **kw):
    return [LoopSpec("cart", controller=law, disturbance=Signal("sine", amplitude=0.4, freq=1.0),
                     gain=Signal("random", offset=1.0, amplitude=0.2, freq=3.0, seed=3), z0=(1.0, 0.0), **kw)]


def _previous_callback(m, d):
    """Stands for a callback someone installed before our run."""


def test_a_run_hands_every_sample_to_the_sinks_and_returns_the_same_arrays():
    sink = RecordingSink()
    res = record_run(make_plant("cart"), _cart_loops(), duration=1.0, period=0.01, physics_step=0.002, sinks=[sink],
                     batch_size=30, scenario_dict={"name": "x"})
    assert res.status == COMPLETED and res.message == ""
    assert res.n_samples == 100 and [len(b) for b in sink.batches] == [30, 30, 30, 10]
    assert sink.closed[0] == COMPLETED
    for f in LOOP_FIELDS:
        np.testing.assert_array_equal(sink.field("cart", f), res.loops["cart"][f])
    np.testing.assert_allclose(res.loops["cart"]["t"], np.arange(100) * 0.01, rtol=0, atol=1e-12)
    assert res.body_pos.shape == (100, 1, 3) and res.body_quat.shape == (100, 1, 4)
    np.testing.assert_array_equal(res.body_pos[:, 0, 0], res.loops["cart"]["z"][:, 0])  # cart body at x
    info = sink.info
    assert info is res.info and info.scenario == {"name": "x"} and info.body_names == ("cart",)
    rebuilt = mujoco.MjModel.from_xml_string(info.model_xml)  # the MJCF simulated, step included
    assert rebuilt.opt.timestep == 0.002 and rebuilt.body_mass[1] == 1.0 and rebuilt.actuator_gainprm[0, 0] == 1.0
    (loop,) = info.loops
    assert (loop.law, loop.r, loop.law_params) == ("robust", 2, {"phibar": 0.5, "gamma_m": 0.8, "discretization": "explicit"})
    assert (loop.true_phibar, loop.true_gamma_m, loop.true_gamma_M) == (0.4, 0.8, 1.2)


def test_same_inputs_give_bit_identical_samples():
    a = simulate(make_plant("cart_integrating"), [LoopSpec("cart", controller=ADAPTIVE3, disturbance=Signal("random", amplitude=0.5, seed=7),
                                                           gain=Signal("sine", offset=1.0, amplitude=0.3), z0=(1, 0, 0))],
                 duration=1.0, period=0.01, physics_step=0.001)
    b = simulate(make_plant("cart_integrating"), [LoopSpec("cart", controller=ADAPTIVE3, disturbance=Signal("random", amplitude=0.5, seed=7),
                                                           gain=Signal("sine", offset=1.0, amplitude=0.3), z0=(1, 0, 0))],
                 duration=1.0, period=0.01, physics_step=0.001)
    for f in LOOP_FIELDS:
        assert np.array_equal(a.loops["cart"][f], b.loops["cart"][f]), f


def test_a_model_compiled_once_per_text_runs_as_a_fresh_compile():
    """Plant.compile keeps compiled models by their MJCF text (a sweep's rows compile their plant
    once per process): the same text gives the same MjModel, another step, integrator or userdata
    size another one, at most COMPILED_MODELS are kept, and a run on a reused model has the samples
    of a run on a fresh compile, bit for bit (the cache emptied before it)."""
    from ftstab_mj.plants import base

    plant = make_plant("cart_integrating")
    m1, d1, x1 = plant.compile(0.001)
    m2, d2, x2 = make_plant("cart_integrating").compile(0.001)
    assert m2 is m1 and d2 is not d1 and x2 == x1
    others = [plant.compile(0.002)[0], plant.compile(0.001, "rk4")[0], plant.compile(0.001, nuserdata=3)[0]]
    assert len({id(m) for m in others + [m1]}) == 4
    for i in range(base.COMPILED_MODELS + 2):
        plant.compile(0.001 * (i + 3))
    assert len(base._COMPILED) == base.COMPILED_MODELS and m1 not in base._COMPILED.values()

    def run():
        return simulate(make_plant("cart_integrating"), [LoopSpec("cart", controller=ADAPTIVE3, z0=(1, 0, 0),
                        disturbance=Signal("random", amplitude=0.5, seed=7))], duration=1.0, period=0.01, physics_step=0.001)

    base._COMPILED.clear()
    fresh = run()
    reused = run()
    for f in LOOP_FIELDS:
        assert np.array_equal(fresh.loops["cart"][f], reused.loops["cart"][f]), f


@pytest.mark.parametrize("integrator", ["euler", "rk4"])
def test_save_continue_restore_continue_is_identical(integrator):
    """The state saved between samples holds everything (phi_hat in userdata, the r = 3 disturbance
    force in qfrc_applied): restoring it replays the continuation bit for bit."""
    loops = [LoopSpec("cart", controller=ADAPTIVE3, disturbance=Signal("random", amplitude=0.8, freq=4.0, seed=1),
                      gain=Signal("sine", offset=1.0, amplitude=0.3, freq=2.0), z0=(1.0, 0.5, 0.0))]
    sim = Simulation(make_plant("cart_integrating"), loops, period=0.01, physics_step=0.002, integrator=integrator)
    with sim.installed():
        sim.advance(150)
        saved = sim.get_state()
        first = sim.advance(100)
        sim.set_state(saved)
        second = sim.advance(100)
        # The state matters: restoring it with phi_hat zeroed gives a different continuation.
        sim.set_state(saved)
        assert sim.data.userdata.shape == (1,) and sim.data.userdata[0] > 0.0  # phi_hat: the one state
        sim.data.userdata[0] = 0.0
        third = sim.advance(100)
    for f in LOOP_FIELDS:
        assert np.array_equal(first.loops["cart"][f], second.loops["cart"][f]), f
    np.testing.assert_array_equal(first.body_pos, second.body_pos)
    assert not np.array_equal(first.loops["cart"]["u"], third.loops["cart"]["u"])


def test_the_law_is_evaluated_once_per_period_even_with_rk4():
    """RK4 calls the callback 4 times a step; the law must still run exactly once per sample."""
    law = FailingLaw(ROBUST2, at=-1, exc=None)
    res = simulate(make_plant("cart"), _cart_loops(law), duration=0.5, period=0.01, physics_step=0.0025, integrator="rk4")
    assert res.n_samples == 50 and law.calls == 50


def test_an_exception_in_the_callback_reaches_the_caller_and_the_previous_callback_is_back():
    sink = RecordingSink()
    law = FailingLaw(ROBUST2, at=40, exc=RuntimeError("law exploded"))
    with control_callback(_previous_callback):
        with pytest.raises(CallbackError, match="law exploded") as err:
            record_run(make_plant("cart"), _cart_loops(law), duration=1.0, period=0.01, physics_step=0.001,
                       sinks=[sink], batch_size=25)
        assert mujoco.get_mjcb_control() is _previous_callback
    assert "t = 0.39" in str(err.value) and isinstance(err.value.__cause__, RuntimeError)
    assert sink.closed[0] == FAILED and "law exploded" in sink.closed[2]
    assert sum(len(b) for b in sink.batches) == 39  # every sample completed before the failure


def test_ctrl_c_stops_the_run_as_interrupted_and_keeps_the_samples():
    sink = RecordingSink()
    law = FailingLaw(ROBUST2, at=61, exc=KeyboardInterrupt())
    res = record_run(make_plant("cart"), _cart_loops(law), duration=1.0, period=0.01, physics_step=0.001,
                     sinks=[sink], batch_size=25)
    assert res.status == INTERRUPTED and "interrupted" in res.message
    assert res.n_samples == 60 and sum(len(b) for b in sink.batches) == 60
    assert sink.closed[0] == INTERRUPTED
    assert mujoco.get_mjcb_control() is None


def test_divergence_stops_the_run_with_a_clear_message_and_keeps_the_samples():
    """A negative actuator gain (the wrong sign) drives the cart away: stopped at |z| > limit."""
    sink = RecordingSink()
    loops = [LoopSpec("cart", controller=ROBUST2, gain=Signal("constant", -1.0), z0=(1.0, 0.0))]
    res = record_run(make_plant("cart"), loops, duration=20.0, period=0.01, physics_step=0.001, sinks=[sink],
                     divergence_limit=50.0)
    assert res.status == DIVERGED and sink.closed[0] == DIVERGED
    assert "beyond the divergence limit 50" in res.message
    z = res.loops["cart"]["z"]
    assert 0 < len(z) < 2000 and np.abs(z).max() <= 50.0 and np.abs(z[-1]).max() > 10.0
    assert sum(len(b) for b in sink.batches) == len(z)


def test_period_must_be_a_multiple_of_the_physics_step_and_the_error_quotes_both():
    with pytest.raises(ParameterError, match=r"period: expected an integer multiple of the physics step 0\.004 s, got 0\.01"):
        simulate(make_plant("cart"), _cart_loops(), duration=1.0, period=0.01, physics_step=0.004)


@pytest.mark.parametrize("model, params, match", [
    ("cartt", {}, "model: expected one of arm, arm_integrating, arm3, cart, cart_integrating, flexible_joint, ideal_chain or the path of an MJCF file"),
    ("cart", {"mas": 1.0}, "params.mas: expected a parameter of model 'cart'"),
    ("cart", {"mass": -1.0}, "params.mass: expected a finite number > 0, got -1.0"),
    ("cart", {"sensor_refresh": False}, "params.sensor_refresh"),
    ("cart_integrating", {"sensor_refresh": 1}, "params.sensor_refresh: expected true or false"),
])
def test_bad_plant_input_names_the_parameter(model, params, match):
    with pytest.raises(ParameterError, match=match):
        make_plant(model, params)


@pytest.mark.parametrize("loops, match", [
    ([], "loops: expected a LoopSpec for every loop of 'cart'"),
    ([LoopSpec("arm", controller=ROBUST2, z0=())], "loops.name: expected a loop of 'cart'"),
    ([LoopSpec("cart", controller=ADAPTIVE3, z0=())], "loops.cart.controller: expected a law for chain length r = 2, got 3"),
    ([LoopSpec("cart", controller=ROBUST2, z0=(1.0,))], "loops.cart.z0: expected 2 finite numbers"),
    ([LoopSpec("cart", controller=ROBUST2, gain=Signal("worst_case", 1.0, 0.1), z0=(1.0, 0.0))], "loops.cart.gain"),
])
def test_bad_loops_are_named(loops, match):
    with pytest.raises(ParameterError, match=match):
        simulate(make_plant("cart"), loops, duration=1.0, period=0.01, physics_step=0.001)


def test_advance_refuses_to_run_without_its_callback():
    sim = Simulation(make_plant("cart"), _cart_loops(), period=0.01, physics_step=0.001)
    with pytest.raises(RuntimeError, match="callback installed"):
        sim.advance(1)


def test_advance_accepts_the_float_drift_of_long_runs_and_refuses_mid_period_calls():
    """d.time is a running sum of steps: after 369,000 steps of 1e-4 s it read 36.900000000101 (a
    sweep row failed with 'advance called between samples'). A drifted sample instant is still a
    sample instant; a step boundary inside a period is not."""
    sim = Simulation(make_plant("cart"), _cart_loops(), period=1e-3, physics_step=1e-4)
    with sim.installed():
        sim.data.time = 36.900000000101
        batch = sim.advance(2)
        assert batch.loops["cart"]["t"].tolist() == [36.9, 36.901]  # sample times from the index, not the drift
        sim.data.time = 36.9003  # three steps into a period
        with pytest.raises(RuntimeError, match="between samples"):
            sim.advance(1)


@pytest.mark.parametrize("native", [False, "auto"])
def test_a_refused_control_stops_the_run_at_its_sample_on_either_path(native):
    """phibar = 1e300: the robust law's u ~ 1e300 at the first sample, a control MuJoCo does not
    apply (beyond 1e10: mjWARN_BADCTRL, no reset). Both paths keep that one sample and say so (the
    kernel steps the rest of its batch: its rows after the refused one are dropped)."""
    law = RobustLaw(HONG2, phibar=1e300, gamma_m=0.8)
    res = simulate(make_plant("cart"), [LoopSpec("cart", controller=law, z0=(1.0, 0.0))], duration=1.0,
                   period=1e-3, physics_step=1e-3, native=native)
    assert res.status == DIVERGED and res.n_samples == 1, res.message
    assert "after the sample at t = 0 s: MuJoCo reported a bad state (mjWARN_BADCTRL x" in res.message
    assert res.message.endswith("and did not apply the control (NaN or beyond 1e10)"), res.message


@pytest.mark.parametrize("native", [False, "auto"])
def test_a_mujoco_warning_stops_the_run_as_diverged(tmp_path, monkeypatch, native):
    """A force so large that qacc exceeds MuJoCo's limit: MuJoCo warns (and resets the data); the
    run stops at the next sample with the warning named, keeping the samples before it."""
    monkeypatch.chdir(tmp_path)  # were MuJoCo's log on (plants/base.quiet_mujoco_log), ./MUJOCO_LOG.TXT
    loops = [LoopSpec("cart", controller=ROBUST2, disturbance=Signal("step", amplitude=1e12, t_step=0.05), z0=(1.0, 0.0))]
    res = simulate(make_plant("cart"), loops, duration=1.0, period=0.01, physics_step=0.001, divergence_limit=1e300,
                   native=native)
    assert res.status == DIVERGED
    assert "after the sample at t = 0.05 s: MuJoCo reported a bad state (mjWARN_BADQACC x1)" in res.message
    assert res.n_samples == 6  # samples at t = 0 .. 0.05; the step at 0.05 blows up within that period

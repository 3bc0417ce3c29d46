"""MuJoCo's profiling timer (mjcb_time) is off while a run steps and put back afterwards."""

import mujoco
import numpy as np

from ftstab_mj.plants.callback import _timer_slot, timer_off
from ftstab_mj.scenario import find_scenario, load_scenario
from ftstab_mj.scenario.run import run_scenario


class _Probe:
    """A sink recording the timer pointer each time it is handed a batch (inside the run)."""

    def __init__(self, fail_at=None):
        self.seen, self.fail_at = [], fail_at

    def open(self, info):
        pass

    def write(self, batch):
        self.seen.append(_timer_slot().value)
        if self.fail_at is not None and len(self.seen) >= self.fail_at:
            raise KeyboardInterrupt  # as a Ctrl-C would, mid-run

    def close(self, status, metrics, message=""):
        pass


def test_the_bindings_install_a_timer_that_set_mjcb_time_none_does_not_remove():
    # The fact timer_off works around: a non-NULL C timer after import, still there after None.
    slot = _timer_slot()
    assert slot is not None and slot.value
    before = slot.value
    mujoco.set_mjcb_time(None)
    assert slot.value == before and mujoco.get_mjcb_time() is None


def test_a_run_steps_without_the_timer_and_puts_it_back():
    slot = _timer_slot()
    before = slot.value
    sc = load_scenario(find_scenario("cart_r2_robust"), ["sim.duration=0.05"])
    probe = _Probe()
    run_scenario(sc, [probe])
    assert probe.seen and all(v is None for v in probe.seen)
    assert slot.value == before
    m = mujoco.MjModel.from_xml_string("<mujoco><worldbody><body><joint/><geom size='1'/></body></worldbody></mujoco>")
    d = mujoco.MjData(m)
    with timer_off():
        mujoco.mj_step(m, d, 10)
    assert d.timer[mujoco.mjtTimer.mjTIMER_STEP].duration == 0.0  # no clock read while off
    mujoco.mj_step(m, d, 10)
    assert d.timer[mujoco.mjtTimer.mjTIMER_STEP].duration > 0.0  # timed again once put back


def test_the_timer_is_put_back_when_a_run_is_interrupted():
    slot = _timer_slot()
    before = slot.value
    sc = load_scenario(find_scenario("cart_r2_robust"), ["sim.duration=0.5"])
    probe = _Probe(fail_at=1)
    run = run_scenario(sc, [probe])
    assert run.result.status == "interrupted" and probe.seen == [None]
    assert slot.value == before and np.isfinite(before)

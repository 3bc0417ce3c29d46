"""Stacked joints as chains (plants/chain.py): the r = 3 arm's chain map, its computed bounds along a
run, and the native callback against the Python one on the arms."""

import numpy as np
import pytest

from ftstab_mj.control import HongController, RobustLaw
from ftstab_mj.plants.disturbances import Signal
from ftstab_mj.plants import make_plant
from ftstab_mj.scenario import find_scenario, load_scenario
from ftstab_mj.scenario import LoopSpec

from ftstab_mj.simulation.run_loop import simulate

HONG3 = HongController(3, -0.1, (1.0, 1.7, 5.0))
HONG2 = HongController(2, -0.2, (1.0, 2.0))


def _loops(plant, hong, phibar=(72.0, 103.0, 30.0), gamma_m=(1.83, 7.49, 8.0)):
    r = plant.r
    return [LoopSpec(name, z0=(-0.3 * (-1) ** i,) + (0.0,) * (r - 1),
                     controller=RobustLaw(hong, phibar[i], gamma_m[i]),
                     disturbance=Signal("sine", amplitude=0.3, freq=0.5),
                     gain=Signal("sine", offset=1.0, amplitude=0.1, freq=0.3), ref=0.3 * (-1) ** i)
            for i, name in enumerate(plant.loop_names)]


def _residual(h):
    """max over the run of |z_3(t + h) - z_3(t) - h (phi + gamma u)| / h^2 per joint, one physics
    step per control period (so the logged increment is one Euler step)."""
    plant = make_plant("arm_integrating")
    res = simulate(plant, _loops(plant, HONG3), duration=0.5, period=h, physics_step=h)
    out = []
    for name in plant.loop_names:
        s = res.loops[name]
        w = s["phi"] + s["gamma"] * s["u"]
        out.append(np.abs(np.diff(s["z"][:, 2]) - h * w[:-1]).max() / h ** 2)
        assert np.abs(w).max() > 50.0  # rad/s^3: gravity, coupling and the law are really there
    return np.array(out)


def test_r3_arm_logged_increment_of_z3_is_phi_plus_gamma_u_to_second_order_in_the_step():
    """z_3 = q'' is read from the links' angular-acceleration sensors; phi and gamma are the model's
    (chain.py). One semi-implicit Euler step of length h moves q by h q'(t + h) = h q' + h^2 q'', q' by
    h q'', act by h ctrl, so q'' changes by h (phi + gamma u) + O(h^2): the residual over h^2 must
    stay put when h halves (a missing term of phi, e.g. the M' q'' of r = 3, would leave an O(h)
    residual: the ratio would fall to 2). Measured: 6.98, 5.02 at 1 ms; 6.61, 4.48 at 0.5 ms."""
    coarse, fine = _residual(1e-3), _residual(5e-4)
    ratio = coarse / fine * 4.0  # residual(h) / residual(h / 2): 4 for a second-order residual
    assert np.all((ratio > 3.2) & (ratio < 4.8)), ratio
    assert np.all(coarse < 20.0)  # rad/s^3 per s^2: the h^2 term is 7e-6 rad/s^2 against h|w| ~ 0.1 at 1 ms


@pytest.mark.parametrize("name", ["arm_r3_robust", "arm3_robust"])
def test_computed_bounds_hold_along_the_run_with_margins(name, capsys):
    """The shipped robust scenarios take phibar and gamma_m "computed" from the model over the
    workspace (chain_bounds.py); along the whole run, which stays in that workspace, the true phi and
    gamma (recorded from the model) stay within the bounds. The margins are printed (pytest -s) and
    listed in the README."""
    sc = load_scenario(find_scenario(name))
    from ftstab_mj.scenario.run import run_scenario

    run = run_scenario(sc, keep_samples=True)
    assert run.result.status == "completed"
    for info in run.result.info.loops:
        s = run.result.loops[info.name]
        m = run.metrics["loops"][info.name]
        assert m["workspace_left"] == "" and m["bound_applies"] is True
        phi_max, g_lo, g_hi = np.abs(s["phi"]).max(), s["gamma"].min(), s["gamma"].max()
        assert phi_max <= info.true_phibar and info.true_gamma_m <= g_lo and g_hi <= info.true_gamma_M
        with capsys.disabled():
            print(f"\n{name} {info.name}: max|phi| {phi_max:.4g} <= phibar {info.true_phibar:.4g} "
                  f"(margin {1 - phi_max / info.true_phibar:.0%}); gamma in [{g_lo:.4g}, {g_hi:.4g}] within "
                  f"[{info.true_gamma_m:.4g}, {info.true_gamma_M:.4g}]")


@pytest.mark.parametrize("model,hong", [("arm", HONG2), ("arm_integrating", HONG3), ("arm3", HONG2)])
def test_native_and_python_callbacks_agree_on_the_arms(model, hong):
    plant = make_plant(model)
    loops = _loops(plant, hong, phibar=(20.0, 20.0, 20.0), gamma_m=(1.5, 1.5, 1.5))
    py = native_and_python_agree(plant, loops)
    assert all(np.abs(py.loops[name]["phi"]).max() > 1.0 for name in plant.loop_names)


def native_and_python_agree(plant, loops):
    """Run ``loops`` 0.3 s with the Python and with the native callback; every recorded field and the
    body poses agree to 1e-12 (relative to the field's size). Returns the Python run."""
    py = simulate(plant, loops, duration=0.3, period=0.002, physics_step=0.001, native=False)
    nat = simulate(plant, loops, duration=0.3, period=0.002, physics_step=0.001, native=True)
    assert py.status == nat.status == "completed"
    for name in plant.loop_names:
        for f, a in py.loops[name].items():
            np.testing.assert_allclose(nat.loops[name][f], a, rtol=0, atol=1e-12 * max(1.0, np.abs(a).max()),
                                       err_msg=f"{plant.model_name} {name} {f}")
    np.testing.assert_allclose(nat.body_pos, py.body_pos, rtol=0, atol=1e-12)
    return py


def test_bounds_are_computed_only_when_asked_and_cached():
    """Building an arm computes no bound table; the first true_bounds does, the next one reuses it."""
    from ftstab_mj.plants import chain_bounds

    chain_bounds._CACHE.clear()
    plant = make_plant("arm_integrating", {"grid": 5, "qd_grid": 3})
    assert not chain_bounds._CACHE
    args = ([(-0.3, 0.3)] * 2, [(0.9, 1.1)] * 2)
    first = plant.true_bounds(*args)
    assert len(chain_bounds._CACHE) == 1
    again = make_plant("arm_integrating", {"grid": 5, "qd_grid": 3}).true_bounds(*args)
    assert len(chain_bounds._CACHE) == 1 and all(np.array_equal(a, b) for a, b in zip(first, again))

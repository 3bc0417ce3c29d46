"""The physical loop on the plants: sensor, observer and actuator stages in the run loop
(ftstab_mj/loop_stages, sim.py, the native callback), checked against identities and theory.

Theory used by the output-feedback test (derived in the module docstring of loop_stages/levant.py
and in README "Physical loop"): near the origin the robust law's discontinuous term holds u0 near
0, a first-order sliding mode on s = z_r - v_(r-1)(z_1..z_(r-1)). Fed by Levant's differentiator of
order r - 1 from a position with noise of amplitude eps, the law sees z_r with an error
O(eps^(1/r)) (the largest of the estimation errors eps^((r-i+1)/r)), so s = O(eps^(1/r)), and Hong's
reduced chain, homogeneous with weights p_i = 1 + (i - 1) k, gives z_i = O(eps^(p_i / (r p_r))).
For r = 2, k = -0.2: z_1 ~ eps^0.625, z_2 ~ eps^0.5.
"""


import numpy as np
import pytest

from ftstab_mj.simulation import native
from ftstab_mj.plants import make_plant
from ftstab_mj.simulation.records import LOOP_FIELDS, STAGE_FIELDS
from ftstab_mj.scenario import SCENARIO_DIR, load_scenario, shipped_scenarios
from ftstab_mj.scenario.run import run_scenario
from ftstab_mj.simulation.run_loop import Simulation, simulate

ROBUST = SCENARIO_DIR / "cart_r2_robust.toml"
R3 = SCENARIO_DIR / "cart_r3_robust.toml"
POSITION = ["loops.cart.sensor.measured=position", "loops.cart.observer.kind=levant"]


def _run(path, sets, native_path="auto"):
    sc = load_scenario(path, sets)
    plant = make_plant(sc.plant.model, sc.plant.params)
    return simulate(plant, sc.loops, duration=sc.sim.duration, period=sc.sim.period,
                    physics_step=sc.sim.physics_step, integrator=sc.sim.integrator,
                    divergence_limit=sc.sim.divergence_limit, native=native_path)


def _same_samples(a, b, fields=LOOP_FIELDS):
    """Bit for bit: every field of every loop and the body poses."""
    for name in a.loops:
        for f in fields:
            assert a.loops[name][f].tobytes() == b.loops[name][f].tobytes(), (name, f)
    assert a.body_pos.tobytes() == b.body_pos.tobytes() and a.body_quat.tobytes() == b.body_quat.tobytes()


@pytest.mark.parametrize("name,path", [(n, p) for n, p, _ in shipped_scenarios()
                                       if not n.startswith(("cart_r2_output", "cart_r3_output", "cart_r2_sat",
                                                            "cart_r2_actuator"))])
def test_stages_at_their_defaults_leave_every_scenario_bit_identical(name, path):
    # (a) the scenario as it is; (b) every stage table given with its defaults (the loop is ideal,
    # so the run is today's); (c) the whole pipeline running (a saturation far beyond any control:
    # sensor reading, observer-less z_hat, actuator clip and per-step inputs all on the real path)
    sc = load_scenario(path, ["sim.duration=0.3"])
    loops = [lp.name for lp in sc.loops]
    defaults = [s for lp in loops for s in (f"loops.{lp}.sensor.measured=state", f"loops.{lp}.sensor.noise=0",
                                            f"loops.{lp}.sensor.delay=0", f"loops.{lp}.actuator.tau=0")]
    active = [f"loops.{lp}.actuator.u_max=1e300" for lp in loops]
    a = _run(path, ["sim.duration=0.3"])
    b = _run(path, ["sim.duration=0.3"] + defaults)
    c = _run(path, ["sim.duration=0.3"] + active)
    _same_samples(a, b, tuple(a.loops[loops[0]]))
    assert set(a.loops[loops[0]]) == set(LOOP_FIELDS)  # no stage fields for an ideal loop: logs unchanged
    _same_samples(a, c)
    for lp in loops:
        assert c.loops[lp]["u_applied"].tobytes() == a.loops[lp]["u"].tobytes()
        assert c.loops[lp]["z_hat"].tobytes() == a.loops[lp]["z"].tobytes()


def test_saturation_above_need_is_the_unsaturated_run_and_below_it_the_guarantee_does_not_apply():
    free = run_scenario(load_scenario(ROBUST, ["sim.duration=5"]), keep_samples=True)
    m_free = free.metrics["loops"]["cart"]
    probe = run_scenario(load_scenario(ROBUST, ["sim.duration=0.01", "loops.cart.actuator.u_max=1e9"]), keep_samples=True)
    need = probe.metrics["loops"]["cart"]["u_needed"]  # 7.459: sampled sup of |u| over V1 <= V1(z0)
    # the estimate covers what the run asks (V1 decreases, so the run stays in V1 <= V1(z0))
    assert m_free["u_max_abs"] <= need
    above = run_scenario(load_scenario(ROBUST, ["sim.duration=5", f"loops.cart.actuator.u_max={1.01 * need}"]), keep_samples=True)
    _same_samples(free.result, above.result)
    m = above.metrics["loops"]["cart"]
    assert m["bound_applies"] is True and m["bound_applies_reason"] is None and m["time_saturated"] == 0.0
    below = run_scenario(load_scenario(ROBUST, ["sim.duration=5", "loops.cart.actuator.u_max=3"]), keep_samples=True)
    m = below.metrics["loops"]["cart"]
    assert m["bound_applies"] is False and "needs |u| up to 7.459 > u_max = 3" in m["bound_applies_reason"]
    assert m["time_saturated"] > 0 and m["u_applied_max_abs"] == 3.0 and m["u_max_abs"] == 6.0


def test_differentiator_in_closed_loop_on_the_cart_keeps_levants_accuracy():
    # The signal is the cart's own position under the robust law (|x''| <= 3.6 < L = 5 near the
    # origin): Levant's bounds hold for any such signal, so in closed loop too the estimation error
    # of z_i scales as tau^(n-i+1) without noise and as eps^((n-i+1)/(n+1)) with it (n = 1).
    # Tolerance 0.1 as in tests/test_loop_stages.py. Measured: 2.04, 1.01 and 0.92, 0.46.
    def errors(sets):
        run = run_scenario(load_scenario(ROBUST, POSITION + ["loops.cart.observer.L=5", "metrics.final_fraction=0.5"]
                                         + sets), keep_samples=True)
        return run.metrics["loops"]["cart"]["estimation_error_max"]

    hs = [0.00025, 0.0005, 0.001, 0.002]
    e_tau = np.array([errors([f"sim.period={h}", f"sim.physics_step={h}"]) for h in hs])
    eps = [1e-5, 1e-4, 1e-3, 1e-2]
    e_eps = np.array([errors(["sim.period=0.00025", "sim.physics_step=0.00025", f"loops.cart.sensor.noise={e}"])
                      for e in eps])
    s_tau = [np.polyfit(np.log(hs), np.log(e_tau[:, i]), 1)[0] for i in range(2)]
    s_eps = [np.polyfit(np.log(eps), np.log(e_eps[:, i]), 1)[0] for i in range(2)]
    assert abs(s_tau[0] - 2) < 0.1 and abs(s_tau[1] - 1) < 0.1, s_tau
    assert abs(s_eps[0] - 1) < 0.1 and abs(s_eps[1] - 0.5) < 0.1, s_eps


def test_output_feedback_converges_and_its_accuracy_follows_the_noise_as_the_theory_says():
    # position only, uniform noise eps, Levant's differentiator of order 1 (L = 5), robust law,
    # 0.25 ms sampling so that the noise term dominates the sampling term over the eps range
    eps = np.array([1e-4, 3e-4, 1e-3, 3e-3, 1e-2])
    acc = []
    for e in eps:
        run = run_scenario(load_scenario(ROBUST, POSITION + [
            f"loops.cart.sensor.noise={e}", "loops.cart.observer.L=5", "sim.period=0.00025",
            "sim.physics_step=0.00025", "metrics.final_fraction=0.5"]), keep_samples=True)
        m = run.metrics["loops"]["cart"]
        assert run.metrics["status"] == "completed" and m["bound_applies"] is False
        acc.append(m["final_abs_z_max"])
    acc = np.array(acc)
    assert np.all(acc[:, 0] < 0.03) and np.all(np.diff(acc, axis=0) > 0)  # converged; monotone in eps
    slopes = [np.polyfit(np.log(eps), np.log(acc[:, i]), 1)[0] for i in range(2)]
    # theory eps^(p_i / (r p_r)): 0.625 and 0.5 (measured 0.66 and 0.54); tolerance 0.1, half the
    # gap between the two exponents plus the sampling term's pull at the smallest eps
    assert abs(slopes[0] - 0.625) < 0.1 and abs(slopes[1] - 0.5) < 0.1, slopes


def test_chattering_grows_with_a_second_order_actuator_and_not_with_a_first_order_lag():
    # A relay closed through the integrator and one lag (relative degree 2) has no finite-frequency
    # limit cycle: the chattering stays the sampling's. Through two lags (relative degree 3) it
    # oscillates near 1/tau with an amplitude ~ tau (describing function), monotone in tau.
    taus = [0.002, 0.005, 0.01, 0.02]
    base = ["sim.duration=6", "sim.physics_step=0.0005"]
    free = _run(ROBUST, base)
    n = len(free.loops["cart"]["t"])

    def amplitude(res):  # chattering amplitude: max |z_2| over the last 20 %
        return float(np.max(np.abs(res.loops["cart"]["z"][int(0.8 * n):, 1])))

    a0 = amplitude(free)
    first = [amplitude(_run(ROBUST, base + [f"loops.cart.actuator.tau={t}"])) for t in taus]
    second = [amplitude(_run(ROBUST, base + [f"loops.cart.actuator.tau={t}", "loops.cart.actuator.lag_order=2"]))
              for t in taus]
    assert np.all(np.diff(second) > 0), second  # measured 4.7e-3, 1.0e-2, 1.8e-2, 3.3e-2 m/s
    assert second[-1] > 10 * a0  # lag-free: 2.1e-3
    slope = np.polyfit(np.log(taus), np.log(second), 1)[0]
    assert 0.6 < slope < 1.2, slope  # describing function: 1 once the lag's cycle dominates (measured 0.86)
    assert max(abs(a / a0 - 1.0) for a in first) < 0.3, first  # first order: within 30 % of lag-free


def test_stage_state_saves_and_restores_exactly():
    sets = POSITION + ["loops.cart.sensor.noise=1e-3", "loops.cart.sensor.delay=2", "loops.cart.observer.L=5",
                       "loops.cart.observer.kind=levant_filtering", "loops.cart.actuator.tau=0.01",
                       "loops.cart.actuator.rate_max=100", "sim.period=0.005"]
    sc = load_scenario(ROBUST, sets)
    for path in ((False, True) if native.available() else (False,)):
        sim = Simulation(make_plant(sc.plant.model, sc.plant.params), sc.loops, sc.sim.period, sc.sim.physics_step,
                         native=path)
        with sim.installed():
            sim.advance(137)
            saved = sim.get_state()
            first = sim.advance(200)
            sim.set_state(saved)
            again = sim.advance(200)
        for f in first.loops["cart"]:
            assert first.loops["cart"][f].tobytes() == again.loops["cart"][f].tobytes(), (path, f)


@pytest.mark.skipif(not native.available(), reason=native.UNAVAILABLE_REASON or "")
@pytest.mark.parametrize("path,sets", [
    (ROBUST, POSITION + ["loops.cart.sensor.noise=1e-3", "loops.cart.observer.L=5", "loops.cart.actuator.u_max=3",
                         "loops.cart.actuator.tau=0.005", "loops.cart.sensor.quantum=1e-4", "sim.period=0.005"]),
    (R3, POSITION + ["loops.cart.observer.kind=levant_filtering", "loops.cart.observer.L=20",
                     "loops.cart.sensor.delay=1", "loops.cart.actuator.dead_zone=0.05",
                     "loops.cart.actuator.rate_max=200"]),
    (R3, ["loops.cart.sensor.noise=[1e-5, 1e-4, 1e-3]", "loops.cart.sensor.noise_kind=gaussian",
          "loops.cart.actuator.tau=0.003", "loops.cart.actuator.lag_order=2"]),
])
def test_native_stages_run_the_python_pipeline(path, sets):
    # 1e-10: both paths do the same operations (the stages bit for bit: tests/test_loop_stages_native.py);
    # the discontinuous law turns ulp differences of pow into larger ones only later in a run
    a = _run(path, sets + ["sim.duration=1"], False)
    b = _run(path, sets + ["sim.duration=1"], True)
    for f in LOOP_FIELDS + STAGE_FIELDS:
        np.testing.assert_allclose(a.loops["cart"][f], b.loops["cart"][f], rtol=1e-10, atol=1e-12, err_msg=f)


def test_the_law_sees_the_estimate_and_the_log_keeps_the_truth():
    res = _run(ROBUST, POSITION + ["loops.cart.sensor.noise=1e-3", "loops.cart.observer.L=5",
                                   "loops.cart.sensor.delay=1", "sim.duration=0.5"])
    L = res.loops["cart"]
    assert L["z_measured"].shape == (500, 1) and L["z_hat"].shape == (500, 2)
    # the reading is the true position one sample earlier plus bounded noise
    assert np.max(np.abs(L["z_measured"][1:, 0] - L["z"][:-1, 0])) <= 1e-3
    assert not np.array_equal(L["z_hat"], L["z"])
    from ftstab_mj.control import law_class  # u is the law at the estimate, not at the truth
    sc = load_scenario(ROBUST)
    law = sc.loops[0].law(2)
    assert law_class("robust") is type(law)
    # (the run evaluated it in C one sample at a time: equal to rounding)
    np.testing.assert_allclose(law.evaluate(L["z_hat"], law.initial_state()).u, L["u"], rtol=1e-14, atol=0)
    assert np.max(np.abs(law.evaluate(L["z"], law.initial_state()).u - L["u"])) > 0.1


@pytest.mark.skipif(not native.available(), reason=native.UNAVAILABLE_REASON or "")
def test_physical_loop_benchmark_prints_its_rows():
    # the script the README quotes runs (shortened); no timing is asserted (speed lives in benchmarks/)
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    out = subprocess.run([sys.executable, str(root / "benchmarks" / "physical_loop.py"), "--repeat", "1",
                          "--steps", "2000"], capture_output=True, text=True, timeout=300, cwd=root)
    assert out.returncode == 0, out.stderr
    for row in ("native callback r=2, all stages on", "stages on / off, native r=3", "Python pipeline r=2, stages on"):
        assert row in out.stdout, out.stdout

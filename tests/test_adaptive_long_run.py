"""The adaptive law's accuracy depends on how long it runs (README "What they show").

cart_r2_adaptive (10 s as shipped) ends at the robust law's accuracy (|x| ~ 1.2e-4 m) only because
phi_hat is still high from the transient. Below eps the estimate decays (phi_hat' = -sig(phi_hat,
eta)); once it is too small for the disturbance, V1 leaves the eps level, phi_hat grows again, and
the run settles into a cycle with the period of the inputs (sine 0.5 Hz and gain 0.3 Hz: 10 s)
where |x| reaches 8.9e-3 m, 70 times the robust law's, and V1 5.6e-4 > eps = 1e-4, still below
Theorem 3's ultimate bound Delta (8.3e-3). Measured with the native run loop (1 ms period):
    ftstab run cart_r2_adaptive --set sim.duration=60
Pinned values: 2 % (the cycle is an attractor; the figures repeat to 4 digits from cycle to cycle).
"""

import numpy as np
import pytest

from ftstab_mj.scenario import find_scenario, load_scenario
from ftstab_mj.scenario.run import run_scenario


def _run(name, duration):
    return run_scenario(load_scenario(find_scenario(name), [f"sim.duration={duration}"]), keep_samples=True)


def test_the_adaptive_law_matches_the_robust_accuracy_only_in_the_shipped_10_s():
    adaptive, robust = (_run(n, 10.0).metrics["loops"]["cart"]["final_abs_z_max"][0]
                        for n in ("cart_r2_adaptive", "cart_r2_robust"))
    assert robust == pytest.approx(1.24e-4, rel=0.02) and adaptive == pytest.approx(1.17e-4, rel=0.02)


def test_over_60_s_phi_hat_decays_and_the_adaptive_law_cycles_70_times_less_accurate():
    run = _run("cart_r2_adaptive", 60.0)
    m = run.metrics["loops"]["cart"]
    robust = _run("cart_r2_robust", 60.0).metrics["loops"]["cart"]["final_abs_z_max"][0]
    x_final = m["final_abs_z_max"][0]
    assert x_final == pytest.approx(8.88e-3, rel=0.02) and x_final > 50 * robust
    th = m["theorem3"]
    eps = run.result.info.loops[0].law_params["eps"]
    assert th["V1_max_final"] == pytest.approx(5.63e-4, rel=0.02) and eps < th["V1_max_final"] < th["Delta"]
    assert th["Delta_held"] and th["phi_hat_bound_held"]
    a = run.result.loops["cart"]
    t, x, ph = a["t"], np.abs(a["z"][:, 0]), a["phi_hat"]
    # still at the robust accuracy up to 10 s, then the first excursion beyond 1e-3 m
    assert x[(t > 5) & (t < 10)].max() < 2e-4
    assert 10.0 < t[(t > 5) & (x > 1e-3)][0] < 11.0
    # phi_hat fell from its transient peak to below a tenth of it, and the cycle repeats every 10 s
    assert ph[t > 10].min() < 0.1 * ph.max()
    peaks = [x[(t >= s) & (t < s + 10)].max() for s in (20, 30, 40, 50)]
    assert np.ptp(peaks) < 0.01 * max(peaks)

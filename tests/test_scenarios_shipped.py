"""Every shipped scenario runs through the real CLI and does what its one-line description claims.

Each claim below restates the description's numbers and is asserted on the metrics that
``ftstab run --json`` prints (the same dict the log's /metrics holds). Runs are shortened with
``--set sim.duration=...`` where the claim still holds (the final-accuracy window, the last 20 % of
the run, must start after the settling time); the measured values are in the comments, so the
margin of each threshold is visible. The runs are deterministic (same seed, bit-identical samples), so a margin
only has to absorb changes of platform or library version, not noise.
"""

import json

import pytest
from conftest import run_cli

from ftstab_mj.scenario import shipped_scenarios


def _x_final(m):
    return m["final_abs_z_max"][0]


def _theorem3_held(m):
    th = m["theorem3"]
    return th["Delta_held"] and th["phi_hat_bound_held"] and th["eps_reached"]


# name: (duration for the test or None for the file's, claim on {loop name: loop metrics})
CLAIMS = {
    # exact convergence: settles at 3.865 s, final |x| 1.1e-15, T(z0) = 6.853 s
    "cart_r2_nominal": (None, lambda m: m["cart"]["settle_time"] <= 4.0 and m["cart"]["beat_bound"]
                        and _x_final(m["cart"]) < 1e-12),
    # settles at 3.16 s, final |x| 1.24e-4
    "cart_r2_robust": (6.0, lambda m: m["cart"]["settle_time"] <= 3.5 and m["cart"]["beat_bound"]
                       and _x_final(m["cart"]) < 2e-4),
    # settles (V1 < 1e-3) at 2.645 s, final |x| 1.17e-4, Delta = 8.3e-3 vs V1 <= 8.5e-7 at the end
    "cart_r2_adaptive": (6.0, lambda m: m["cart"]["settle_time"] <= 3.0 and _x_final(m["cart"]) < 2e-4
                         and _theorem3_held(m["cart"])),
    # the same trajectory as the nominal law: 3.865 s, final |x| 1.1e-15
    "cart_r2_worst_case": (None, lambda m: m["cart"]["settle_time"] <= 4.0 and m["cart"]["beat_bound"]
                           and _x_final(m["cart"]) < 1e-12),
    # never settles at 1e-3; |x| up to 0.43 m over the last 3 s (a 0.2 Hz disturbance: full length)
    "cart_r2_above_bound_robust": (None, lambda m: m["cart"]["settle_time"] is None
                                   and _x_final(m["cart"]) > 0.3),
    # settles (V1 < 1e-3) at 9.72 s, final |x| 9.5e-4
    "cart_r2_above_bound_adaptive": (None, lambda m: m["cart"]["settle_time"] <= 11.0
                                     and _x_final(m["cart"]) < 2e-3 and _theorem3_held(m["cart"])),
    # settles at 4.128 s, final |x| 5.8e-5, T(z0) = 35.1 s
    "cart_r3_robust": (None, lambda m: m["cart"]["settle_time"] <= 4.5 and m["cart"]["beat_bound"]
                       and _x_final(m["cart"]) < 1e-4),
    # settles (V1 < 1e-3) at 3.35 s, final |x| 6.4e-5
    "cart_r3_adaptive": (None, lambda m: m["cart"]["settle_time"] <= 4.0 and _x_final(m["cart"]) < 1e-4
                         and _theorem3_held(m["cart"])),
    # position only, noise 1e-4 m: final |x| 1.83e-3 m, velocity estimate error <= 3.9e-2 m/s; no guarantee claimed
    "cart_r2_output_feedback": (None, lambda m: _x_final(m["cart"]) < 3e-3
                                and m["cart"]["estimation_error_max"][1] < 0.05 and m["cart"]["bound_applies"] is False),
    # u_max = 8 above u_needed = 7.459: never saturates, settles at 3.16 s as cart_r2_robust, bound applies
    "cart_r2_saturation_above": (6.0, lambda m: m["cart"]["time_saturated"] == 0.0 and m["cart"]["bound_applies"]
                                 and m["cart"]["settle_time"] <= 3.5 and m["cart"]["beat_bound"]),
    # u_max = 3 below u_needed = 7.459: saturated 0.219 s, bound_applies false, still settles at 3.209 s
    "cart_r2_saturation_below": (6.0, lambda m: 0.2 <= m["cart"]["time_saturated"] <= 0.25
                                 and m["cart"]["bound_applies"] is False and m["cart"]["settle_time"] <= 3.5),
    # two 10 ms lags: final |x'| 2.48e-2 m/s (lag-free 2.93e-3, one 10 ms lag 2.77e-3)
    "cart_r2_actuator_lag": (None, lambda m: m["cart"]["final_abs_z_max"][1] > 2e-2),
    # position only through a second-order differentiator: final |x| 1.01e-3 m
    "cart_r3_output_feedback": (None, lambda m: _x_final(m["cart"]) < 2e-3 and m["cart"]["bound_applies"] is False),
    # settles at 1.878 / 1.868 s (T(z0) 5.97 / 5.71 s), final |q - ref| 2.0e-3 / 4.5e-4 rad
    "arm_robust": (4.0, lambda m: all(m[j]["settle_time"] <= 2.5 and m[j]["beat_bound"] and _x_final(m[j]) < 3e-3
                                      for j in ("joint0", "joint1"))),
    # V1 enters eps at 1.655 / 1.45 s, then stays below 5.9e-3 / 4.6e-3; final |q - ref| 0.031 / 3.3e-4 rad (6 s)
    "arm_adaptive": (6.0, lambda m: all(m[j]["eps_entry_time"] <= 2.0 and m[j]["V1_max_after_entry"] < 1e-2
                                        and _x_final(m[j]) < 0.05 and _theorem3_held(m[j])
                                        for j in ("joint0", "joint1"))),
    # settles (V1 < 1e-3) at 2.02 / 4.87 / 1.63 s (T(z0) 5.97 / 5.71 / 5.39 s), in the workspace
    "arm3_robust": (None, lambda m: all(m[j]["settle_time"] <= 5.0 and m[j]["beat_bound"] and m[j]["bound_applies"]
                                        for j in ("joint0", "joint1", "joint2"))),
    # V1 enters eps at 1.68 / 1.45 / 1.16 s, then stays below 1.04e-2 / 5.6e-3 / 4.4e-3 (10 s)
    "arm3_adaptive": (None, lambda m: all(m[j]["eps_entry_time"] <= 2.5 and m[j]["V1_max_after_entry"] < 1.5e-2
                                          and _x_final(m[j]) < 0.05 and _theorem3_held(m[j])
                                          for j in ("joint0", "joint1", "joint2"))),
    # r = 3: V1 < 2e-2 from 0.83 / 1.04 s on (T(z0) 31.1 s), in the workspace, final |q - ref| 2.4e-3 / 6.2e-3 rad
    "arm_r3_robust": (None, lambda m: all(m[j]["settle_time"] <= 1.5 and m[j]["beat_bound"] and m[j]["bound_applies"]
                                          and _x_final(m[j]) < 1e-2 for j in ("joint0", "joint1"))),
    # r = 3: V1 enters eps at 0.83 / 0.79 s, then stays below 2.0e-2 / 2.04e-2; final |q - ref| 0.025 / 0.010 rad
    "arm_r3_adaptive": (None, lambda m: all(m[j]["eps_entry_time"] <= 1.0 and m[j]["V1_max_after_entry"] < 2.5e-2
                                            and _x_final(m[j]) < 0.05 and _theorem3_held(m[j])
                                            for j in ("joint0", "joint1"))),
    # r = 4 exact chain, designed gains: V1 < 1e-4 from 5.409 s on (T(z0) 68.43 s), final |z_1| 4.9e-4
    "ideal_chain_r4": (None, lambda m: m["chain"]["settle_time"] <= 5.5 and m["chain"]["beat_bound"]
                       and m["chain"]["bound_applies"] and m["chain"]["certificate"]["status"] == "certified"
                       and _x_final(m["chain"]) < 1e-3),
    # flexible joint, r = 4 (6 s): V1 < 1e-4 from 4.115 s on (T(z0) = 64.43 s), V1 1.386 -> 1.14e-5 (falls by 1.2e5),
    # in the bounds' workspace, final |q - ref| 3.2e-3 rad
    "flexible_joint_r4_robust": (6.0, lambda m: m["link"]["settle_time"] <= 4.5 and m["link"]["beat_bound"]
                                 and m["link"]["bound_applies"] and m["link"]["certificate"]["status"] == "certified"
                                 and m["link"]["V1_initial"] / m["link"]["V1_final"] >= 1e3
                                 and _x_final(m["link"]) < 5e-3),
    # flexible joint, r = 4, adaptive (6 s): V1 enters eps = 1e-3 at 2.775 s, then stays below 1.92e-3; Theorem 3 held;
    # in the workspace, final |q - ref| 3.4e-3 rad
    "flexible_joint_r4_adaptive": (6.0, lambda m: m["link"]["eps_entry_time"] <= 3.0
                                   and m["link"]["V1_max_after_entry"] < 2.5e-3 and m["link"]["workspace_left"] == ""
                                   and _x_final(m["link"]) < 5e-3 and _theorem3_held(m["link"])),
    # flexible joint with an integrating motor, r = 5 (8 s): V1 < 1e-3 from 6.058 s on (T(z0) = 380.1 s), V1 13.04 ->
    # 3.47e-4 (falls by 3.8e4), in the workspace (z_1..z_3, u), final |q - ref| 2.2e-2 rad
    "flexible_joint_r5_robust": (8.0, lambda m: m["link"]["settle_time"] <= 6.5 and m["link"]["beat_bound"]
                                 and m["link"]["bound_applies"] and m["link"]["certificate"]["status"] == "certified"
                                 and m["link"]["V1_initial"] / m["link"]["V1_final"] >= 1e4
                                 and _x_final(m["link"]) < 3e-2),
    # r = 5 exact chain, designed gains, the run's certificate within the default work limit: V1 < 1e-4
    # from 12.769 s on (T(z0) = 389.4 s from c_lower = 0.2673, the gap left open at the limit), final |z_1| 2.08e-3
    "ideal_chain_r5": (None, lambda m: m["chain"]["settle_time"] <= 13.5 and m["chain"]["beat_bound"]
                       and m["chain"]["bound_applies"] and m["chain"]["certificate"]["status"] == "certified"
                       and _x_final(m["chain"]) < 3e-3),
}


def test_every_shipped_scenario_has_a_checked_claim():
    assert sorted(CLAIMS) == sorted(name for name, _, _ in shipped_scenarios())


@pytest.mark.parametrize("name", sorted(CLAIMS))
def test_shipped_scenario_does_what_its_description_says(name, tmp_path):
    duration, claim = CLAIMS[name]
    args = ["run", name, "--out", tmp_path, "--json", "--rrd"]  # the recording of every plant, as a run writes it
    if duration is not None:
        args += ["--set", f"sim.duration={duration}"]
    proc = run_cli(*args)
    assert proc.returncode == 0, proc.stderr
    metrics = json.loads(proc.stdout)
    assert metrics["status"] == "completed"
    assert (tmp_path / f"{name}.mcap").stat().st_size > 0 and (tmp_path / f"{name}.rrd").stat().st_size > 0
    loops = metrics["loops"]
    assert claim(loops), f"{name}: claim not met by {json.dumps(loops, indent=1)}"

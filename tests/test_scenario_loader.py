"""The scenario schema and its strict loader (issue 4): round trip, overrides, seeds, malformed inputs.

The table of malformed inputs goes through the real CLI (``python -m ftstab_mj run``): each must
exit with code 2, print exactly one line on stderr naming the file and the key path, show no
traceback and leave no log (the output directory is not even created).
"""

import json

import pytest
from conftest import ROOT, run_args, run_cli

from ftstab_mj.config.errors import ScenarioError
from ftstab_mj.scenario import (apply_override, load_scenario, scenario_from_dict, scenario_to_dict,
                                shipped_scenarios)

SHIPPED = [path for _, path, _ in shipped_scenarios()]
ROBUST = ROOT / "scenarios" / "cart_r2_robust.toml"
R3 = ROOT / "scenarios" / "cart_r3_robust.toml"


@pytest.mark.parametrize("path", SHIPPED, ids=[p.stem for p in SHIPPED])
def test_shipped_scenario_round_trips_through_its_resolved_dict(path):
    """The resolved dict (what the log's /scenario holds) is plain JSON and loads back to the same scenario."""
    sc = load_scenario(path)
    assert sc.name == path.stem  # file name = scenario name, so `ftstab run NAME` finds it
    raw = json.loads(json.dumps(scenario_to_dict(sc)))
    assert scenario_from_dict(raw) == sc


def test_signal_seeds_come_from_the_scenario_seed_only():
    """Same seed -> same signal seeds; another seed -> others; disturbance and gain never share one."""
    a, b = load_scenario(ROBUST), load_scenario(ROBUST)
    c = load_scenario(ROBUST, ["seed=1"])
    (la,), (lb,), (lc,) = a.loops, b.loops, c.loops
    assert (la.disturbance.seed, la.gain.seed) == (lb.disturbance.seed, lb.gain.seed)
    assert la.disturbance.seed != la.gain.seed
    assert lc.disturbance.seed != la.disturbance.seed and lc.gain.seed != la.gain.seed


def test_overrides_set_nested_keys_list_items_and_bare_strings():
    sc = load_scenario(ROBUST, ["sim.duration=2", "loops.cart.controller.gains[1]=3",
                                "loops.cart.disturbance.kind=square", "metrics.settle_level=1e-6"])
    (lp,) = sc.loops
    assert sc.sim.duration == 2.0 and lp.controller.gains == (1.0, 3.0)
    assert lp.disturbance.kind == "square" and sc.metrics.settle_level == 1e-6
    raw = {}
    assert apply_override(raw, "loops.cart.z0=[0.5, 0]", "f") == "loops.cart.z0"
    assert raw == {"loops": {"cart": {"z0": [0.5, 0]}}}


def test_error_names_the_override_that_caused_it():
    with pytest.raises(ScenarioError) as err:
        load_scenario(ROBUST, ["sim.duration=2", "loops.cart.gain.amplitude=1.5"])
    assert err.value.path == "loops.cart.gain"
    assert "(--set loops.cart.gain.amplitude=1.5)" in err.value.source


# (id, scenario file, replacement in the file text or None, --set overrides, key path expected in the message)
MALFORMED = [
    ("toml-syntax", ROBUST, ('name = "cart_r2_robust"', 'name = "cart_r2_robust'), [], "(TOML syntax)"),
    ("missing-file", None, None, [], "(file)"),
    ("unknown-top-key", ROBUST, ("seed = 0", "sed = 0"), [], "sed"),
    ("unknown-nested-key", ROBUST, None, ["loops.cart.controller.gian=2"], "loops.cart.controller.gian"),
    ("wrong-type", ROBUST, ("duration = 10.0", 'duration = "ten"'), [], "sim.duration"),
    ("out-of-range", ROBUST, None, ["sim.duration=-1"], "sim.duration"),
    ("gain-not-positive", ROBUST, ("gains = [1.0, 2.0]", "gains = [1.0, -2.0]"), [],
     "loops.cart.controller.gains[1]"),
    ("non-hurwitz-gains", R3, None, ["loops.cart.controller.gains=[3, 1.7, 1]"], "loops.cart.controller.gains"),
    ("k-out-of-range", ROBUST, None, ["loops.cart.controller.k=-0.6"], "loops.cart.controller.k"),
    ("period-not-multiple", ROBUST, ("period = 0.001 ", "period = 0.0015"), [], "sim.period"),
    ("unknown-model", ROBUST, None, ["plant.model=boat"], "plant.model"),
    ("unknown-plant-param", ROBUST, None, ["plant.colour=1"], "plant.colour"),
    ("unknown-signal", ROBUST, ('kind = "sine"', 'kind = "triangle"'), [], "loops.cart.disturbance.kind"),
    ("z0-length", ROBUST, None, ["loops.cart.z0=[1, 0, 0]"], "loops.cart.z0"),
    ("gains-length", R3, None, ["loops.cart.controller.gains=[1, 2]"], "loops.cart.controller.gains"),
    ("other-law-param", ROBUST, None, ["loops.cart.controller.kappa=1"], "loops.cart.controller.kappa"),
    ("missing-required", ROBUST, ('law = "robust"', ""), [], "loops.cart.controller.law"),
    ("gamma-reaches-zero", ROBUST, None, ["loops.cart.gain.amplitude=1.5"], "loops.cart.gain"),
    ("wrong-loop-name", ROBUST, ("[loops.cart", "[loops.kart"), [], "loops"),
    ("bad-set-syntax", ROBUST, None, ["sim.duration"], "--set sim.duration"),
    ("set-index-out-of-range", ROBUST, None, ["loops.cart.z0[5]=1"], "loops.cart.z0[5]"),
    ("integrator", ROBUST, None, ["sim.integrator=leapfrog"], "sim.integrator"),
    ("step-absurd", ROBUST, None, ["sim.physics_step=1e-300", "sim.period=1e-300"], "sim.physics_step"),
    ("limit-beyond-mujoco", ROBUST, None, ["sim.divergence_limit=1e300"], "sim.divergence_limit"),
    ("z0-beyond-mujoco", ROBUST, None, ["loops.cart.z0=[1e300, 0.0]"], "loops.cart.z0[0]"),
]


@pytest.mark.parametrize("case", MALFORMED, ids=[c[0] for c in MALFORMED])
def test_malformed_input_exit_2_one_line_key_path_no_log(case, tmp_path):
    _, base, edit, sets, key_path = case
    path, out, args = run_args(tmp_path, base, edit, sets)
    proc = run_cli(*args)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr and proc.stdout == ""
    assert lines[0].startswith(f"error: {path}") and f": {key_path}: expected " in lines[0], lines[0]
    assert not out.exists()


def test_period_error_quotes_both_numbers(tmp_path):
    proc = run_cli("run", ROBUST, "--out", tmp_path / "out", "--set", "sim.period=0.0015")
    assert proc.returncode == 2
    assert "0.001 s" in proc.stderr and "0.0015 s" in proc.stderr


def test_computed_bounds_are_the_plants_bounds_for_the_scenarios_signals():
    """phibar = gamma_m = "computed" resolves, at load time, to Plant.true_bounds of the loops' signals:
    the cart's from the signal ranges (|phi| <= 0.8, gamma >= 0.6), the arm's from its model."""
    from ftstab_mj.plants import make_plant

    sc = load_scenario(ROBUST, ['loops.cart.controller.phibar="computed"', "loops.cart.controller.gamma_m=computed"])
    (lp,) = sc.loops
    assert (lp.controller.phibar, lp.controller.gamma_m) == pytest.approx((0.8, 0.6), rel=1e-12)
    arm = load_scenario(ROOT / "scenarios" / "arm_robust.toml")
    plant = make_plant("arm")
    phibar, gamma_m, _ = plant.true_bounds([lp.disturbance.bounds() for lp in arm.loops],
                                           [lp.gain.bounds() for lp in arm.loops])
    assert [lp.controller.phibar for lp in arm.loops] == list(phibar)
    assert [lp.controller.gamma_m for lp in arm.loops] == list(gamma_m)
    # the resolved scenario (what a log records) holds the numbers
    assert scenario_to_dict(arm)["loops"]["joint0"]["controller"]["phibar"] == phibar[0]

"""ftstab montecarlo: per-trajectory metrics of many initial states, against independent references."""

import json
import math

import numpy as np
import pytest
from conftest import ROOT, run_cli
from metrics_reference import settle_time

from ftstab_mj.metrics import run_metrics as mt
from ftstab_mj.studies import montecarlo as mc
from ftstab_mj.simulation.ideal_chain import simulate_chain
from ftstab_mj.scenario import find_scenario, load_scenario


def test_vectorised_settle_times_equal_the_metric_of_each_column():
    rng = np.random.default_rng(3)
    t = np.arange(50) * 0.01
    V1 = rng.uniform(0, 2, size=(50, 400))
    V1[:, :100] *= np.linspace(1, 0, 50)[:, None] ** 3  # decaying: settle somewhere
    V1[:, 100:110] = 0.0  # never above: t[0]
    V1[-1, 110:120] = 5.0  # above at the end: never
    V1[rng.integers(0, 50, 30), rng.integers(0, 400, 30)] = np.nan  # NaN counts as above
    got = mc.settle_times(t, V1, 0.5)
    for j in range(V1.shape[1]):
        ref = settle_time(t, V1[:, j], 0.5)
        assert (math.isnan(got[j]) and ref is None) or got[j] == ref, j


def test_draw_is_seeded_and_inside_the_box():
    d = mc.Distribution(1000, (1.0, 0.25), seed=7)
    Z = d.draw()
    assert Z.shape == (1000, 2) and np.all(np.abs(Z) <= [1.0, 0.25])
    assert np.array_equal(Z, mc.Distribution(1000, (1.0, 0.25), seed=7).draw())
    assert not np.array_equal(Z, mc.Distribution(1000, (1.0, 0.25), seed=8).draw())


def test_chain_distribution_of_1000_states_reproduces_the_serial_runs():
    # Robust law under its sine disturbance, 1000 states in chunks of 128; reference: each state
    # run alone (same kernel, one trajectory per call) with the run metrics' own functions.
    sc = load_scenario(find_scenario("cart_r2_robust"), ["sim.duration=3", "sim.period=0.002", "sim.physics_step=0.001"])
    Z0 = mc.Distribution(1000, (1.0, 1.0), seed=1).draw()
    rows, info = mc.run_chain(sc, "cart", Z0)
    lp = sc.loops[0]
    law = lp.law(2)
    assert mt.bound_applies(info)
    picked = np.random.default_rng(0).choice(1000, 1000, replace=False)
    for i in picked:
        run = simulate_chain(law, Z0[i], sc.sim.period, sc.sim.duration, phi=lp.disturbance, gamma=lp.gain,
                             substeps=2, native="auto")
        ts = settle_time(run.t, run.V1, sc.metrics.settle_level)
        tb = mt.time_bound(info, run.z[0])
        row = rows[i]
        assert row["row"] == i and row["z0"] == list(Z0[i])
        assert (ts is None and math.isnan(row["settle_time"])) or row["settle_time"] == ts
        assert row["time_bound"] == tb and row["V1_final"] == run.V1[-1]
        assert row["u_max_abs"] == np.max(np.abs(run.u))
    summary = mc.summarize(rows, True)
    ratios = np.array([r["ratio"] for r in rows])
    assert summary["states"] == 1000 and summary["violations"] == int(np.sum(ratios > 1))
    assert summary["worst"]["ratio"] == np.nanmax(ratios) or summary["never_settled"] > 0


def test_chain_matches_the_numpy_reference_path():
    # The native chain against the pure NumPy loop (the reference of ideal_chain): same settling
    # instants (one-period resolution; rounding of 1e-16 cannot move a crossing of V1 = 1e-4 by a period
    # except by a coincidence this seed does not have) and V1 to 1e-9 relative.
    sc = load_scenario(find_scenario("cart_r2_robust"), ["sim.duration=2"])
    Z0 = mc.Distribution(64, (1.0, 1.0), seed=2).draw()
    fast, _ = mc.run_chain(sc, "cart", Z0, native="auto")
    slow, _ = mc.run_chain(sc, "cart", Z0, native=False)
    for a, b in zip(fast, slow):
        assert a["settle_time"] == b["settle_time"] or (math.isnan(a["settle_time"]) and math.isnan(b["settle_time"]))
        assert a["V1_final"] == pytest.approx(b["V1_final"], rel=1e-9, abs=1e-15)


@pytest.mark.parametrize("plant", ["friction=0.5", "damping=0.2"])
def test_chain_mode_refuses_a_plant_without_an_exact_chain_twin(tmp_path, plant):
    """A cart with friction or damping is not the ideal chain (its plant declares no exact twin). (The arm is
    refused likewise, after its bound tables, whose progress lines take seconds of a loaded machine.)"""
    res = run_cli("montecarlo", "cart_r2_robust", "--set", f"plant.{plant}", "--on", "chain", "--states", "4",
                  "--out", tmp_path / "o")
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and "--on plant" in res.stderr, res.stderr
    assert plant.replace("=", " = ") in res.stderr  # what makes it no chain is named
    assert res.stdout == ""  # the refusal is the only line: no header printed before it
    assert "Traceback" not in res.stderr and not (tmp_path / "o").exists()
    for bad in (["--states", "0"], ["--states", "3", "--box", "1,2,3"], ["--states", "3", "--box", "1,nan"]):
        res = run_cli("montecarlo", "cart_r2_robust", *bad, "--out", tmp_path / "o")
        assert res.returncode == 2 and res.stderr.count("\n") == 1, (bad, res.stderr)
    assert not (tmp_path / "o").exists()


def _rerun_gives_the_worst_case(tmp_path, scenario, loop, duration, worst):
    """`ftstab run SCENARIO` from the Monte Carlo's worst z0: the same z0, settling time and T(z0)."""
    z0 = "[" + ", ".join(repr(x) for x in worst["z0"]) + "]"
    rerun = run_cli("run", scenario, "--set", f"sim.duration={duration}", "--set", f"loops.{loop}.z0={z0}",
                    "--out", tmp_path / "runs", "--json")
    assert rerun.returncode == 0, rerun.stderr
    m = json.loads(rerun.stdout)["loops"][loop]
    assert m["z0"] == worst["z0"] and m["settle_time"] == worst["settle_time"]
    assert m["time_bound"] == worst["time_bound"]


def test_plant_worst_case_rerun_with_ftstab_run_gives_the_same_settling_time(tmp_path):
    out = tmp_path / "mc"
    res = run_cli("montecarlo", "cart_r2_robust", "--on", "plant", "--states", "5", "--box", "1,1", "--seed", "4",
                  "--set", "sim.duration=4", "--out", out, "--json")
    assert res.returncode == 0, res.stderr
    summary = json.loads(res.stdout)
    assert summary == json.loads((out / "montecarlo.json").read_text())
    assert (out / "montecarlo.png").stat().st_size > 0 and summary["states"] == 5
    # cart_r2_robust runs within its assumed bounds: Theorem 2 applies and no state may exceed T(z0)
    assert summary["bound_applies"] is True and summary["violations"] == 0
    _rerun_gives_the_worst_case(tmp_path, "cart_r2_robust", "cart", 4, summary["worst"])


def test_chain_mode_on_an_ideal_chain_scenario_and_its_worst_case_rerun_with_ftstab_run(tmp_path):
    """An ideal-chain scenario is its own exact twin: `--on chain` runs it on the native kernel, and
    the worst case's z0 rerun with `ftstab run` (the ideal-chain plant, the Python loop) gives the
    same settling time and T(z0) (r = 4, the robust law inside its bounds: no state beyond its bound)."""
    res = run_cli("montecarlo", "ideal_chain_r4", "--states", "20", "--box", "1,1,1,1", "--set", "sim.duration=8",
                  "--out", tmp_path / "mc", "--json")
    assert res.returncode == 0, res.stderr
    summary = json.loads(res.stdout)
    assert summary["states"] == summary["settled"] == 20 and summary["bound_applies"] is True
    assert summary["violations"] == 0
    _rerun_gives_the_worst_case(tmp_path, "ideal_chain_r4", "chain", 8, summary["worst"])


def test_settle_times_reduced_piece_by_piece_equal_the_whole_run_s():
    rng = np.random.default_rng(7)
    for _ in range(100):
        n = int(rng.integers(1, 25))
        V1 = rng.choice([0.0, 1.0, np.nan], size=(n, 6), p=[0.6, 0.3, 0.1])
        t = np.arange(n) * 0.01
        for seg in (1, 2, 5):
            st = mc._Settle(0.5)
            for a in range(0, n, seg):
                st.add(t[a:a + seg], V1[a:a + seg])
            np.testing.assert_array_equal(st.times(), mc.settle_times(t, V1, 0.5))


@pytest.mark.parametrize("native", ["auto", False])
def test_the_chain_run_in_pieces_gives_the_rows_of_the_whole_run_and_memory_flat_in_the_duration(native):
    import tracemalloc

    sc = load_scenario(ROOT / "scenarios" / "cart_r2_robust.toml", ["sim.duration=0.6"])
    Z0 = mc.Distribution(24 if native else 6, (1.0, 1.0), 3).draw()
    loop = sc.loops[0].name
    whole, _ = mc.run_chain(sc, loop, Z0, native=native, segment=10**9)
    for seg in (1, 77):
        assert repr(mc.run_chain(sc, loop, Z0, native=native, segment=seg)[0]) == repr(whole)
    if native is False:
        return
    peaks = []
    for duration in (2.0, 10.0):  # samples held: one piece of 100, whatever the duration
        long = load_scenario(ROOT / "scenarios" / "cart_r2_robust.toml", [f"sim.duration={duration}"])
        tracemalloc.start()
        mc.run_chain(long, loop, Z0, segment=100)
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    assert peaks[1] <= 1.2 * peaks[0], peaks  # a whole record would take 5x


def test_plant_rows_read_t_z0_enclosed_ahead_and_give_the_rows_of_runs_that_enclose_their_own(monkeypatch):
    """run_on encloses V1(z0) for the whole draw before the runs (one vectorised call): every run finds its
    state's entry (none left over), and the rows equal bit for bit those of the same runs computing their own."""
    from ftstab_mj.studies.sweep.row import ScenarioTask

    path = ROOT / "scenarios" / "cart_r2_robust.toml"
    sets = ["sim.duration=0.5"]
    sc = load_scenario(path, sets)
    Z0 = mc.Distribution(8, (1.0, 1.0), seed=3).draw()
    left = []
    run_plant = mc.run_plant

    def watched(*a, **kw):
        rows = run_plant(*a, **kw)
        left.append(sum(len(index) for entries in mt._V1_AHEAD.values() for index, _, _ in entries))
        return rows

    monkeypatch.setattr(mc, "run_plant", watched)
    ahead, applies = mc.run_on("plant", sc, path, sets, "cart", Z0)
    assert left == [0] and not mt._V1_AHEAD  # every state's entry taken, the draw forgotten after
    mt._V1_ENCLOSURES.clear()
    from ftstab_mj.config.tomlfile import read_toml
    from ftstab_mj.scenario.loader import apply_override

    raw = read_toml(path, "scenario")
    apply_override(raw, sets[0], str(path))
    own = run_plant(ScenarioTask(raw, str(path)), "cart", Z0)
    assert applies and all(np.isfinite(rw["time_bound"]) for rw in ahead)
    key = lambda rows: json.dumps(rows, sort_keys=True)  # noqa: E731 - NaN written as NaN: compared too
    assert key(ahead) == key(own)


@pytest.mark.parametrize("name", ["cart_r2_robust", "cart_r2_actuator_lag"])
def test_plant_states_on_one_reset_simulation_give_the_metrics_of_ftstab_run(name):
    """The Monte Carlo's row task (one simulation per thread, reset to each z0, the guarantee's metrics only)
    gives, bit for bit, the metrics ``ftstab run`` computes for that z0 (run_scenario: a new scenario,
    simulation and full MetricsStream each): states that settle, one that does not within the run, one
    that diverges mid-run (|z| passes the scenario's divergence limit, 1000), the next one after it (the reset undoes
    the divergence), and states the file's checks refuse (|z0| > 1e9: the full path's failure), the first one too."""
    from ftstab_mj.config.tomlfile import read_toml
    from ftstab_mj.scenario.loader import apply_override
    from ftstab_mj.scenario.run import run_scenario
    from ftstab_mj.studies.sweep.engine import guarded
    from ftstab_mj.studies.sweep.row import ScenarioTask, StatesTask

    path = ROOT / "scenarios" / f"{name}.toml"
    sets = ["sim.duration=0.6"]
    raw = read_toml(path, "scenario")
    apply_override(raw, sets[0], str(path))
    task = StatesTask(ScenarioTask(raw, str(path)), "cart")
    states = [[2e9, 0.0], [0.01, -0.02], [1.0, 0.0], [-0.3, 0.7], [900.0, 900.0], [0.02, 0.01], [-3e9, 1.0]]
    for i, z in enumerate(states):
        got = guarded(task, i, (("loops.cart.z0", z),))
        if abs(z[0]) > 1e9:  # refused by the loader, as a full run of that state is (first: nothing prepared yet)
            assert got["status"] == "failed" and "z0[0]" in got["error"]
            continue
        full = run_scenario(load_scenario(path, sets + [f"loops.cart.z0=[{z[0]!r}, {z[1]!r}]"])).metrics
        assert got["status"] == full["status"] and got["metrics"]["n_samples"] == full["n_samples"]
        lean, whole = got["metrics"]["loops"]["cart"], full["loops"]["cart"]
        assert set(lean) == set(mt.GUARANTEE_METRICS) | {"law", "n_samples"}
        assert json.dumps(lean) == json.dumps({k: whole[k] for k in lean}), (i, z)
        if i == 2:
            assert lean["settle_time"] is None  # 0.6 s is too short from z0 = (1, 0)
        if i == 4:
            assert full["status"] == "diverged" and 100 < full["n_samples"] < 600
        if i == 1 or (i == 5 and name == "cart_r2_robust"):  # through the lag, state 5 has not settled by 0.6 s
            assert full["status"] == "completed" and lean["settle_time"] is not None


def test_plant_states_on_the_python_control_path_take_the_full_run():
    """RK4 has no native kernel: a simulation on the Python path is not reset, each state is the full run
    (every metric of ``ftstab run``, not the guarantee's selection), equal to run_scenario's."""
    from ftstab_mj.config.tomlfile import read_toml
    from ftstab_mj.scenario.loader import apply_override
    from ftstab_mj.scenario.run import run_scenario
    from ftstab_mj.studies.sweep.row import ScenarioTask, StatesTask

    path = ROOT / "scenarios" / "cart_r2_robust.toml"
    sets = ["sim.duration=0.2", "sim.integrator=rk4"]
    raw = read_toml(path, "scenario")
    for text in sets:
        apply_override(raw, text, str(path))
    task = StatesTask(ScenarioTask(raw, str(path)), "cart")
    for i, z in enumerate([[0.5, -0.1], [0.2, 0.3]]):
        got = task(i, (("loops.cart.z0", z),))["metrics"]["loops"]["cart"]
        full = run_scenario(load_scenario(path, sets + [f"loops.cart.z0=[{z[0]!r}, {z[1]!r}]"])).metrics
        assert set(got) > set(mt.GUARANTEE_METRICS) and json.dumps(got) == json.dumps(full["loops"]["cart"])


def test_a_state_not_settled_by_the_end_of_the_run_breaks_its_bound_only_when_its_bound_lies_within_the_run():
    """summarize(rows, applies, duration): a state that never settled in a run of 2 s with T(z0) = 1.5 s is beyond its
    bound (it must have settled by 1.5 s) and is the worst case; one with T(z0) = 5 s says nothing either way and is
    counted apart, with the run length that would show it settle."""
    nan = math.nan
    rows = [{"row": 0, "z0": [0.1, 0.0], "settle_time": 0.5, "time_bound": 1.0, "ratio": 0.5, "V1_initial": 1.0},
            {"row": 1, "z0": [0.9, 0.0], "settle_time": nan, "time_bound": 5.0, "ratio": nan, "V1_initial": 1.0},
            {"row": 2, "z0": [0.5, 0.0], "settle_time": nan, "time_bound": 1.5, "ratio": nan, "V1_initial": 1.0}]
    s = mc.summarize(rows, True, 2.0)
    assert s["violations"] == 1 and s["worst"]["row"] == 2
    assert s["unsettled_bound_beyond"] == 1 and s["longest_bound"] == 5.0 and s["never_settled"] == 2
    s = mc.summarize(rows[:2], True, 2.0)  # no late state: the worst is the largest ratio, nothing beyond its bound
    assert s["violations"] == 0 and s["worst"]["row"] == 0 and s["unsettled_bound_beyond"] == 1


@pytest.mark.parametrize("scenario, sets, on", [
    ("cart_r2_robust", [], "chain"),  # an exact twin: the native chain (fast, exact)
    ("cart_r2_robust", ["--set", "plant.friction=0.5"], "plant"),  # none: the plant itself, not a refusal
    ("cart_r2_robust", ["--engine", "serial"], "plant"),  # an engine option asks for runs of the plant
])
def test_without_on_the_monte_carlo_runs_on_the_chain_where_the_loop_has_an_exact_twin_else_on_the_plant(
        tmp_path, scenario, sets, on):
    res = run_cli("montecarlo", scenario, *sets, "--states", "3", "--set", "sim.duration=0.2", "--out", tmp_path / "o")
    assert res.returncode == 0, res.stderr
    assert res.stdout.splitlines()[0].endswith("on the ideal chain" if on == "chain" else "on the plant cart")

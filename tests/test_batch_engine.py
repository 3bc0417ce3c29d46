"""The batch engine (rows on T threads of one process) gives the serial engine's results, bit for bit.

Rows whose control runs on the native kernel step at once in several threads (the kernel finds each
call's run from its MjData); rows on the Python control path (laws without a C twin, RK4) take MuJoCo's
callback slot one at a time. Either way each row is the serial run: every metric of every row is
compared exactly, over laws x plants x integrators x loop stages, at 1 and 2 threads, rows of both
kinds mixed in one sweep.
"""

import itertools

import pytest

from conftest import ROOT, run_cli
from test_sweep_cli import results
from ftstab_mj.config.tomlfile import read_toml
from ftstab_mj.simulation import native
from ftstab_mj.studies.sweep.engine import execute
from ftstab_mj.studies.sweep.row import ScenarioTask
from ftstab_mj.studies.sweep.table import read_table

ROBUST = {"law": "robust", "k": -0.2, "gains": [1.0, 2.0], "phibar": 1.0, "gamma_m": 0.5}
ADAPTIVE = {"law": "adaptive", "k": -0.2, "gains": [1.0, 2.0], "kappa": 1.0, "delta": 0.5, "rate": 5.0, "eta": 0.5,
            "eps": 1e-4}
SUPER_TWISTING = {"law": "super_twisting", "surface": [3.0], "L": 8.0}  # the Python control path
LAWS = (ROBUST, ADAPTIVE, SUPER_TWISTING)
INTEGRATORS = ("euler", "implicitfast", "rk4")  # rk4: the Python path whatever the law
# (scenario file, loop, duration s): the cart, its loop stages (noisy sensor + differentiator, actuator
# lag), the flexible joint (r = 4: its own law) and the arm (three loops on one model)
PLANTS = (("cart_r2_robust.toml", "cart", 0.2), ("cart_r2_output_feedback.toml", "cart", 0.2),
          ("cart_r2_actuator_lag.toml", "cart", 0.2), ("flexible_joint_r4_robust.toml", None, 0.2),
          ("arm_robust.toml", None, 0.1))


def rows_of(plant_file: str, loop: str | None):
    """(index, params) of the law x integrator grid on ``plant_file`` (loop None: the file's own laws)."""
    laws = LAWS if loop else (None,)
    out = []
    for i, (law, integ) in enumerate(itertools.product(laws, INTEGRATORS)):
        params = (("sim.integrator", integ),) + (((f"loops.{loop}.controller", law),) if law else ())
        out.append((i, params))
    return out


def run_all(task, items, engine, workers):
    out = dict(execute(items, task, engine, workers))
    for r in out.values():
        assert r["status"] == "completed", r["error"]
        del r["elapsed_s"], r["started_at"]
    return out


@pytest.mark.skipif(not native.available(), reason="the C kernel is not built")
@pytest.mark.parametrize("plant_file, loop, duration", PLANTS, ids=[p[0].removesuffix(".toml") for p in PLANTS])
def test_the_batch_engine_gives_the_serial_results_bit_for_bit_at_one_and_two_threads(plant_file, loop, duration):
    base = read_toml(ROOT / "scenarios" / plant_file, "scenario")
    base["sim"]["duration"] = duration
    task = ScenarioTask(base, plant_file)
    items = rows_of(plant_file, loop)
    serial = run_all(task, items, "serial", 1)
    assert len({repr(r["metrics"]) for r in serial.values()}) > 1  # the rows differ: a mix-up would show
    for workers in (1, 2):
        assert run_all(task, items, "batch", workers) == serial, f"batch --workers {workers}"


def test_ftstab_sweep_engine_batch_writes_the_serial_table(tmp_path):
    sweep = tmp_path / "mix.toml"
    sweep.write_text(f'''name = "mix"
description = "native and Python-path rows in one sweep"
scenario = "{ROOT / "scenarios" / "cart_r2_robust.toml"}"
[set]
"sim.duration" = 0.3
[grid]
"sim.integrator" = ["euler", "rk4"]
"loops.cart.disturbance.amplitude" = [0.2, 0.4, 0.8]
''')
    tables = {}
    for name, args in (("serial", ()), ("batch1", ("--engine", "batch")), ("batch2", ("--engine", "batch", "--workers", "2"))):
        res = run_cli("sweep", sweep, "--out", tmp_path / name, *args)
        assert res.returncode == 0, res.stderr
        assert "6/6 runs in the table (6 completed)" in res.stdout, res.stdout
        tables[name] = results(read_table(tmp_path / name / "mix.parquet"))
    assert tables["batch1"] == tables["serial"] and tables["batch2"] == tables["serial"]


def test_ftstab_compare_engine_batch_writes_the_serial_table(tmp_path):
    """The shipped cart comparison (native and Python-path laws, 4 periods), shortened: the same table."""
    import csv

    tables = {}
    for name, args in (("serial", ()), ("batch", ("--engine", "batch", "--workers", "2"))):
        res = run_cli("compare", ROOT / "scenarios" / "compare" / "cart_r2.toml", "--set", "sim.duration=0.1",
                      "--out", tmp_path / name, *args)
        assert res.returncode == 0, res.stderr[-2000:]
        with open(tmp_path / name / "cart_r2.csv", newline="") as f:
            tables[name] = [{k: v for k, v in row.items() if k != "elapsed_s"} for row in csv.DictReader(f)]
    assert len(tables["serial"]) > 8 and tables["batch"] == tables["serial"]


def test_montecarlo_on_the_plant_with_engine_batch_gives_the_serial_rows(tmp_path):
    import json

    out = {}
    for name, args in (("serial", ()), ("batch", ("--engine", "batch", "--workers", "2"))):
        res = run_cli("montecarlo", ROOT / "scenarios" / "cart_r2_robust.toml", "--on", "plant", "--states", "6",
                      "--set", "sim.duration=0.2", "--out", tmp_path / name, "--json", *args)
        assert res.returncode == 0, res.stderr[-2000:]
        out[name] = json.loads(res.stdout[res.stdout.index("{"):])
    assert out["batch"] == out["serial"]


@pytest.mark.skipif(not native.available(), reason="the C kernel is not built")
def test_a_finished_runs_mjdata_serves_the_next_run_of_its_model_bit_for_bit(monkeypatch):
    # run_scenario gives its MjData back (plants.base.release_data) and the next run of the model steps it,
    # reset, instead of a new one: the samples (law and actuator-lag state in userdata) and metrics must be
    # those of a run on a new MjData
    import numpy as np

    from ftstab_mj.plants import base, make_plant
    from ftstab_mj.scenario.loader import scenario_from_dict
    from ftstab_mj.scenario.run import run_scenario

    raw = read_toml(ROOT / "scenarios" / "cart_r2_actuator_lag.toml", "scenario")
    raw["sim"]["duration"] = 0.3
    sc = scenario_from_dict(raw, "cart_r2_actuator_lag.toml")
    m, d, _ = make_plant("cart").compile(0.001)
    base.release_data(m, d)
    assert make_plant("cart").compile(0.001)[1] is d  # the spare one, not a new one
    runs = [run_scenario(sc, keep_samples=True) for _ in range(2)]  # the second on the first's MjData
    monkeypatch.setattr(base, "_SPARE", {})  # no spare MjData left: the next run makes a new one
    fresh = run_scenario(sc, keep_samples=True)
    for run in runs:
        assert run.metrics == fresh.metrics
        for name, fields in fresh.result.loops.items():
            for f, a in fields.items():
                assert np.array_equal(run.result.loops[name][f], a, equal_nan=True), (name, f)

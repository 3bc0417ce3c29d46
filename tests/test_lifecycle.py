"""The run lifecycle goes one way: the plant is built and compiled once per run, the simulation
produces samples and a status, the scenario runner feeds the sinks and the metrics, and logs/
depends on nothing above it."""

from __future__ import annotations

import ast

import numpy as np

from conftest import ROOT
from ftstab_mj.plants.base import Plant
from ftstab_mj.scenario import load_scenario
from ftstab_mj.scenario.run import run_scenario
from ftstab_mj.simulation.run_loop import simulate

# What logs/ may import: itself and what lies below it, i.e. the record contract and pure functions
# of records (metrics, control: the Rerun view draws Theorem 1's envelope), errors, the callback slot
# its viewers clear while compiling a model, the package version. Above it, never: the run loop
# (sim, native, plants), the scenario runner and loader, sweeps, the CLI.
BELOW_LOGS = ("ftstab_mj.logs", "ftstab_mj.simulation.records", "ftstab_mj.metrics.run_metrics", "ftstab_mj.control",
              "ftstab_mj.config",  # the bottom layer: any of it (tests/test_layers.py keeps config itself below all)
              "ftstab_mj.plants.callback")


def test_loading_and_running_a_scenario_compiles_the_plant_once(monkeypatch):
    calls = []
    compile_ = Plant.compile

    def counted(self, *args, **kw):
        calls.append(self.model_name)
        return compile_(self, *args, **kw)

    monkeypatch.setattr(Plant, "compile", counted)
    sc = load_scenario(ROOT / "scenarios" / "cart_r2_robust.toml", ["sim.duration=0.05"])
    assert calls == []  # validation builds the plant, it does not compile it
    run = run_scenario(sc, keep_samples=True)
    assert run.result.status == "completed" and calls == ["cart"]


def test_simulate_returns_the_samples_and_the_status_the_runner_records():
    sc = load_scenario(ROOT / "scenarios" / "cart_r2_adaptive.toml", ["sim.duration=0.3"])
    from ftstab_mj.plants import make_plant

    s = sc.sim
    res = simulate(make_plant(sc.plant.model, sc.plant.params), sc.loops, s.duration, s.period, s.physics_step,
                   s.integrator, divergence_limit=s.divergence_limit)
    recorded = run_scenario(sc, keep_samples=True)
    assert res.status == recorded.result.status == "completed"
    for f, a in res.loops["cart"].items():
        np.testing.assert_array_equal(a, recorded.result.loops["cart"][f], err_msg=f)
    assert recorded.metrics["n_samples"] == res.n_samples == 300


def _imports(path):
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            yield from (a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            yield node.module


def test_logs_import_nothing_above_them():
    """Every import in ftstab_mj/logs/ (also the ones inside functions) is of logs/ or below it."""
    bad = []
    for path in sorted((ROOT / "ftstab_mj" / "logs").glob("*.py")):
        for name in _imports(path):
            if name.startswith("ftstab_mj") and name != "ftstab_mj" and not name.startswith(BELOW_LOGS):
                bad.append(f"{path.name}: {name}")
    assert bad == []

"""Layer 7, scenario: the typed schema, the strict TOML loader with --set overrides, and running a scenario.

May import: config, control, plants, simulation, metrics, logs.

    sc = load_scenario("scenarios/cart_r2_robust.toml", ["sim.duration=2"])   # ScenarioError if bad
    result = run_scenario(sc, sinks)                                            # ftstab_mj.scenario.run
"""

from ftstab_mj.scenario.loader import apply_override, load_scenario, scenario_from_dict, scenario_to_dict
from ftstab_mj.scenario.schema import ControllerSpec, LoopSpec, PlantSpec, Scenario, SimSpec
from ftstab_mj.scenario.shipped import SCENARIO_DIR, find_scenario, shipped_scenarios

__all__ = [
    "SCENARIO_DIR", "ControllerSpec", "LoopSpec", "PlantSpec", "Scenario", "SimSpec", "apply_override",
    "find_scenario", "load_scenario", "scenario_from_dict", "scenario_to_dict", "shipped_scenarios",
]

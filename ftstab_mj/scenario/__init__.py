"""Scenarios: the typed schema, the strict TOML loader with --set overrides, and running a scenario."""

from ftstab_mj.scenario.loader import apply_override, load_scenario, scenario_from_dict, scenario_to_dict
from ftstab_mj.scenario.schema import ControllerSpec, LoopSpec, PlantSpec, Scenario, SimSpec

__all__ = [
    "ControllerSpec", "LoopSpec", "PlantSpec", "Scenario", "SimSpec", "apply_override", "load_scenario",
    "scenario_from_dict", "scenario_to_dict",
]

"""A sweep row's set-up, made once per base or per model where it can be: the result must be what the
whole set-up gives.

The row's scenario (loader.scenario_with): only the row's overridden tables are read again, the
others come from the base's memo; the result and every error must be those of validating the whole file.

The reference is the plain path: a deep copy of the base with the values set, validated by
scenario_from_dict (no memo). Rows mix values that change the model (plant mass), the law's
parameters, a signal, the initial state and a whole controller table.
"""

import copy

import pytest
from conftest import ROOT

from ftstab_mj.config import keypath
from ftstab_mj.config.errors import ScenarioError
from ftstab_mj.config.tomlfile import read_toml
from ftstab_mj.scenario.loader import scenario_from_dict, scenario_with

BASE = ROOT / "scenarios" / "cart_r2_robust.toml"

GOOD = [
    (("loops.cart.disturbance.amplitude", 0.3),),
    (("plant.mass", 2.5),),  # another model
    (("loops.cart.controller.gains", [1.5, 2.5]), ("loops.cart.z0[0]", 0.25)),
    (("loops.cart.controller", {"law": "nominal", "k": -0.2, "gains": [1.0, 2.0]}),),
    (("sim.duration", 0.5), ("loops.cart.gain.offset", 1.2)),
    (("loops.cart.disturbance.amplitude", 0.3),),  # a row seen before: the memo's own tables
]

BAD = [  # (values, the key path the one-line error names)
    (("loops.cart.disturbance.amplitude", "big"),), "loops.cart.disturbance.amplitude",
    (("plant.mass", -1.0),), "plant.mass",
    (("loops.cart.controller.gains", [1.0]),), "loops.cart.controller.gains",
    (("loops.cart.z0[1]", 2e9),), "loops.cart.z0[1]",
    (("loops.cart.gain.offset", 0.1),), "loops.cart.gain",  # a check across fields: gamma(t) > 0
    (("loops.cart.controller.k", 0.5),), "loops.cart.controller.k",  # the law's own check (Hong's k)
]


def _plain(raw, values):
    data = copy.deepcopy(raw)
    for path, value in values:
        keypath.assign(data, keypath.parse(path), value, str(BASE))
    return scenario_from_dict(data, str(BASE), {p: f"row: {p}" for p, _ in values})


def _error(fn):
    with pytest.raises(ScenarioError) as exc:
        fn()
    return str(exc.value)


def test_row_scenarios_equal_the_whole_file_validated_and_leave_the_base_unchanged():
    raw = read_toml(BASE, "scenario file (.toml)")
    before = copy.deepcopy(raw)
    scenario_from_dict(raw, str(BASE))
    masses = set()
    for values in GOOD + GOOD:  # twice: the second pass reads every table from the memo
        notes = {p: f"row: {p}" for p, _ in values}
        sc = scenario_with(raw, values, str(BASE), notes)
        assert sc == _plain(raw, values), values
        masses.add(sc.plant.params["mass"])
        assert raw == before  # the rows' values never reach the base
    assert masses == {1.0, 2.5}


@pytest.mark.parametrize("values, where", [BAD[i:i + 2] for i in range(0, len(BAD), 2)],
                         ids=[BAD[i + 1] for i in range(0, len(BAD), 2)])
def test_a_bad_row_value_is_the_same_one_line_error_after_good_rows(values, where):
    raw = read_toml(BASE, "scenario file (.toml)")
    for good in GOOD:  # the memo holds every table of the base
        scenario_with(raw, good, str(BASE), {p: f"row: {p}" for p, _ in good})
    notes = {p: f"row: {p}" for p, _ in values}
    text = _error(lambda: scenario_with(raw, values, str(BASE), notes))
    assert text == _error(lambda: _plain(raw, values))
    assert "\n" not in text and where in text and "row: " in text


def test_a_cart_seen_before_compiles_to_the_model_of_its_own_text():
    """Plant.compile of a cart whose spec was compiled before (the text skipped, Plant.spec_key) gives
    the model its parameters make: the model of its MJCF text, with its mass; rows of other masses
    in between do not leak into it."""
    import mujoco

    from ftstab_mj.plants import make_plant
    from ftstab_mj.plants.base import model_bytes

    for params in ({"mass": 1.0}, {"mass": 2.5}, {"mass": 1.0}, {"mass": 1.0, "friction": 0.3}, {"mass": 2.5}):
        for nuserdata in (0, 2):
            model, data, xml = make_plant("cart", params).compile(0.001, "euler", nuserdata)
            assert model_bytes(model) == model_bytes(mujoco.MjModel.from_xml_string(xml))
            assert model.nuserdata == nuserdata and data.userdata.shape == (nuserdata,)
            assert model.body_mass[1] == params["mass"]
            assert model.dof_frictionloss[0] == params.get("friction", 0.0)


def test_sweep_rows_of_two_masses_run_as_their_whole_scenarios_do():
    """Rows that change the model (plant.mass) between rows that do not, run by the sweep's task: each
    row's metrics are those of its scenario validated whole and run alone (every metric, exactly)."""
    from ftstab_mj.scenario.run import run_scenario
    from ftstab_mj.studies.sweep.engine import execute
    from ftstab_mj.studies.sweep.row import ScenarioTask

    raw = read_toml(BASE, "scenario file (.toml)")
    raw["sim"]["duration"] = 0.2
    rows = [(i, (("plant.mass", mass), ("loops.cart.disturbance.amplitude", amp)))
            for i, (mass, amp) in enumerate([(1.0, 0.3), (2.5, 0.3), (1.0, 0.6), (2.5, 0.6), (1.0, 0.3)])]
    got = dict(execute(rows, ScenarioTask(raw, str(BASE))))
    for i, values in rows:
        want = run_scenario(_plain(raw, values)).metrics
        assert got[i]["status"] == "completed" and got[i]["metrics"] == want, values
    assert got[0]["metrics"] == got[4]["metrics"] and got[0]["metrics"] != got[1]["metrics"]

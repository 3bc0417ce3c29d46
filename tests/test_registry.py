"""Adding a law or a plant is one module: a toy law and a toy plant, defined and registered here, run
through the scenario loader, ``simulate``, the metrics and the logs without touching the package.

The toy law is not built on Hong's controller and has a state of size 2 (the integrals of z_1 and
z_2): u = -(pd_1 z_1 + pd_2 z_2) - ki x_1, x' = (z_1, z_2). With pd = (3, 3) and ki = 1 on the unit
cart (z_1'' = u + phi) the closed loop is (s + 1)^3: a constant disturbance phi is rejected (the
integral state ends at phi / ki), where the same PD without integral leaves z_1 = phi / 3.
"""

from __future__ import annotations

import numpy as np
import pytest

from conftest import ROOT, run_cli
from ftstab_mj.simulation import native
from ftstab_mj.control import LAWS, Law, LawOutput, Param, register_law
from ftstab_mj.control.law import non_negative, unregister_law
from ftstab_mj.plants.disturbances import Signal
from ftstab_mj.config.errors import ScenarioError
from ftstab_mj.plants import PLANTS, make_plant, register_plant
from ftstab_mj.plants.cart import CartPlant
from ftstab_mj.simulation.records import LOOP_FIELDS
from ftstab_mj.scenario import LoopSpec, scenario_from_dict, scenario_to_dict
from ftstab_mj.scenario.run import run_scenario
from ftstab_mj.simulation.run_loop import Simulation
from ftstab_mj.config.tomlfile import read_toml


class ToyPI(Law):
    name = "toy_pi"
    summary = "test law: PD plus integral action, no Lyapunov function"
    params = (Param("pd", tuple[float, ...], "PD gains on z_1, z_2", "1/s^2, 1/s"),
              Param("ki", float, "integral gain", "1/s^3", non_negative, default=0.0))

    def __init__(self, r, pd, ki):
        self.r, self.pd, self.ki = r, tuple(float(g) for g in pd), float(ki)

    @classmethod
    def from_params(cls, r, values):
        return cls(r, values["pd"], values["ki"])

    @property
    def state_size(self):
        return 2

    def evaluate(self, z, state):
        u = -(self.pd[0] * z[..., 0] + self.pd[1] * z[..., 1]) - self.ki * state[..., 0]
        nan = np.full_like(u, np.nan)
        return LawOutput(u, nan, nan, nan, nan, nan)

    def state_derivative(self, z, state, out):
        return z[..., :2]


@pytest.fixture
def toy_law():
    register_law(ToyPI)
    try:
        yield ToyPI
    finally:
        unregister_law(ToyPI.name)


@pytest.fixture
def toy_plant():
    register_plant("heavy_cart", lambda name, params: CartPlant("cart", {"mass": 3.0, **params}, integrating=False),
                   "test plant: the cart with 3 kg by default")
    try:
        yield "heavy_cart"
    finally:
        del PLANTS["heavy_cart"]


def _raw(model="cart", **controller):
    raw = read_toml(ROOT / "scenarios" / "cart_r2_robust.toml", "scenario")
    raw["plant"] = {"model": model}
    raw["sim"].update(duration=20.0, physics_step=0.01, period=0.01)
    lp = raw["loops"]["cart"]
    lp["controller"] = controller
    lp["disturbance"] = {"kind": "constant", "offset": 0.3}
    lp["gain"] = {"kind": "constant", "offset": 1.0}
    return raw


def test_a_law_registered_in_one_module_runs_through_loader_sim_metrics_and_logs(toy_law, tmp_path):
    from ftstab_mj.logs import McapSink
    from ftstab_mj.logs.reader import read_log

    sc = scenario_from_dict(_raw(law="toy_pi", pd=[3.0, 3.0], ki=1.0), "toy.toml")
    assert scenario_to_dict(sc)["loops"]["cart"]["controller"] == {"law": "toy_pi", "pd": [3.0, 3.0], "ki": 1.0}
    run = run_scenario(sc, [McapSink(tmp_path / "toy.mcap")], keep_samples=True)
    res = run.result
    assert res.status == "completed" and res.n_samples == 2000
    (loop,) = res.info.loops
    assert (loop.law, loop.hong, loop.law_params) == ("toy_pi", {}, {"pd": (3.0, 3.0), "ki": 1.0})
    a = res.loops["cart"]
    # the state is the integral of z with z held over each period; u follows the law from it
    x1 = np.concatenate([[0.0], np.cumsum(0.01 * a["z"][:-1, 0])])
    np.testing.assert_allclose(a["u"], -(3.0 * a["z"][:, 0] + 3.0 * a["z"][:, 1]) - x1, rtol=1e-12, atol=1e-15)
    # no Lyapunov function, no u = gamma_hat u0 + phi_hat sign(u0) form: NaN in the log, None in the metrics
    for f in ("V1", "dV1_dzr", "u0", "phi_hat", "gamma_hat"):
        assert np.all(np.isnan(a[f])), f
    m = run.metrics["loops"]["cart"]
    assert m["V1_final"] is None and m["time_bound"] is None and m["theorem3"] is None
    # the integral action rejects the 0.3 m/s^2 disturbance: poles (s+1)^3, so after 20 s what is left
    # of the transient is O(t^2 e^-t) = 1e-6
    assert abs(a["z"][-1, 0]) < 1e-5 and x1[-1] == pytest.approx(0.3, rel=1e-4)
    log = read_log(tmp_path / "toy.mcap")
    assert log.complete and log.info.loops[0].law == "toy_pi" and log.recorded["metrics"] == run.metrics


def test_without_integral_the_toy_law_keeps_the_static_offset(toy_law):
    """The control experiment of the one above: same law, ki defaulted to 0 -> z_1 = phi / pd_1."""
    sc = scenario_from_dict(_raw(law="toy_pi", pd=[3.0, 3.0]), "toy.toml")
    assert sc.loops[0].controller.ki == 0.0  # the Param default, filled in by the schema
    z = run_scenario(sc, keep_samples=True).result.loops["cart"]["z"]
    assert z[-1, 0] == pytest.approx(0.1, rel=1e-3)


@pytest.mark.parametrize("controller, key", [
    ({"law": "toy_pi"}, "loops.cart.controller.pd"),  # required
    ({"law": "toy_pi", "pd": [3.0, 3.0], "ki": -1.0}, "loops.cart.controller.ki"),  # the Param's check
    ({"law": "toy_pi", "pd": [3.0, 3.0], "kappa": 1.0}, "loops.cart.controller.kappa"),  # another law's
    ({"law": "robust", "k": -0.2, "gains": [1, 2], "phibar": 1, "gamma_m": 0.5, "pd": [1, 1]},
     "loops.cart.controller.pd"),
    ({"law": "toy_p", "pd": [3.0, 3.0]}, "loops.cart.controller.law"),
])
def test_the_loader_validates_a_registered_laws_keys(toy_law, controller, key):
    with pytest.raises(ScenarioError) as err:
        scenario_from_dict(_raw(**controller), "toy.toml")
    assert err.value.path == key


def test_a_law_state_of_any_size_is_in_the_saved_state(toy_law):
    law = ToyPI(2, (3.0, 3.0), 1.0)
    loops = [LoopSpec("cart", controller=law, z0=(1.0, 0.0), disturbance=Signal("sine", amplitude=0.5, freq=2.0))]
    sim = Simulation(make_plant("cart"), loops, period=0.01, physics_step=0.005)
    assert sim.data.userdata.shape == (2,)
    with sim.installed():
        sim.advance(50)
        saved = sim.get_state()
        first = sim.advance(30)
        sim.set_state(saved)
        second = sim.advance(30)
        sim.set_state(saved)
        sim.data.userdata[1] += 1.0  # x_2 is not used by u: the continuation is the same
        third = sim.advance(30)
        sim.set_state(saved)
        sim.data.userdata[0] += 1.0  # x_1 is: it differs
        fourth = sim.advance(30)
    for f in LOOP_FIELDS:
        np.testing.assert_array_equal(first.loops["cart"][f], second.loops["cart"][f], err_msg=f)
        np.testing.assert_array_equal(first.loops["cart"][f], third.loops["cart"][f], err_msg=f)
    assert not np.array_equal(first.loops["cart"]["u"], fourth.loops["cart"]["u"])


def test_a_law_without_a_native_twin_runs_in_python_or_refuses_native(toy_law):
    loops = [LoopSpec("cart", controller=ToyPI(2, (3.0, 3.0), 1.0), z0=(1.0, 0.0))]
    assert Simulation(make_plant("cart"), loops, period=0.01, physics_step=0.01)._native is None
    if native.available():
        with pytest.raises(native.NativeUnavailable, match="ToyPI"):
            Simulation(make_plant("cart"), loops, period=0.01, physics_step=0.01, native=True)


def test_each_law_reads_its_own_declaration_of_a_shared_key(toy_law):
    """Each law owns its parameter table: a plugin may call a parameter ki without asking toy_pi."""
    assert "toy_pi" in LAWS

    class Clash(ToyPI):
        name = "clash"
        params = (Param("ki", float, "another meaning of ki", check=lambda v: None if v >= 10 else "a number >= 10"),)

        @classmethod
        def from_params(cls, r, values):
            return cls(r, (3.0, 3.0), values["ki"])

    register_law(Clash)
    try:
        ok = scenario_from_dict(_raw(law="clash", ki=12.0), "toy.toml")
        assert ok.loops[0].controller.ki == 12.0
        with pytest.raises(ScenarioError, match=r"loops\.cart\.controller\.ki: expected a number >= 10, found 1\.0"):
            scenario_from_dict(_raw(law="clash", ki=1.0), "toy.toml")
        with pytest.raises(ScenarioError, match=r"loops\.cart\.controller\.pd: expected only the clash law's "
                           r"parameters \(ki\), found pd = \[3\.0, 3\.0\] \(an array\), a parameter of another law"):
            scenario_from_dict(_raw(law="clash", ki=12.0, pd=[3.0, 3.0]), "toy.toml")
    finally:
        unregister_law("clash")


def test_a_plant_registered_in_one_module_is_a_scenario_model(toy_plant):
    robust = dict(law="robust", k=-0.2, gains=[1.0, 2.0], phibar=1.0, gamma_m=0.5)
    runs = {}
    for model in ("heavy_cart", "cart"):
        raw = _raw(model=model, **robust)
        raw["sim"]["duration"] = 0.5
        runs[model] = run_scenario(scenario_from_dict(raw, "toy.toml"), keep_samples=True).result
    assert make_plant("heavy_cart").params["mass"] == 3.0
    assert runs["heavy_cart"].info.scenario["plant"]["model"] == "heavy_cart"
    # the cart's actuator gain and disturbance scale are its mass: in chain units both runs coincide
    np.testing.assert_allclose(runs["heavy_cart"].loops["cart"]["z"], runs["cart"].loops["cart"]["z"],
                               rtol=1e-9, atol=1e-12)
    with pytest.raises(ScenarioError) as err:
        scenario_from_dict(_raw(model="heavy_kart", law="nominal", k=-0.2, gains=[1.0, 2.0]), "toy.toml")
    assert err.value.path == "plant.model" and "heavy_cart" in str(err.value)


def test_ftstab_list_shows_the_registered_laws_with_their_keys_and_the_plants():
    out = run_cli("list").stdout
    for name, cls in LAWS.items():
        assert f"  {name}: {cls.summary}" in out
        for p in cls.all_params():
            assert f"      {p.name}: {p.describe()}" in out
    for name, entry in PLANTS.items():
        assert f"  {name}: {entry.summary}" in out

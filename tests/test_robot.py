"""Your robot: models the project did not write, with contacts, joint limits and a planar floating base
(gymnasium's hopper), a clamped actuator (gymnasium's inverted pendulum: ctrlrange +-3) and tracking.

Checked from the runs' logs: the physics identity increment(z_2) = h (phi + gamma u_applied) per
control period (phi and gamma the true ones, from MuJoCo's full dynamics: contact and limit forces
included), the control the plant received beside the law's, and the tracking error z_1 = q - ref(t).
"""

import math
from pathlib import Path

import gymnasium
import numpy as np
import pytest
from conftest import run_cli

import ftstab_mj
from ftstab_mj.config.errors import ScenarioError
from ftstab_mj.plants import make_plant
from ftstab_mj.plants.reference import Reference
from ftstab_mj.scenario import load_scenario
from ftstab_mj.scenario.loader import scenario_from_dict, scenario_to_dict
from ftstab_mj.simulation.run_loop import simulate

ASSETS = Path(gymnasium.__file__).parent / "envs" / "mujoco" / "assets"
HOPPER_LOOPS = ("thigh", "leg", "foot")
ADAPTIVE = '{law = "adaptive", k = -0.2, gains = [1.0, 2.0], kappa = 0.006, delta = 0.001, rate = 0.5, eta = 0.5, eps = 3e-3}'
HOPPER = """name = "hopper"
description = "gymnasium's hopper: three actuated joints hold set points while the body falls on the floor"
[plant]
model = "{model}"
{plant}
[sim]
duration = {duration}
physics_step = 0.002
period = 0.002
{loops}
"""


def _hopper(tmp_path, controller=ADAPTIVE, duration=3.0, plant_extra=""):
    plant = "\n".join(f'[plant.loops.{n}]\njoint = "{n}_joint"\nsaturation = true' for n in HOPPER_LOOPS)
    refs = {"thigh": -0.3, "leg": -0.3, "foot": 0.2}
    loops = "\n".join(f"[loops.{n}]\nz0 = [0.1, 0.0]\nref = {refs[n]}\ncontroller = {controller}" for n in HOPPER_LOOPS)
    path = tmp_path / "hopper.toml"
    path.write_text(HOPPER.format(model=ASSETS / "hopper.xml", plant=plant + plant_extra, loops=loops, duration=duration))
    return path


def _identity_residual(a: dict, u_field: str = "u_applied") -> np.ndarray:
    """|increment of z_2 - h (phi + gamma u)| / |increment of z_2| per control period (Euler: exact but for
    MuJoCo's implicit joint damping, O(h damping / inertia))."""
    h = a["t"][1] - a["t"][0]
    inc = np.diff(a["z"][:, 1])
    pred = h * (a["phi"][:-1] + a["gamma"][:-1] * a[u_field][:-1])
    return np.abs(inc - pred) / np.maximum(np.abs(inc), 1e-9)


def test_hopper_holds_set_points_under_the_adaptive_law_through_floor_contact_with_no_workspace(tmp_path):
    """Figures (3 s, h = 2 ms): |z_1| <= 0.027 / 0.028 / 0.036 rad over the final 20 % (from 0.1 rad);
    the torso falls from 1.25 m to 1.14 m on the floor; the identity's 95th percentile residual is
    0.25 %, contacts and limits included (MuJoCo's implicit joint damping is the rest); the foot, pushed
    by the floor, is clamped by its ctrlrange 32 % of the time."""
    path = _hopper(tmp_path)
    plant = make_plant(str(ASSETS / "hopper.xml"), load_scenario(path).plant.params)
    note = plant.notes[-1]
    assert "joint limits ('thigh_joint', 'leg_joint', 'foot_joint')" in note and "contacts that can happen" in note
    res = ftstab_mj.run(path, out=tmp_path / "runs")
    assert res.status == "completed", res.message
    log = ftstab_mj.replay(res.logs["mcap"])  # everything below from the log
    for name in HOPPER_LOOPS:
        a, m = log.samples[name], log.metrics["loops"][name]
        assert m["final_abs_z_max"][0] < 0.04, (name, m["final_abs_z_max"])
        assert np.percentile(_identity_residual(a), 95) < 0.05
        assert m["clamp"] == "ctrlrange [-1, 1]" and m["u_applied_max_abs"] <= 1.0
        assert np.array_equal(a["u_applied"], np.clip(a["u"], -1.0, 1.0))
    torso = res.body_pos[:, 0, 2]  # the first body: the torso, starting at 1.25 m
    assert torso[0] == pytest.approx(1.25) and torso.min() < 1.2


def test_hopper_robust_law_native_and_python_callbacks_agree_bit_for_bit_with_contacts(tmp_path):
    """The constraint solver's phi and gamma (kernel.c chain_full against ChainPlant._full_chain) and
    everything else, sample for sample, under a second law (robust, bounds by hand)."""
    robust = '{law = "robust", k = -0.2, gains = [1.0, 2.0], phibar = 60.0, gamma_m = 120.0}'
    sc = load_scenario(_hopper(tmp_path, controller=robust, duration=1.0))
    runs = {nat: simulate(make_plant(sc.plant.model, sc.plant.params), sc.loops, 1.0, sc.sim.period,
                          sc.sim.physics_step, native=nat) for nat in (True, False)}
    for name in HOPPER_LOOPS:
        a, b = runs[True].loops[name], runs[False].loops[name]
        for f in ("z", "u", "u_applied", "phi", "gamma"):
            assert np.array_equal(a[f], b[f]), (name, f)
        assert abs(a["z"][-1, 0]) < 0.035 and np.percentile(_identity_residual(a), 95) < 0.05


def test_computed_bounds_on_the_hopper_are_refused_in_one_line_naming_everything_missing(tmp_path):
    computed = '{law = "robust", k = -0.2, gains = [1.0, 2.0], phibar = "computed", gamma_m = "computed"}'
    proc = run_cli("run", _hopper(tmp_path, controller=computed), "--out", tmp_path / "out")
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "..." not in lines[0], proc.stderr
    line = lines[0]
    assert "loops.thigh.controller.phibar" in line and "contacts can happen" in line
    for joint in ("rootx", "rootz", "rooty", "thigh_joint", "leg_joint", "foot_joint"):
        assert repr(joint) in line
    assert "u_max in [plant.loops.<name>] for 'thigh', 'leg', 'foot'" in line


ST_PENDULUM = {"loops": {"cart": {"joint": "slider", "saturation": True}}}


def test_clamped_super_twisting_logs_the_applied_control_beside_the_laws(tmp_path):
    """gymnasium's inverted pendulum (ctrlrange +-3): super-twisting asks for |u| = 5.2, the plant gets 3.
    Metrics say both; the log holds u_applied; the identity holds with u_applied, not with u."""
    path = tmp_path / "st.toml"
    path.write_text(f"""name = "pendulum_st"
description = "super-twisting clamped by the actuator's ctrlrange"
[plant]
model = "{ASSETS / 'inverted_pendulum.xml'}"
[plant.loops.cart]
joint = "slider"
saturation = true
[sim]
duration = 1.0
[loops.cart]
z0 = [-0.3, 0.0]
ref = 0.1
[loops.cart.controller]
law = "super_twisting"
surface = [2.0]
L = 20.0
""")
    res = ftstab_mj.run(path, out=tmp_path / "runs")
    m = res.metrics["loops"]["cart"]
    assert m["u_max_abs"] > 5.0 and m["u_applied_max_abs"] == 3.0, m
    assert m["clamp"] == "ctrlrange [-3, 3]" and 0 < m["saturated_fraction"] < 1
    assert m["bound_applies"] is False and "clamped the law's u" in m["bound_applies_reason"]
    from ftstab_mj.studies.compare import table_row  # the comparison table's row: both controls

    row = table_row(("st", {"law": "super_twisting"}, None, True), {"status": "completed", "metrics": res.metrics},
                    "cart", None)
    assert row["u_max_abs"] == m["u_max_abs"] and row["u_applied_max_abs"] == 3.0
    log = ftstab_mj.replay(res.logs["mcap"])
    a = log.samples["cart"]
    assert np.array_equal(a["u_applied"], res.samples["cart"]["u_applied"])
    assert log.metrics["loops"]["cart"]["u_applied_max_abs"] == 3.0
    clamped = a["u_applied"][:-1] != a["u"][:-1]
    assert clamped.any()
    assert np.percentile(_identity_residual(a), 95) < 0.05
    assert np.max(_identity_residual(a, "u")[clamped]) > 0.5  # the law's u is not what the plant received


def _cart_tracking(reference: str, z0="[0.1, 0.0]", duration=8.0, extra=()):
    raw = {"name": "cart_track", "description": "the cart tracks a reference", "plant": {"model": "cart"},
           "sim": {"duration": duration},
           "loops": {"cart": {"z0": eval(z0), "reference": reference,
                              "controller": {"law": "robust", "k": -0.2, "gains": [1.0, 2.0], "phibar": 4.0,
                                             "gamma_m": 0.8},
                              "disturbance": {"kind": "sine", "amplitude": 0.5, "freq": 1.0}}}}
    return scenario_from_dict(raw)


def test_the_cart_tracks_a_sine_with_the_robust_law():
    """0.3 sin(2 pi 0.5 t) from 0.1 m off, under a 0.5 sine disturbance: |x - ref| <= 0.3 mm over the
    final 20 % of 8 s; the logged z_1 is x - ref(t) bit for bit; the native and Python paths agree."""
    sc = _cart_tracking({"kind": "sine", "amplitude": 0.3, "freq": 0.5})
    res = ftstab_mj.run(sc)
    a, m = res.samples["cart"], res.metrics["loops"]["cart"]
    assert m["final_abs_z_max"][0] < 1e-3 and m["settle_time_z1"] < 5.0, m
    # phibar = 4 covers the disturbance's 0.5 plus max |ref''| = 0.3 pi^2
    assert m["reference_r_max_abs"] == pytest.approx(0.3 * math.pi ** 2) and m["phibar_covers_reference"] is True
    x = res.body_pos[:, 0, 0]  # the cart's position (its body sits on the slide's origin)
    ref = 0.3 * np.sin(2 * math.pi * 0.5 * a["t"])
    assert np.array_equal(a["z"][:, 0], x - ref)
    info = res.scenario["loops"]["cart"]["reference"]
    assert info == {"kind": "sine", "offset": 0.0, "amplitude": 0.3, "freq": 0.5, "phase": 0.0}
    runs = {nat: simulate(make_plant("cart"), sc.loops, 2.0, sc.sim.period, sc.sim.physics_step, native=nat)
            for nat in (True, False)}
    for f in ("z", "u", "phi", "gamma"):
        assert np.array_equal(runs[True].loops["cart"][f], runs[False].loops["cart"][f]), f
    lp = runs[True].info.loops[0]  # ref'' = -0.3 pi^2 sin enters phi and its bound
    assert lp.true_phibar == pytest.approx(0.5 + 0.3 * math.pi ** 2)
    t = runs[True].loops["cart"]["t"]
    assert np.allclose(runs[True].loops["cart"]["phi"], 0.5 * np.sin(2 * math.pi * t) + 0.3 * math.pi ** 2 * np.sin(math.pi * t))


def test_a_constant_reference_table_is_the_set_point_bit_for_bit():
    a = ftstab_mj.run(_cart_tracking({"kind": "constant", "value": 0.2}, duration=1.0)).samples["cart"]
    sc = _cart_tracking({"kind": "constant", "value": 0.2}, duration=1.0)
    raw = scenario_to_dict(sc)
    del raw["loops"]["cart"]["reference"]
    raw["loops"]["cart"]["ref"] = 0.2
    b = ftstab_mj.run(scenario_from_dict(raw)).samples["cart"]
    for f in a:
        assert np.array_equal(a[f], b[f]), f


@pytest.mark.parametrize("ref", [Reference("polynomial", coeffs=(0.1, -0.2, 0.3, -0.05)),
                                 Reference("min_jerk", start=-0.2, end=0.4, t_start=0.5, duration=1.5),
                                 Reference("sine", offset=0.1, amplitude=0.2, freq=0.7, phase=0.3)])
def test_reference_derivatives_match_finite_differences(ref):
    t = np.linspace(0.0, 3.0, 30001)
    d = ref.derivatives(t, 3)
    h = t[1] - t[0]
    inner = np.ones(len(t), dtype=bool)
    inner[:5] = inner[-5:] = False
    if ref.kind == "min_jerk":  # its third derivative jumps at both ends
        inner &= (np.abs(t - ref.t_start) > 5 * h) & (np.abs(t - ref.t_start - ref.duration) > 5 * h)
    for j in range(3):
        fd = np.gradient(d[:, j], h)
        assert np.allclose(fd[inner], d[inner, j + 1], atol=2e-3 * max(1.0, np.abs(d[:, j + 1]).max())), j
    assert np.all(ref.max_abs(3, 3.0) >= np.abs(d).max(axis=0) - 1e-9)
    back = scenario_from_dict(scenario_to_dict(_cart_tracking({"kind": ref.kind, **{
        k: list(v) if isinstance(v, tuple) else v for k, v in ref.describe(1, 1.0).items() if k not in ("kind", "max_abs")}},
        duration=0.5)))
    assert back.loops[0].reference == ref


def test_the_cart_follows_a_min_jerk_move():
    sc = _cart_tracking({"kind": "min_jerk", "start": 0.0, "end": 0.5, "t_start": 0.5, "duration": 2.0},
                        z0="[0.0, 0.0]", duration=5.0)
    res = ftstab_mj.run(sc)
    a = res.samples["cart"]
    x = res.body_pos[:, 0, 0]
    assert abs(x[-1] - 0.5) < 1e-3 and np.max(np.abs(a["z"][:, 0])) < 5e-3


@pytest.mark.parametrize("loop,found", [
    ({"ref": 0.1, "reference": {"kind": "sine", "amplitude": 0.1, "freq": 1.0}}, "either ref"),
    ({"reference": {"kind": "sine", "amplitude": 0.1, "coeffs": [1.0]}}, "only keys that a sine reference uses"),
    ({"reference": {"kind": "spline"}}, "one of constant, sine, polynomial, min_jerk"),
    ({"reference": {"kind": "min_jerk", "duration": 0.0}}, "a duration > 0"),
])
def test_reference_tables_are_checked_in_one_line(loop, found):
    raw = scenario_to_dict(_cart_tracking({"kind": "constant", "value": 0.0}, duration=0.5))
    raw["loops"]["cart"].pop("reference")
    raw["loops"]["cart"].pop("ref", None)
    raw["loops"]["cart"].update(loop)
    with pytest.raises(ScenarioError, match="loops.cart.ref") as exc:
        scenario_from_dict(raw)
    assert found in str(exc.value)


def test_a_computed_phibar_covers_the_references_second_derivative():
    raw = scenario_to_dict(_cart_tracking({"kind": "sine", "amplitude": 0.3, "freq": 0.5}, duration=0.5))
    raw["loops"]["cart"]["controller"]["phibar"] = "computed"
    sc = scenario_from_dict(raw)
    assert sc.loops[0].controller.phibar == pytest.approx(0.5 + 0.3 * math.pi ** 2)


def test_hopper_log_replays_with_verify_and_reports_in_rad_under_a_short_title(tmp_path):
    """Its builtin textures read no file: --verify re-runs it from the logged XML, bit for bit; the
    report names the model's file (not its path) and draws the joints in rad."""
    res = ftstab_mj.run(_hopper(tmp_path, duration=0.2), out=tmp_path / "runs")
    proc = run_cli("replay", "--verify", res.logs["mcap"])
    assert proc.returncode == 0 and "bit-identical" in proc.stdout, proc.stdout + proc.stderr
    from ftstab_mj.figures.run_report import report_data
    from ftstab_mj.logs.reader import read_log

    rep = report_data(read_log(res.logs["mcap"]))
    assert "plant hopper.xml," in rep.title and str(ASSETS) not in rep.title
    assert rep.loops["thigh"][0].ylabel == "z1 (rad)"


def test_api_overrides_take_a_dict_as_a_table_and_scenarios_come_from_dicts(tmp_path):
    table = {"law": "nominal", "k": -0.2, "gains": [1.0, 2.0]}
    sc = ftstab_mj.load_scenario("cart_r2_robust", overrides={"loops.cart.controller": table, "sim.duration": 0.5})
    assert sc.loops[0].controller.law == "nominal" and sc.sim.duration == 0.5
    data = scenario_to_dict(sc)
    back = ftstab_mj.scenario_from_dict(data, overrides={"sim.duration": 0.25})
    assert back.sim.duration == 0.25 and back.loops == sc.loops
    (tmp_path / "robot.xml").write_text((ASSETS / "inverted_pendulum.xml").read_text())
    user = ftstab_mj.scenario_from_dict({"name": "p", "description": "d", "plant": {
        "model": "robot.xml", "loops": {"cart": {"joint": "slider", "saturation": True}}}, "sim": {"duration": 0.1},
        "loops": {"cart": {"z0": [0.0, 0.0], "controller": table}}}, base_dir=tmp_path)
    assert user.plant.model == str(tmp_path / "robot.xml")
    with pytest.raises(ScenarioError, match=r"loops.cart.controller.gains"):
        ftstab_mj.load_scenario("cart_r2_robust", overrides={"loops.cart.controller": {**table, "gains": [1.0]}})



def _pendulum(tmp_path, pole: str):
    """The scenario of docs/your-robot.md (the robust law, bounds computed over a workspace of both
    joints) on gymnasium's inverted pendulum, its pole upright or hung down (``pole``: the geom's fromto).
    Returns the run, the controller (its phibar and gamma_m computed) and the pole's angle (n,) rad."""
    xml = (ASSETS / "inverted_pendulum.xml").read_text()
    assert 'fromto="0 0 0 0.001 0 0.6"' in xml
    (tmp_path / "pendulum.xml").write_text(xml.replace('fromto="0 0 0 0.001 0 0.6"', f'fromto="{pole}"'))
    raw = {"name": "my_pendulum", "description": "the robust law moves the cart, bounds computed",
           "plant": {"model": "pendulum.xml", "grid": 7,
                     "loops": {"cart": {"joint": "slider", "saturation": True, "u_max": 1.0}},
                     "workspace": {"slider": {"q": [-0.5, 0.5], "qd_max": 1.0},
                                   "hinge": {"q": [-0.5, 0.5], "qd_max": 2.0}}},
           "sim": {"duration": 2.0},
           "loops": {"cart": {"z0": [-0.2, 0.0], "ref": 0.1, "controller": {
               "law": "robust", "k": -0.2, "gains": [1.0, 2.0], "phibar": "computed", "gamma_m": "computed"}}}}
    sc = ftstab_mj.scenario_from_dict(raw, base_dir=tmp_path)
    res = ftstab_mj.run(sc)
    pole = 2.0 * np.arctan2(res.body_quat[:, 1, 2], res.body_quat[:, 1, 0])  # body 1, the pole, turns about y
    return res, sc.loops[0].controller, pole


def test_the_time_bound_is_not_claimed_once_the_logged_phi_or_gamma_left_the_computed_bounds(tmp_path):
    """Upright, the passive pole falls out of the workspace of the computed bounds (|hinge| <= 0.5 rad)
    while the cart's own z stays in its workspace: the logged true gamma leaves [gamma_m, ...) the law
    assumed, so T(z0) is not claimed, and the reason names the loop, the quantity, the bound and the
    first sample out. Hung down, the pole swings inside and the same law's bound is claimed (and beaten)."""
    res, law, pole = _pendulum(tmp_path, "0 0 0 0.001 0 0.6")
    m, a = res.metrics["loops"]["cart"], res.samples["cart"]
    assert np.max(np.abs(pole)) > 0.5 and m["workspace_left"] == ""  # the pole left, the cart did not
    assert m["bound_applies"] is False and m["beat_bound"] is None, m
    out = (np.abs(a["phi"]) > law.phibar) | (a["gamma"] < law.gamma_m)  # Theorem 2's hypothesis, per sample
    k = int(np.argmax(out))
    assert out[k] and m["bound_applies_reason"] == (
        f"loop 'cart': the logged true gamma reached {a['gamma'][k]:.4g} at t = {a['t'][k]:.6g} s, outside the "
        f"bounds the law assumed (phibar = {law.phibar:.4g}, gamma_m = {law.gamma_m:.4g})")
    res, law, pole = _pendulum(tmp_path, "0 0 0 0.001 0 -0.6")
    m, a = res.metrics["loops"]["cart"], res.samples["cart"]
    assert np.max(np.abs(pole)) < 0.5 and m["workspace_left"] == ""
    assert np.max(np.abs(a["phi"])) <= law.phibar and np.min(a["gamma"]) >= law.gamma_m
    assert m["bound_applies"] is True and m["beat_bound"] is True and m.get("bound_applies_reason") is None, m


@pytest.mark.parametrize("phibar, covers", [(2.0, False), (3.2, False), (3.5, True)])
def test_the_metrics_say_whether_phibar_covers_the_references_rth_derivative(phibar, covers):
    """max |ref''| = 0.3 pi^2 = 2.96 and the disturbance's 0.5: phibar 2 misses the reference alone,
    3.2 the sum 3.46, 3.5 covers both."""
    raw = scenario_to_dict(_cart_tracking({"kind": "sine", "amplitude": 0.3, "freq": 0.5}, duration=0.2))
    raw["loops"]["cart"]["controller"]["phibar"] = phibar
    m = ftstab_mj.run(scenario_from_dict(raw)).metrics["loops"]["cart"]
    assert m["reference_r_max_abs"] == pytest.approx(0.3 * math.pi ** 2)
    assert m["phibar_covers_reference"] is covers


FILE_SAMPLES = "t, x\n" + "".join(f"{0.5 * k}, {0.2 * math.sin(0.4 * k):.6f}\n" for k in range(17))


@pytest.mark.parametrize("smooth", [1, 2, 3, 5])
def test_a_file_reference_passes_through_its_samples_with_smooth_continuous_derivatives(smooth):
    """The min-jerk-like join of samples: ref(t_k) = v_k, ref^(j)(t_k) = 0 (j = 1..smooth), ref between
    consecutive samples, ref^(j) continuous for j <= smooth (its one-sided limits at a sample agree),
    the derivatives those of ref by finite differences, max_abs a bound of the dense maxima."""
    T = np.array([0.0, 0.4, 1.0, 1.3, 2.5])
    V = np.array([0.1, -0.2, 0.3, 0.3, 0.0])
    ref = Reference("file", times=tuple(T), values=tuple(V), smooth=smooth)
    at = ref.derivatives(T, smooth + 1)
    assert np.allclose(at[:, 0], V, atol=1e-12, rtol=0) and np.allclose(at[:, 1:smooth + 1], 0.0, atol=1e-9)
    bound = ref.max_abs(smooth + 1, 3.0)
    for e in (1e-7, -1e-7):  # both sides of every inner sample: |ref^(j)| <= |e| max |ref^(j+1)| (mean value)
        near = np.abs(ref.derivatives(T[1:-1] + e, smooth)[:, 1:])
        assert np.all(near <= abs(e) * bound[2:] * (1 + 1e-9) + 1e-15), e
    t = np.linspace(-0.5, 3.0, 35001)
    d = ref.derivatives(t, smooth + 1)
    k = np.clip(np.searchsorted(T, t, side="right") - 1, 0, len(T) - 2)
    assert np.all(d[:, 0] >= np.minimum(V[k], V[k + 1]) - 1e-12) and np.all(d[:, 0] <= np.maximum(V[k], V[k + 1]) + 1e-12)
    assert np.all(d[t < 0, 0] == V[0]) and np.all(d[t > T[-1], 0] == V[-1])
    h = t[1] - t[0]
    inner = np.min(np.abs(t[:, None] - T[None, :]), axis=1) > 5 * h
    for j in range(smooth + 1):
        fd = np.gradient(d[:, j], h)
        assert np.allclose(fd[inner], d[inner, j + 1], atol=2e-3 * np.abs(d[:, j + 1]).max()), j
    assert np.all(ref.max_abs(smooth + 1, 3.0) >= np.abs(d).max(axis=0) - 1e-9)


def test_the_cart_tracks_a_file_of_samples_on_the_native_and_python_paths(tmp_path):
    """A CSV beside the scenario (its path relative to it): the logged z_1 is x - ref(t) with ref the
    smoothed samples; the scenario keeps the samples (a log re-runs without the file); both callbacks
    give the same bits."""
    (tmp_path / "path.csv").write_text(FILE_SAMPLES)
    sc = ftstab_mj.scenario_from_dict({
        "name": "cart_file", "description": "the cart tracks samples", "plant": {"model": "cart"}, "sim": {"duration": 8.0},
        "loops": {"cart": {"z0": [0.05, 0.0], "reference": {"kind": "file", "path": "path.csv"},
                           "controller": {"law": "robust", "k": -0.2, "gains": [1.0, 2.0], "phibar": "computed",
                                          "gamma_m": "computed"}}}}, base_dir=tmp_path)
    ref = sc.loops[0].reference
    assert ref.times == tuple(0.5 * k for k in range(17)) and ref.path == str(tmp_path / "path.csv")
    (tmp_path / "path.csv").unlink()  # the scenario holds its samples
    res = ftstab_mj.run(scenario_from_dict(scenario_to_dict(sc)))
    a, m = res.samples["cart"], res.metrics["loops"]["cart"]
    assert np.array_equal(a["z"][:, 0], res.body_pos[:, 0, 0] - ref.derivatives(a["t"], 0)[:, 0])
    assert m["final_abs_z_max"][0] < 1e-3 and m["phibar_covers_reference"] is True, m
    runs = {nat: simulate(make_plant("cart"), sc.loops, 2.0, sc.sim.period, sc.sim.physics_step, native=nat)
            for nat in (True, False)}
    for f in ("z", "u", "phi", "gamma"):
        assert np.array_equal(runs[True].loops["cart"][f], runs[False].loops["cart"][f]), f


@pytest.mark.parametrize("text, found", [
    ("t, x\n0, 0.1\n", "at least two samples t, value, found path.csv: 1"),
    ("0, 0.1\n0.5, x\n", "lines of two numbers t, value, found path.csv line 2: '0.5, x'"),
    ("0, 0.1\n0.5, 0.2\n0.5, 0.3\n", "times t strictly increasing, found path.csv line 3: t = 0.5 after 0.5"),
    ("0, 0.1, 3\n1, 0.2\n", "lines of two numbers t, value, found path.csv line 1: '0, 0.1, 3'"),
    (None, "a CSV file of samples t, value, found path.csv: "),
])
def test_a_bad_samples_file_is_refused_in_one_line_with_exit_2(tmp_path, text, found):
    if text is not None:
        (tmp_path / "path.csv").write_text(text)
    (tmp_path / "s.toml").write_text('name = "f"\ndescription = "d"\n[plant]\nmodel = "cart"\n[sim]\nduration = 0.1\n'
                                     '[loops.cart]\nz0 = [0.0, 0.0]\n[loops.cart.reference]\nkind = "file"\n'
                                     'path = "path.csv"\n[loops.cart.controller]\nlaw = "nominal"\nk = -0.2\n'
                                     'gains = [1.0, 2.0]\n')
    out = run_cli("run", tmp_path / "s.toml", "--out", tmp_path / "runs")
    lines = out.stderr.strip().splitlines()
    assert out.returncode == 2 and len(lines) == 1 and "loops.cart.reference.path" in lines[0], out.stderr
    assert found in lines[0] and not (tmp_path / "runs").exists(), lines[0]


def test_a_file_reference_too_rough_for_the_chain_is_refused():
    """ref^(r) enters phi: a chain of length 4 needs smooth >= 3 (ref''' continuous, ref'''' bounded)."""
    raw = scenario_to_dict(ftstab_mj.load_scenario("ideal_chain_r4"))
    raw["loops"]["chain"].pop("ref", None)
    raw["loops"]["chain"]["reference"] = {"kind": "file", "times": [0.0, 1.0], "values": [0.0, 0.1], "smooth": 2}
    with pytest.raises(ScenarioError, match=r"loops.chain.reference.smooth: expected an integer >= 3 for this chain "
                                            r"of length r = 4 .*found 2"):
        scenario_from_dict(raw)
    raw["loops"]["chain"]["reference"]["smooth"] = 3
    assert scenario_from_dict(raw).loops[0].reference.smooth == 3


WALKER_LOOPS = ("thigh", "leg", "foot", "thigh_left", "leg_left", "foot_left")
WALKER_REFS = {"thigh": -0.3, "leg": -0.3, "foot": 0.2, "thigh_left": -0.4, "leg_left": -0.2, "foot_left": 0.1}


def _walker(tmp_path, controller, duration):
    """gymnasium's walker2d (v5 assets: a planar base rootx/rootz/rooty, floor contact, joint limits, six
    motors with ctrlrange +-1 and gear 100), its six actuated joints from 0.1 rad off set points."""
    plant = "\n".join(f'[plant.loops.{n}]\njoint = "{n}_joint"\nsaturation = true' for n in WALKER_LOOPS)
    loops = "\n".join(f"[loops.{n}]\nz0 = [0.1, 0.0]\nref = {WALKER_REFS[n]}\ncontroller = {controller}"
                      for n in WALKER_LOOPS)
    path = tmp_path / "walker.toml"
    path.write_text(HOPPER.format(model=ASSETS / "walker2d_v5.xml", plant=plant, loops=loops, duration=duration)
                    .replace('"hopper"', '"walker"'))
    return path


@pytest.mark.parametrize("law", ["adaptive", "robust"])
def test_walker2d_identity_holds_from_the_log_under_two_laws(tmp_path, law):
    """A second model the project did not write: on its planar base the walker collapses onto the floor
    (torso from 1.25 m to below 0.1 m: its +-1 x gear 100 motors do not hold it up, each clamped 2 to
    3 % of the time under the adaptive law, all the time under this robust law), and through the impacts,
    limits and contacts the log keeps the physics: increment(z_2) = h (phi + gamma u_applied) per
    period, 95th percentile residual < 5 % (measured 0.6 to 1.1 %), for each of the six joints."""
    robust = '{law = "robust", k = -0.2, gains = [1.0, 2.0], phibar = 60.0, gamma_m = 60.0}'
    path = _walker(tmp_path, ADAPTIVE if law == "adaptive" else robust, 2.0)
    res = ftstab_mj.run(path, out=tmp_path / "runs")
    assert res.status == "completed", res.message
    log = ftstab_mj.replay(res.logs["mcap"])  # everything below from the log
    for name in WALKER_LOOPS:
        a, m = log.samples[name], log.metrics["loops"][name]
        assert np.percentile(_identity_residual(a), 95) < 0.05, name
        assert m["clamp"] == "ctrlrange [-1, 1]" and np.array_equal(a["u_applied"], np.clip(a["u"], -1.0, 1.0))
        assert m["bound_applies"] is False  # contacts: no time bound is claimed
    torso = res.body_pos[:, 0, 2]
    assert torso[0] == pytest.approx(1.25) and torso.min() < 0.1



def test_dm_control_finger_identity_holds_from_the_log_under_two_laws(tmp_path):
    """A third model the project did not write, dm_control's suite finger (its XML and the <include>d
    common/ files): two motors (ctrlrange +-1, gear 30 and 15) on damped, limited hinges push a passive
    spinner (frictionloss, no gravity). MuJoCo's Euler integrates joint damping implicitly, and the
    finger's damping 2.5 on its light links (h b / I ~ 1.25 at h = 2 ms) makes the explicit identity's
    residual 187 % at the 95th percentile (measured over 2 s under the adaptive law); with that option off (``eulerdamp="disable"``: the one edit),
    increment(z_2) = h (phi + gamma u_applied) holds from the log to rounding under both laws, and the
    spinner turns: the finger touched it (only a contact can move it)."""
    import dm_control

    suite = Path(dm_control.__file__).parent / "suite"
    xml = (suite / "finger.xml").read_text()
    assert '<flag gravity="disable"/>' in xml
    (tmp_path / "finger.xml").write_text(xml.replace('<flag gravity="disable"/>', '<flag gravity="disable" eulerdamp="disable"/>'))
    for f in ("visual.xml", "skybox.xml", "materials.xml"):
        (tmp_path / "common").mkdir(exist_ok=True)
        (tmp_path / "common" / f).write_text((suite / "common" / f).read_text())
    laws = {"adaptive": ADAPTIVE, "robust": '{law = "robust", k = -0.2, gains = [1.0, 2.0], phibar = 2000.0, gamma_m = 800.0}'}
    for law, controller in laws.items():
        path = tmp_path / f"finger_{law}.toml"
        path.write_text(HOPPER.format(model="finger.xml", duration=1.0, plant="\n".join(
            f'[plant.loops.{n}]\njoint = "{n}"\nsaturation = true' for n in ("proximal", "distal")), loops="\n".join(
            f"[loops.{n}]\nz0 = [0.3, 0.0]\nref = {ref}\ncontroller = {controller}" for n, ref in
            (("proximal", -0.3), ("distal", 0.0)))).replace('"hopper"', f'"finger_{law}"'))
        res = ftstab_mj.run(path, out=tmp_path / "runs")
        assert res.status == "completed", res.message
        log = ftstab_mj.replay(res.logs["mcap"])
        for name in ("proximal", "distal"):
            a = log.samples[name]
            assert np.percentile(_identity_residual(a), 95) < 0.05, (law, name)
            assert np.array_equal(a["u_applied"], np.clip(a["u"], -1.0, 1.0))
        spinner = 2.0 * np.arctan2(res.body_quat[:, 2, 2], res.body_quat[:, 2, 0])  # body 3, about y
        assert np.ptp(spinner) > 0.05, law

"""Hostile input (issue 17): each class the reliability review found is refused in one line, exit 2.

Through the command's own ``main`` (in process: the same code as ``ftstab run`` without a process
start per case). Every case: exit 2, one line on stderr naming the file, the key path, what is
allowed and what was found, no traceback, and no output directory (nothing written).
"""

import pytest

from conftest import ROOT, run_args
from ftstab_mj.cli import main
from ftstab_mj.plants.disturbances import Signal
from ftstab_mj.scenario import load_scenario

R2 = ROOT / "scenarios" / "cart_r2_robust.toml"
R3 = ROOT / "scenarios" / "cart_r3_robust.toml"
ARM = ROOT / "scenarios" / "arm_robust.toml"
DEEP = "[" * 500 + "]" * 500

# (id, scenario, edit of the file text (old, new) or None, --set texts, key path, texts the line must hold)
HOSTILE = [
    ("nested-500-in-file", R2, ("mass = 1.0 ", f"mass = {DEEP} "), [], "(TOML syntax)",
     ["nested at most 16 deep"]),
    ("nested-500-in-set", R2, None, [f"plant.mass={DEEP}"], "plant.mass", ["nested at most 16 deep"]),
    ("int-beyond-64-bits", R2, None, [f"plant.mass={10 ** 20}"], "plant.mass",
     ["integer of 64 bits", "100000000000000000000 (an integer)"]),
    ("seed-2^64", R2, None, [f"seed={2 ** 64}"], "seed", ["integer of 64 bits", "18446744073709551616"]),
    ("int-5000-digits", R2, ("mass = 1.0 ", "mass = 1" + "0" * 5000 + " "), [], "(TOML syntax)",
     ["valid TOML", "Exceeds the limit (4300 digits)"]),
    ("gain-products-overflow", R3, None, ["loops.cart.controller.gains[1]=1.797e308"],
     "loops.cart.controller.gains", ["below 1.8e308", "1.797e+308"]),
    ("name-251-chars", R2, None, ["name=" + "a" * 251], "name", ["at most 200 characters", "255 bytes"]),
    ("name-not-ascii", R2, None, ["name=caf\u00e9"], "name", ["ASCII letters"]),
    ("gain-worst-case", R2, None, ['loops.cart.gain={kind="worst_case", offset=1.0}'], "loops.cart.gain.kind",
     ["depends on time only", "found 'worst_case'"]),
    ("period-1e308", R2, None, ["sim.period=1e308"], "sim.period",
     ["at most 1e6 physics steps per period", "> 1e308 steps"]),
    ("period-1e9", R2, None, ["sim.period=1e9", "sim.duration=1e9"], "sim.period",
     ["at most 1e6 physics steps per period", "1e+12 steps"]),
    ("duration-1e308-step-1e-7", R2, None, ["sim.duration=1e308", "sim.physics_step=1e-7", "sim.period=1e-7"],
     "sim.duration", ["at most 1e7 control samples per run", "~3.5 GB of logs"]),
    ("duration-1e300", R2, None, ["sim.duration=1e300"], "sim.duration", ["at most 1e7 control samples"]),
    ("steps-per-run", R2, None, ["sim.duration=9000", "sim.physics_step=1e-6"], "sim.duration",
     ["at most 1e9 physics steps per run", "about an hour"]),
    ("random-modes-1e12", R2, None, [f'loops.cart.disturbance={{kind="random", amplitude=0.8, modes={10 ** 12}}}'],
     "loops.cart.disturbance.modes", ["[1, 10000]", "1000000000000 (an integer)"]),
    ("arm-grid-100000", ARM, None, ["plant.grid=100000"], "plant.grid", ["[2, 161]", "100000"]),
    ("arm-grid-5000", ARM, None, ["plant.grid=5000"], "plant.grid", ["[2, 161]", "~8 s"]),
    ("freq-end-on-sine", R2, None, ["loops.cart.disturbance.freq_end=3"], "loops.cart.disturbance.freq_end",
     ["only keys that a sine signal uses", "freq_end = 3"]),
    ("amplitude-on-constant", R2, None, ['loops.cart.gain={kind="constant", offset=1.0, amplitude=0.5}'],
     "loops.cart.gain.amplitude", ["only keys that a constant signal uses"]),
    ("freq-beyond-nyquist", R2, None, ["loops.cart.disturbance.freq=600"], "loops.cart.disturbance.freq",
     ["<= 500 Hz", "alias"]),
    ("gain-offset-1.8e308", ARM, None, ["loops.joint1.gain.offset=1.797e308"], "loops.joint1.gain.offset",
     ["|offset| + |amplitude| <= 1e+09", "1.797e+308"]),
    ("negative-sine-amplitude", R2, None, ["loops.cart.disturbance.amplitude=-1"],
     "loops.cart.disturbance.amplitude", ["only a step's amplitude is signed"]),
    ("step-down-through-zero", R2, None, ['loops.cart.gain={kind="step", offset=1.0, amplitude=-1.5}'],
     "loops.cart.gain", ["gamma(t) > 0 at all times", "-0.5"]),
]


@pytest.mark.parametrize("case", HOSTILE, ids=[c[0] for c in HOSTILE])
def test_hostile_input_is_one_line_exit_2_and_writes_nothing(case, tmp_path, capsys):
    _, base, edit, sets, key_path, texts = case
    path, out, args = run_args(tmp_path, base, edit, sets)
    code = main(args)
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith(f"error: {path}") and f": {key_path}: expected " in lines[0], lines[0]
    for t in texts:
        assert t in lines[0], lines[0]
    assert not out.exists()


def test_a_step_may_step_down_an_actuator_losing_half_its_gain():
    """gamma(t) = 1 until t_step, then 0.5: a signed step amplitude, the bounds the robust law is checked with."""
    sc = load_scenario(R2, ['loops.cart.gain={kind="step", offset=1.0, amplitude=-0.5, t_step=0.25}'])
    (lp,) = sc.loops
    assert lp.gain.bounds() == (0.5, 1.0)
    assert list(lp.gain([0.0, 0.2499, 0.25, 3.0])) == [1.0, 1.0, 0.5, 0.5]
    with pytest.raises(ValueError, match="only a step's amplitude is signed"):
        Signal("sine", 1.0, -0.5)


def test_a_count_of_one_is_singular_in_a_message():
    from ftstab_mj.config.errors import ScenarioError

    with pytest.raises(ScenarioError) as exc:
        load_scenario(R2, ["loops.cart.z0=[1.0]"])
    assert str(exc.value).endswith("loops.cart.z0: expected 2 numbers (z_1..z_r, r = 2 for model 'cart'), "
                                   "found 1 number"), str(exc.value)


def test_the_limits_hold_exactly_at_their_values():
    """1e7 samples and 1e6 steps per period are allowed; one more is refused (the limits are the
    stated numbers, not approximations of them). Loader only: nothing runs."""
    from ftstab_mj.config.errors import ScenarioError

    load_scenario(R2, ["sim.duration=10000"])  # 1e7 samples of 1 ms
    with pytest.raises(ScenarioError, match="at most 1e7 control samples"):
        load_scenario(R2, ["sim.duration=10000.002"])
    load_scenario(R2, ["sim.physics_step=1e-6", "sim.period=1.0", "sim.duration=1"])  # 1e6 steps per period
    with pytest.raises(ScenarioError, match="at most 1e6 physics steps per period"):
        load_scenario(R2, ["sim.physics_step=1e-6", "sim.period=1.000001", "sim.duration=1.000001"])


def test_theorem3_bounds_of_absurd_but_finite_parameters_are_infinite_not_an_overflow():
    """Found by the fuzzer: a gain offset of 1.797e308 made the metrics raise OverflowError (Python's
    float **) after the run. A bound beyond the largest float is reported as infinite."""
    import math

    from ftstab_mj.control import HongController, certify, theorem3_bounds

    cert = certify(HongController(2, -0.2, (1.0, 2.0)), samples=2000, seed=0)
    b = theorem3_bounds(cert, 0.1, 1.797e308, 1.0, 1.0, 1.0, 1e-3)
    assert math.isinf(b.Phibar) and math.isinf(b.Delta) and math.isinf(b.phi_hat_limsup)
    finite = theorem3_bounds(cert, 0.1, 1.0, 1.0, 1.0, 1.0, 1e-3)  # ordinary values: finite, exact to a few ulps
    assert 0.1 <= finite.Phibar <= 0.1 * (1 + 1e-15)  # (0.1 + (1 * 1 - 1)^2 / 4) / 1, rounded upwards


def test_a_run_out_of_memory_mid_way_closes_its_logs_as_failed_in_one_line(tmp_path, capsys, monkeypatch):
    """Point 2's other half: a MemoryError in the third batch (as a machine short of memory gives)
    ends `ftstab run` with exit 1, one line, and logs that hold the first batches and say "failed"."""
    from ftstab_mj.simulation import run_loop as sim
    from ftstab_mj.logs.reader import read_log

    advance, calls = sim.Simulation.advance, []

    def short_of_memory(self, n):
        calls.append(n)
        if len(calls) == 3:
            raise MemoryError
        return advance(self, n)

    monkeypatch.setattr(sim.Simulation, "advance", short_of_memory)
    code = main(["run", str(R2), "--out", str(tmp_path), "--set", "sim.duration=5"])
    err = capsys.readouterr().err
    assert code == 1 and err.count("\n") == 1 and "out of memory" in err and "Traceback" not in err, err
    log = read_log(tmp_path / "cart_r2_robust.mcap")
    assert log.recorded["status"] == "failed" and "MemoryError" in log.recorded["message"]
    assert log.n_samples == 2 * calls[0]  # the two batches computed before the failure, nothing else


def test_a_structure_problem_is_named_by_its_whole_key_path_quoted_where_toml_needs_it():
    """structure_problem keeps a value's place as (parent, key) and writes its key path only for the value at
    fault: the path is keypath's, array indices and quoted keys included, at any depth."""
    from ftstab_mj.config.validate import MAX_DEPTH, structure_problem

    assert structure_problem({"a": {"b": [1, 2, {"c d": 2 ** 70}]}})[0] == 'a.b[2]."c d"'
    deep = node = {}
    for _ in range(MAX_DEPTH + 3):
        node["k"] = node = {}
    assert structure_problem({"x": [deep]})[0] == "x[0]" + ".k" * (MAX_DEPTH - 1)  # the first value too deep
    assert structure_problem({"ok": [1, {"y": "z"}]}) is None

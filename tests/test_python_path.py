"""The Python control path (the one a plugin law without a C twin takes) records the same samples,
bit for bit, as before it was made cheap.

Reference: SHA-256 digests of every recorded field (name, dtype, shape, bytes) of short runs forced
onto the Python path (native=False), saved from the per-sample implementation before its rewrite
(git history of ftstab_mj/simulation/run_loop.py), re-pinned once since, where the paper's laws' V1
became the C kernel's bit for bit (hong._W, 0.4.0; the Python path's samples then equal the native
path's in all 41 cases: test_the_python_path_is_the_native_path). Cases: every shipped scenario (stages,
saturation, the arm, the flexible joint, r = 2..5, their integrators), every law of the shipped
cart comparisons on the cart scenario, a tracked reference, and RK4 with 5 steps a period. Each
runs 250 samples in two batches of 170 and 80 (a batch boundary inside the run). The digests hold
on this platform (x86_64 Linux, the pinned NumPy and MuJoCo): the Python path evaluates the laws in
NumPy one state at a time, whose libm results are deterministic for a given build.
"""

import dataclasses
import hashlib
from pathlib import Path

import numpy as np
import pytest

from ftstab_mj.control.laws.linear import LinearLaw
from ftstab_mj.plants import make_plant
from ftstab_mj.scenario.loader import load_scenario, read_toml, scenario_from_dict
from ftstab_mj.simulation import native
from ftstab_mj.simulation.run_loop import Simulation
from ftstab_mj.studies.compare import load_comparison

ROOT = Path(__file__).resolve().parent.parent
BATCHES = (170, 80)

EXPECTED = {  # case id: digest (the __main__ block below prints this table)
    'arm3_adaptive': '1c4a548e412fd620e0f62284e7c47c9e3cdbaf26c04cb665d1f8ac561f91916d',
    'arm3_robust': '97b7d13cffe94ed2f7bd4113ead04ffaa5916b9dcc32f6b91e8be8b10951ec45',
    'arm_adaptive': '841074b3e2a25ddfe7dd58cf06fafd8fade9cf6ef2a1a0d1eb48646f39378b7f',
    'arm_r3_adaptive': '719a32812fd2913d8fa88f9955f5050abe145a565e735482638b4e0bb556c513',
    'arm_r3_robust': '8dd7b5200d84cc914f3ca7d07dfff6e7e1f9cbb0f0462d316d0ed0cc35b0c4c3',
    'arm_robust': 'c5aa8d7bb660c079a6b29a041d84689c85a061c309f5cf7855c45afd8d2ed698',
    'cart_r2_above_bound_adaptive': '38933b6ff3e14ffaf5fe1a35cfc157931656842414bc6eb0f6d0f72ba131ba57',
    'cart_r2_above_bound_robust': 'eda5cf10f764fee93f2561740fa0987163dd57df71f23b2e77db7a1f9e9c09af',
    'cart_r2_actuator_lag': 'f00c82d5cdee3441a9400a16abc08469195b86ff214f659e22a37d6c1dcae4aa',
    'cart_r2_adaptive': '27853782c059a290f3648dbe34695dc1c2b652805bdd7093af74a030cdf135bc',
    'cart_r2_nominal': '826a1ea6fae0b1837db5480004eb2666e12d620ab779d5429e8fc4751e8a9323',
    'cart_r2_output_feedback': '61db4df0cde650b959742149bf9e8d6224f2b55121cc681ea802939f1df38f6f',
    'cart_r2_robust': '73673d2c05b7725790dd624681aba72ec3104bc12dd7640642f33765b3684670',
    'cart_r2_saturation_above': '061b3195e887d1b9052c3238d3ddc9578320bd5023dc7cb80c77afa0838273f5',
    'cart_r2_saturation_below': 'e647f6e0eb2af2dcff29c8312a48368c76afc7926c15687f085d67b9ecc65542',
    'cart_r2_worst_case': 'a764b119a52de09021b71cdaa45feba4e23ea26721a593bb4b5a1406ce3866dc',
    'cart_r3_adaptive': 'b8b067dadbf2810f30d1258eaf52b45c244a1efeed7a7ab0f72d45cf5ee4489c',
    'cart_r3_output_feedback': '67bda13f321a1080f5d0614d8245eff04adaf3b2b32e54e8c96e082eefb05b8d',
    'cart_r3_robust': '5c92877d9176e20a25d5fcc99c8ddc6976afb46e6ab3f0a45c13b3267cd32cc7',
    'flexible_joint_r4_adaptive': '6ba75d736932e1301405df90b34a7c6ab905f3f083945c7ca1d95a8dd0e9560c',
    'flexible_joint_r4_robust': '237e2c38e98b6f09b67f18bd674cae2c7bcdb6f77d7d58473b3f2d41fb3e3e32',
    'flexible_joint_r5_robust': '1d4fc28022d915b90f93173d6f68ad4bccfe7eca2092cd1f968b78954efae7e5',
    'ideal_chain_r4': '021ff007f5cba854fb5661ee1cc7e44f7c7a07c7b6cc059936af626b0be71799',
    'ideal_chain_r5': '6cdfff8af6d7cfb40fa539b74ab6386f3bfb987d43092ced4d438b45823be073',
    'cart_r2:robust': '50b4f642d7bd1d96d5e3cd1253c9b342b8d05b3e45ab06058330e814fdb76618',
    'cart_r2:robust implicit': '6beac0fb8db17f380306498a9c0580e51a2439773d0996d7603f098822da6d90',
    'cart_r2:robust implicit, gamma_m = 0.5': '172fac53482cf21f15346a300f06c1ef1f07f26c39609d7c951649491326f2db',
    'cart_r2:adaptive': '27853782c059a290f3648dbe34695dc1c2b652805bdd7093af74a030cdf135bc',
    'cart_r2:levant_qc': '88ac3f7b907bef08ea56aa13e6492d1edef8643a86abb55cb83c055ac44d054a',
    'cart_r2:levant_nested': '942f7bfe95367ac4f6543a53880349711a89842cd627ac28256b0a962b104ced',
    'cart_r2:super_twisting': '6dd3c5ec2e4c7f7b8272a58e062fac58f880b5b2f209bbd0047305575e128162',
    'cart_r2:plestan_adaptive': '1537f036f1be881025749195158d398ac66506f49395b4e9de41be9c0954344e',
    'cart_r2:linear': '08df29b241c7d93e1180ae838373ea4458c97ab68c3af91f260595800f220bea',
    'cart_r2:twisting': 'e8f21b36b7b9d54ea6b6be632ccfd6d0d4d801ef3f2aa9fbca9390868786618e',
    'cart_r2:terminal': '06f7f03f1019908734ab75e21aca2ecf6c9671583666e75801ac413775b88a45',
    'cart_r2:fixed_time': '14b5f0c82a96ad95fc1f27862b31095b8727a5e4ffe2729c148f7b1fa8139735',
    'cart_r2:adaptive_super_twisting': '1a5ee9308e24a2a773358725f2e501be8dd68f992f4e82b4527b2c6042e83d75',
    'cart_r2:integral_hosm': 'ff78fd6df94d437789311c57ca66ca067b1281ef0d56079afaf034d71a273f7a',
    'cart_r2:huang_adaptive': '4692ef522198d674643008f783219c415223b12fa3c6f2a520d675bb7d3a86c5',
    'tracking': '3c84bad5aed1c5c0c84db9770a434ca65af9b65845d50cf999bfecfcd63e4a62',
    'rk4_5_steps': '357c4fad951e5d75975d79647beebcd1f0d3c3fc2a016ca5191d40bb72e12f2d',
}


def raw_scenario(path: Path) -> dict:
    from ftstab_mj.scenario.loader import resolve_relative_paths

    raw = read_toml(path, "scenario")
    resolve_relative_paths(raw, path.parent)
    return raw


def cases() -> dict:
    """{case id: validated Scenario}."""
    out = {p.stem: load_scenario(p) for p in sorted((ROOT / "scenarios").glob("*.toml"))}
    base = ROOT / "scenarios" / "cart_r2_robust.toml"
    for cmp_name in ("cart_r2", "field_r2"):
        for entry in load_comparison(ROOT / "scenarios" / "compare" / f"{cmp_name}.toml").laws:
            if f"cart_r2:{entry.label}" in out:
                continue
            raw = raw_scenario(base)
            raw["loops"]["cart"]["controller"] = dict(entry.controller)
            out[f"cart_r2:{entry.label}"] = scenario_from_dict(raw, f"{cmp_name}:{entry.label}")
    raw = raw_scenario(base)
    raw["loops"]["cart"]["reference"] = {"kind": "sine", "offset": 0.1, "amplitude": 0.3, "freq": 0.5}
    out["tracking"] = scenario_from_dict(raw, "tracking")
    raw = raw_scenario(base)
    raw["sim"].update(integrator="rk4", period=5e-3, physics_step=1e-3)
    out["rk4_5_steps"] = scenario_from_dict(raw, "rk4")
    return out


def digest(sc, loops=None, native_choice=False) -> str:
    """SHA-256 of every field of every sample of the Python path's run of ``sc`` (BATCHES samples);
    ``loops``: instead of the scenario's."""
    s = sc.sim
    sim = Simulation(make_plant(sc.plant.model, sc.plant.params), loops or sc.loops, s.period, s.physics_step,
                     s.integrator, s.divergence_limit, native=native_choice)
    h = hashlib.sha256()

    def add(name, a):
        a = np.ascontiguousarray(a)
        h.update(f"{name}:{a.dtype.str}:{a.shape}".encode())
        h.update(a.tobytes())

    with sim.installed():
        for n in BATCHES:
            b = sim.advance(n)
            for loop, rec in b.loops.items():
                for f, a in rec.items():
                    add(f"{loop}.{f}", a)
            add("body_pos", b.body_pos)
            add("body_quat", b.body_quat)
    h.update(sim.stop_reason.encode())
    return h.hexdigest()


@pytest.fixture(scope="module")
def scenarios():
    return cases()


def test_the_cases_are_the_table(scenarios):
    """Every case has its reference digest (a new shipped scenario or law is added to the table)."""
    assert list(scenarios) == list(EXPECTED)


class PluginLinear(LinearLaw):
    """A law from outside: a subclass, so no C twin (its class does not declare one)."""


def test_a_plugin_law_takes_the_python_path_with_the_same_samples(scenarios):
    """native="auto" (the default) puts a plugin law on the Python path, which records what the
    same maths recorded before the path was made cheap (the shipped linear law forced onto it)."""
    sc = scenarios["cart_r2:linear"]
    plugin = PluginLinear(sc.loops[0].controller.poles)
    assert not native.use_native("auto", plugin)
    loops = [dataclasses.replace(sc.loops[0], controller=plugin)]
    assert digest(sc, loops, native_choice="auto") == EXPECTED["cart_r2:linear"]


@pytest.mark.skipif(not native.available(), reason=f"native kernel: {native.UNAVAILABLE_REASON}")
@pytest.mark.parametrize("name", ["cart_r2_adaptive", "arm3_adaptive", "cart_r3_robust", "cart_r2:robust implicit"])
def test_the_python_path_is_the_native_path(scenarios, name):
    """The two paths do the same operations: the same samples, bit for bit (the adaptive law feeds V1
    back, so a rounding between them grew on the coupled arms; ``replay --verify`` across paths)."""
    assert digest(scenarios[name]) == digest(scenarios[name], native_choice="auto")


@pytest.mark.parametrize("name", list(EXPECTED))
def test_python_path_samples_unchanged(scenarios, name):
    assert digest(scenarios[name]) == EXPECTED[name], f"{name}: the Python path's samples changed"



if __name__ == "__main__":  # prints the table below (run before a change to the Python path)
    for name, sc in cases().items():
        print(f"    {name!r}: {digest(sc)!r},")

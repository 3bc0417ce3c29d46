"""The Python control path (the one a plugin law without a C twin takes) records the same samples,
bit for bit, as before it was made cheap.

Reference: SHA-256 digests of every recorded field (name, dtype, shape, bytes) of short runs forced
onto the Python path (native=False), saved from the per-sample implementation before its rewrite
(git history of ftstab_mj/simulation/run_loop.py). Cases: every shipped scenario (stages,
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
    'arm3_adaptive': 'cc5245087fe46d4ca1af1e45eeba38acf50f8770ff83bfff7b2c2ef5afd68b82',
    'arm3_robust': 'b01c301393fd64d59a7cbf66654196c64a0210f0cc0f261f2450511f7f942ce0',
    'arm_adaptive': '983936a60f29f31939c6fcccd78d4ed28c3003e822d44787dce5bbb8f0f85ab7',
    'arm_r3_adaptive': '3ad5e67eaf8b028bdc883512370eda7c33f63fdad86af6dc00187bb8b33479fe',
    'arm_r3_robust': '2df2484a2cec4d6d50a64c7c46eb602277a560942a18967947334db11cf44126',
    'arm_robust': '9ac8560c8da6cb670487b4dbf60270475dace77a660278eb13eac838fce6ba6a',
    'cart_r2_above_bound_adaptive': '3d589e8af6860d3ab32e63701c3ecaf3f83867372301ba8567e05035828d3ec9',
    'cart_r2_above_bound_robust': '360b221c83c58f73f4acc3b963308ac3fce23845f0a47a7161a5711dd978627d',
    'cart_r2_actuator_lag': '0caa79accfe9181d3f229d103de05f59444d074fe56b7f2e02baabd744a8d745',
    'cart_r2_adaptive': '1351c8c493d97de24264d2f9ea2cb9fd6164e0a8ce2860ede6a4ff5ed802cf73',
    'cart_r2_nominal': 'fa38a5675e075d3cddf09a231555c65dfa909221318f4b5de2a6a0dcf6874e50',
    'cart_r2_output_feedback': '5d545d7457b1fcada4c3f83527bd256c4880ec926b656126dc5058f9100e8dfa',
    'cart_r2_robust': 'fbe3cbfb1c90e903b1807eaa593f1cae2996cba77618c0f9042ad6c9be76e1f1',
    'cart_r2_saturation_above': 'f9f23fdc6fc3732bcb257d14a961e51bb884891438f28acfaba36b3a33a62959',
    'cart_r2_saturation_below': '51940b5cf928e3dbf691941e4563fd7ac19fd73db1202a1e314ce92ac4b39cfa',
    'cart_r2_worst_case': '6bad04fd74d1cc81268f401dd912a9e40178642cd7173d538b31a443fc7867ce',
    'cart_r3_adaptive': '558b70329ffd5c24d94f11acd270f074bb28b885174f302868a5dda6b4e84096',
    'cart_r3_output_feedback': 'ecff93250b0ae07d5f527dae8bc4a5495673698f51aa568b3656f671f2af210e',
    'cart_r3_robust': 'f841532224f0a36e54b24a8dc039f8719a9cbc55900fa2b7fca8a83ea10a74aa',
    'flexible_joint_r4_adaptive': 'fc186b295593cbd7ec4addecc77980178dfdd0c322cc6e5d74b389cad3fb8ede',
    'flexible_joint_r4_robust': '00f2fac0ef20c609e4a51338f1c49f93f29b6392137b80cdacc147600e0bfdb6',
    'flexible_joint_r5_robust': '415b9281ca59ef4f2267a16bc5d14c5e5372bf46d2144f61010497612fce966a',
    'ideal_chain_r4': '1852e3f5dfeccf59ac985ca286346e0de70cd3cb39ffa0569684a0718f2a2af0',
    'ideal_chain_r5': '858344f6e2d04230984d5307d1689e6e9c2aa5ed2e67bcecd264905ea659e8e8',
    'cart_r2:robust': '324325f6909ea1249e360596ae21673d3d054a56da798bec339cf31783118635',
    'cart_r2:robust implicit': 'c1da1c72d4105c19c9fc7fb52f4c5e6f208c80b53eba7a3b9e1ae17e86ef0aea',
    'cart_r2:robust implicit, gamma_m = 0.5': 'cdd9e79b334d6c933e7560f2f815ce1aeb1285dcce7415cf9d0ddd6122ae5a83',
    'cart_r2:adaptive': '1351c8c493d97de24264d2f9ea2cb9fd6164e0a8ce2860ede6a4ff5ed802cf73',
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
    'tracking': '6d7cbe9277830edade1322c8fa315bcd8d61bc47a69116556c9b6b7f49832938',
    'rk4_5_steps': '9bbca7f61e52e90b71a53a4ab1623e82938e9a5f312a6141e5e69800ea6999ae',
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


@pytest.mark.parametrize("name", list(EXPECTED))
def test_python_path_samples_unchanged(scenarios, name):
    assert digest(scenarios[name]) == EXPECTED[name], f"{name}: the Python path's samples changed"



if __name__ == "__main__":  # prints the table below (run before a change to the Python path)
    for name, sc in cases().items():
        print(f"    {name!r}: {digest(sc)!r},")

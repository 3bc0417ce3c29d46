"""The ideal-chain plant (plants/ideal.py): the run loop on the exact chain, any r = 1..6.

Reference: ftstab_mj.simulation.ideal_chain.simulate_chain (the NumPy loop the MuJoCo plants are checked
against) with substeps = physics steps per period. Both apply z <- z Phi^T + w G per physics step
with the same w = phi + gamma u, so they give the same bits; with a set point the plant integrates
ref + z_1, so z_1 differs by the rounding of that sum (an ulp of ref per step).
"""

import numpy as np
import pytest
from conftest import run_cli

from ftstab_mj.control import HongController, NominalLaw, RobustLaw
from ftstab_mj.control.hong import gains_for_polynomial
from ftstab_mj.plants.disturbances import Signal
from ftstab_mj.config.errors import ParameterError
from ftstab_mj.simulation.ideal_chain import simulate_chain
from ftstab_mj.simulation.native import NativeUnavailable
from ftstab_mj.plants import make_plant
from ftstab_mj.scenario.schema import LoopSpec
from ftstab_mj.simulation.run_loop import Simulation, simulate

def _law(r, robust=False):
    """Hong's controller with k = -0.5 / (r + 1) and the gains whose nested polynomial is (s + 2)^r."""
    h = HongController(r, -0.5 / (r + 1), gains_for_polynomial(np.poly(-2.0 * np.ones(r))))
    return RobustLaw(h, phibar=0.5, gamma_m=0.8) if robust else NominalLaw(h)


@pytest.mark.parametrize("r, N, ref", [(r, N, 0.0) for r in range(1, 7) for N in (1, 4)] + [(3, 2, 0.3)])
def test_the_plant_is_the_exact_chain(r, N, ref):
    """Robust law, sine disturbance and gain: every sample equals simulate_chain's (bit for bit at ref 0)."""
    z0 = np.linspace(0.5, -0.2, r)
    phi, gamma = Signal("sine", amplitude=0.4, freq=1.3), Signal("sine", offset=1.0, amplitude=0.15, freq=0.7)
    period, duration = 0.001, 0.3
    law = _law(r, robust=True)
    res = simulate(make_plant("ideal_chain", {"r": r}),
                   [LoopSpec("chain", z0=tuple(z0), ref=ref, controller=law, disturbance=phi, gain=gamma)],
                   duration=duration, period=period, physics_step=period / N)
    assert res.status == "completed"
    want = simulate_chain(law, z0, period, duration, phi=phi, gamma=gamma, substeps=N)
    rec = res.loops["chain"]
    if ref == 0.0:
        for f in ("z", "u", "V1", "phi", "gamma"):
            np.testing.assert_array_equal(rec[f], getattr(want, f), err_msg=f)
    else:  # 0.3 + z_1 rounded at each of the 600 steps: within 600 ulps of 0.3
        np.testing.assert_allclose(rec["z"], want.z, rtol=0, atol=600 * np.spacing(0.3))
    # the view: body z<i> at x = qpos[i] (ref + z_1 for the first one)
    np.testing.assert_allclose(res.body_pos[:, :, 0], rec["z"] + np.r_[ref, np.zeros(r - 1)], rtol=0, atol=1e-15)


def test_save_and_restore_reproduce_the_run():
    plant = make_plant("ideal_chain", {"r": 4})
    loops = [LoopSpec("chain", z0=(1.0, 0.0, -0.5, 0.2), controller=_law(4), disturbance=Signal("constant", 0.0),
                      gain=Signal("constant", 1.0))]
    sim = Simulation(plant, loops, period=0.002, physics_step=0.001)
    with sim.installed():
        sim.advance(50)
        state = sim.get_state()
        a = sim.advance(100)
        sim.set_state(state)
        b = sim.advance(100)
    np.testing.assert_array_equal(a.loops["chain"]["z"], b.loops["chain"]["z"])


def test_the_native_callback_does_not_run_it():
    plant = make_plant("ideal_chain", {"r": 2})
    loops = [LoopSpec("chain", z0=(1.0, 0.0), controller=_law(2))]
    with pytest.raises(NativeUnavailable, match="stepped by its own code"):
        Simulation(plant, loops, period=0.001, physics_step=0.001, native=True)


@pytest.mark.parametrize("params, needle", [
    ({"r": 7}, "params.r: expected an integer chain length 1..6"),
    ({"r": 2.0}, "params.r"),
    ({"r": True}, "params.r"),
    ({"mass": 1.0}, "params.mass"),
])
def test_bad_parameters_name_the_key(params, needle):
    with pytest.raises(ParameterError, match=needle.replace(".", r"\.")):
        make_plant("ideal_chain", params)


def test_integrators_other_than_euler_are_refused(tmp_path):
    with pytest.raises(ParameterError, match="integrator: expected one of euler for 'ideal_chain'"):
        make_plant("ideal_chain", {"r": 3}).compile(0.001, "rk4")
    res = run_cli("run", "ideal_chain_r4", "--set", "sim.integrator=rk4", "--out", tmp_path)
    assert res.returncode == 2 and not list(tmp_path.iterdir())
    lines = res.stderr.strip().splitlines()
    want = "ideal_chain_r4.toml (--set sim.integrator=rk4): sim.integrator: expected one of euler for model 'ideal_chain'"
    assert len(lines) == 1 and want in lines[0], res.stderr


def test_cli_bad_r_is_one_line_exit_2(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text('name = "bad"\ndescription = "x"\n[plant]\nmodel = "ideal_chain"\nr = 9\n'
                 '[sim]\nduration = 0.1\n[loops.chain]\nz0 = [1.0, 0.0]\n'
                 '[loops.chain.controller]\nlaw = "nominal"\nk = -0.2\ngains = [1.0, 2.0]\n')
    res = run_cli("run", p, "--out", tmp_path)
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "plant.r" in lines[0] and "1..6" in lines[0], res.stderr

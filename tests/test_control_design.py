"""The gain designer: certified gains whose closed loop on the exact chain beats the guaranteed T(z0)."""

import numpy as np
import pytest

from conftest import run_cli
from ftstab_mj.control import HongController, NominalLaw
from ftstab_mj.control.design import design_max_c, nelder_mead
from ftstab_mj.ideal_chain import simulate_chain


def test_nelder_mead_finds_a_quadratic_minimum():
    x, fx = nelder_mead(lambda x: float(np.sum((x - np.array([1.0, -2.0])) ** 2)), np.zeros(2), iters=400, tol=1e-14)
    np.testing.assert_allclose(x, [1.0, -2.0], atol=1e-5)


@pytest.mark.parametrize("r, k", [(2, -0.2), (3, -0.1)])
def test_designed_gains_are_certified_and_beat_the_bound(r, k):
    """From 100 random initial states (|z_i| <= 1), nominal chain with a 1e-4 s zero-order hold:
    V1 falls below 1e-8 V1(z0) before Theorem 1's T(z0) = V1(z0)^(1-alpha) / (c_lower (1-alpha))."""
    gains, cert = design_max_c(r, k)
    assert cert.status == "certified" and cert.gap < 0.01
    if r == 2:
        assert design_max_c(r, k)[0] == gains  # deterministic
    h = HongController(r, k, gains)
    z0 = np.random.default_rng(11).uniform(-1.0, 1.0, size=(100, r))
    V0 = h.V1(z0)
    T = cert.time_bound(V0)
    run = simulate_chain(NominalLaw(h), z0, 1e-4, float(T.max()), native=True)
    below = run.V1 <= 1e-8 * V0  # (n, 100)
    first = np.argmax(below, axis=0)
    assert below.any(axis=0).all()
    assert np.all(run.t[first] < T), float(np.max(run.t[first] / T))
    print(f"r = {r}, k = {k}: gains {gains}, c_lower {cert.c_lower:.6g}, worst settle/T(z0) "
          f"{float(np.max(run.t[first] / T)):.3g}")


def test_cli_design_prints_gains_and_snippet():
    res = run_cli("design", "--r", 2, "--k", -0.2)
    assert res.returncode == 0, res.stderr
    assert "status: certified" in res.stdout and "gains = [" in res.stdout


@pytest.mark.parametrize("args, needle", [
    (("--r", 2, "--k", 0.5), "k"),
    (("--r", 9, "--k", -0.1), "--r"),
    (("--r", 2, "--k", -0.2, "--gain-max", "1e9"), "--gain-max"),
    (("--r", 2, "--k", -0.2, "--gain-min", "10", "--gain-max", "5"), "--gain-max"),
    (("--r", 2, "--k", -0.2, "--objective", "min-time"), "--objective"),
])
def test_cli_design_bad_input_one_line_exit_2(args, needle):
    res = run_cli("design", *args)
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0] and "Traceback" not in res.stderr

"""The certificate (NOTES.md section 5): reference table, determinism, Theorem 3 constants, CLI."""

import json

import numpy as np
import pytest

from conftest import run_cli
from ftstab_mj.control import HongController, certify, theorem3_bounds
from ftstab_mj.control.certificate import unit_level_set_points
from ftstab_mj.errors import ParameterError

# NOTES.md section 5 (max over 2e5 samples of the unit level set).
REFERENCE = [
    (2, -0.2, (1.0, 2.0), 1.329, 0.8889),
    (3, -0.1, (1.0, 1.7, 5.0), 0.574, 0.9474),
]


@pytest.mark.parametrize("r, k, gains, c_ref, alpha_ref", REFERENCE)
def test_reference_table(r, k, gains, c_ref, alpha_ref):
    cert = certify(HongController(r, k, gains))
    assert cert.certified
    assert cert.c == pytest.approx(c_ref, rel=0.01)
    assert cert.alpha == pytest.approx(alpha_ref, abs=1e-4)
    assert cert.alpha_prime == pytest.approx(1 - (1 + (r - 1) * k) / (2 + k), rel=1e-12)


def test_hurwitz_is_not_enough():
    """r = 3, k = -0.1, gains 1, 2, 3: Hurwitz (l_3 > l_1) but dV1/dt > 0 somewhere on {V1 = 1}."""
    cert = certify(HongController(3, -0.1, (1.0, 2.0, 3.0)))
    assert not cert.certified and cert.c < 0
    assert cert.time_bound(1.0) == float("inf")


def test_k_zero_is_exponential_not_finite_time():
    cert = certify(HongController(2, 0.0, (1.0, 2.0)), samples=20_000)
    assert cert.certified and cert.alpha == 1.0  # dV1/dt <= -c V1: exponential decay
    assert cert.time_bound(1.0) == float("inf") and "exponential" in cert.note
    # Theorem 3's phi_hat bound needs finite-time convergence: infinite here, not a ZeroDivisionError.
    b = theorem3_bounds(cert, phibar=1.0, gamma_m=0.5, kappa=1.0, delta=0.5, rate=2.0, eps=0.05)
    assert b.phi_hat_limsup == float("inf") and np.isfinite(b.Delta)


def test_certificate_is_deterministic_and_seeded():
    h = HongController(2, -0.2, (1.0, 2.0))
    a, b = certify(h, samples=20_000, seed=5), certify(h, samples=20_000, seed=5)
    assert a == b
    c = certify(h, samples=20_000, seed=6)
    assert c.c == pytest.approx(a.c, rel=0.01)  # a different sample set agrees to within 1%


def test_level_set_points_and_constants_hold_off_the_level_set():
    """The constants are global by homogeneity: check dV1/dt <= -c V1^alpha and |dV1/dz_r| <= c' V1^alpha'
    on fresh random states at all scales (not on the level set the certificate sampled)."""
    h = HongController(3, -0.1, (1.0, 1.7, 5.0))
    cert = certify(h)
    rng = np.random.default_rng(123)
    pts = unit_level_set_points(h, 1000, rng)
    np.testing.assert_allclose(h.V1(pts), 1.0, rtol=1e-12)
    z = rng.standard_normal((50_000, 3)) * 10.0 ** rng.uniform(-3, 2, size=(50_000, 1))
    V = h.V1(z)
    dVdt = h.closed_loop_dV1dt(z)
    ok = np.isfinite(dVdt)
    assert ok.mean() > 0.999
    assert np.all(dVdt[ok] <= -cert.c * V[ok] ** cert.alpha * (1 - 1e-9))
    assert np.all(np.abs(h.dV1_dzr(z)) <= cert.c_prime * V ** cert.alpha_prime * (1 + 1e-9))


def test_simplified_form_is_not_a_global_certificate():
    """The quadratic companion V1 of Proposition 1 is not homogeneous, and its dV1/dt is positive
    near z_1 = 0 (the derivative of |z_1|^e with e < 1 is unbounded there): the check says so."""
    cert = certify(HongController(2, -0.2, (1.0, 2.0), form="simplified"))
    assert not cert.certified and cert.c is None
    assert cert.region_negative is False and cert.region_max_dV1dt > 0
    assert "not a global certificate" in cert.note
    # At k = 0 the same V1 is the classic quadratic Lyapunov function of the linear backstepping law.
    lin = certify(HongController(2, 0.0, (1.0, 2.0), form="simplified"))
    assert lin.region_negative is True


def test_theorem3_bounds_properties():
    cert = certify(HongController(2, -0.2, (1.0, 2.0)))
    b = theorem3_bounds(cert, phibar=1.0, gamma_m=0.5, kappa=1.0, delta=0.5, rate=2.0, eps=0.05)
    # Phibar = (phibar + (kappa gamma_m - 1)^2 / (4 gamma_m delta)) / gamma_m = (1 + 0.25) / 0.5
    assert b.Phibar == pytest.approx(2.5, rel=1e-12)
    assert b.Delta > 0.05  # the overshoot bound is above the eps level it starts from
    faster = theorem3_bounds(cert, phibar=1.0, gamma_m=0.5, kappa=1.0, delta=0.5, rate=2e6, eps=0.05)
    assert faster.Delta == pytest.approx(0.05, rel=1e-3)  # rate -> infinity: Delta -> eps
    with pytest.raises(ParameterError):
        theorem3_bounds(certify(HongController(3, -0.1, (1.0, 2.0, 3.0))), 1.0, 0.5, 1.0, 0.5, 2.0, 0.05)


def test_cli_certify_json_matches_library():
    res = run_cli("certify", "--r", 2, "--k", -0.2, "--gains", "1,2", "--json")
    assert res.returncode == 0, res.stderr
    data = json.loads(res.stdout)
    assert {"c", "alpha", "c_prime", "alpha_prime", "certified"} <= set(data)
    assert data["certified"] is True
    assert data["c"] == pytest.approx(certify(HongController(2, -0.2, (1.0, 2.0))).c, rel=1e-12)


@pytest.mark.parametrize("args, needle", [
    (("--r", 3, "--k", -0.1, "--gains", "1,1.7"), "gains"),
    (("--r", 3, "--k", -0.1, "--gains", "1,x,5"), "--gains"),
    (("--r", 3, "--k", -0.1, "--gains", "3,2,1"), "Hurwitz"),
    (("--r", 2, "--k", 0.3, "--gains", "1,2"), "k"),
    (("--r", 2, "--gains", "1,2"), "--k"),
])
def test_cli_certify_bad_input_one_line_exit_2(args, needle):
    res = run_cli("certify", *args)
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0] and "Traceback" not in res.stderr

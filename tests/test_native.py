"""The native kernel (ftstab_mj/native) against the NumPy reference (ftstab_mj/control, ideal_chain).

Tolerance 1e-12 (relative to max(1, |value|)): both paths do the same floating-point operations in
the same order except pow on batches, where NumPy's SIMD pow and libm's pow may differ by one ulp
(one state at a time, as the run loop's Python path calls a law, NumPy takes libm's pow: bit-identical,
test_one_state_at_a_time_is_bit_identical). Per evaluation that is ~1e-15.

Along a trajectory those ulps are carried forward by the sampled closed loop. Near the switching
surface dV1/dz_r = 0 the sampled loop of a discontinuous law can amplify perturbations (seen here:
r = 3, robust law, worst-case disturbance, period 1e-2, in 1 of 500 random initial states a 1-ulp
difference grew ~x100 every 3 periods in the sliding phase, up to 1e-8); there both paths are
right to the conditioning of the problem, and no
tolerance derived from rounding applies. The trajectories below are the paper's certified
controllers under smooth and random disturbances, where the amplification stays far below 1e-12.

The kernel is built by ``pip install`` (optional extension). In a source checkout that was never
built the tests that need it skip, unless FTSTAB_REQUIRE_NATIVE=1 (CI sets it) makes that a failure.
"""

import os

import numpy as np
import pytest

from ftstab_mj.simulation import native
from ftstab_mj.control import AdaptiveLaw, HongController, NominalLaw, RobustLaw, advance_phi_hat
from ftstab_mj.plants.disturbances import Signal
from ftstab_mj.simulation.ideal_chain import simulate_chain

TOL = 1e-12

if not native.available():
    if os.environ.get("FTSTAB_REQUIRE_NATIVE") == "1":
        raise RuntimeError(f"FTSTAB_REQUIRE_NATIVE=1 but {native.UNAVAILABLE_REASON}")
needs_kernel = pytest.mark.skipif(not native.available(), reason=f"native kernel: {native.UNAVAILABLE_REASON}")

CONTROLLERS = {  # (r, k, gains) per form; the certified ones of the reference table among them
    "full": [(1, -0.5, (2.0,)), (2, -0.2, (1.0, 2.0)), (3, -0.1, (1.0, 1.7, 5.0)), (4, -0.05, (1.0, 2.0, 3.0, 4.0)),
             (2, 0.0, (1.0, 2.0))],
    "simplified": [(2, -0.2, (1.0, 2.0)), (3, -0.1, (1.0, 1.7, 5.0))],
}


def laws(hong):
    return [NominalLaw(hong), RobustLaw(hong, 0.5, 0.8), AdaptiveLaw(hong, 1.0, 0.5, 2.0, 0.5, 0.05)]


def all_laws() -> list:
    return [pytest.param(law, id=f"{form}-r{r}-k{k}-{type(law).__name__}")
            for form, rows in CONTROLLERS.items() for r, k, gains in rows
            for law in laws(HongController(r, k, gains, form=form, check_hurwitz=False))]


def random_states(rng, n, r):
    """States over 10 decades of magnitude, with exact zeros in some components (sign(0) = 0)."""
    z = rng.standard_normal((n, r)) * 10.0 ** rng.uniform(-8.0, 2.0, (n, 1))
    z[rng.random((n, r)) < 0.05] = 0.0
    z[0] = 0.0
    return z


def assert_agree(ref, fast, what):
    ref, fast = np.asarray(ref), np.asarray(fast)
    assert ref.shape == fast.shape, what
    err = np.abs(fast - ref) / np.maximum(1.0, np.abs(ref))
    assert np.all(err <= TOL), f"{what}: max relative difference {np.max(err):.3g} > {TOL:g}"


@needs_kernel
@pytest.mark.parametrize("law", all_laws())
def test_law_output_agrees_on_random_states(law):
    rng = np.random.default_rng(0)
    z = random_states(rng, 4000, law.hong.r)
    phi_hat = rng.uniform(0.0, 3.0, 4000)
    ref, fast = law.output(z, phi_hat), native.law_output(law, z, phi_hat)
    for name in ref._fields:
        assert_agree(getattr(ref, name), getattr(fast, name), name)
    assert np.all(fast.u[0] == 0.0) and fast.V1[0] == 0.0  # z = 0: u0 = 0, sign(0) = 0


@needs_kernel
def test_law_output_keeps_batch_shape():
    law = RobustLaw(HongController(2, -0.2, (1.0, 2.0)), 0.5, 0.8)
    z = np.random.default_rng(1).standard_normal((3, 4, 2))
    out = native.law_output(law, z)
    assert out.u.shape == (3, 4)
    assert_agree(law.output(z).u, out.u, "u")


@needs_kernel
@pytest.mark.parametrize("law", [AdaptiveLaw(HongController(2, -0.2, (1.0, 2.0)), 1.0, 0.5, 2.0, eta, 0.05)
                                 for eta in (0.3, 0.5, 0.9)])
def test_advance_phi_hat_agrees_in_every_regime(law):
    """V1 spread over the three regimes of nu_eps (decay below eps/2, RK4 band, ramp above eps),
    phi_hat from 0 to large, periods that make the decay reach 0 or not."""
    rng = np.random.default_rng(2)
    V1 = law.eps * rng.uniform(0.0, 2.0, 20000)
    phi_hat = np.where(rng.random(20000) < 0.1, 0.0, 10.0 ** rng.uniform(-6, 1, 20000))
    regimes = law.nu(V1)
    assert np.any(regimes == 0.0) and np.any(regimes == 1.0) and np.any((regimes > 0) & (regimes < 1))
    for h in (1e-4, 1e-2, 0.5):
        ref = advance_phi_hat(law, V1, phi_hat, h)
        fast = native.advance_phi_hat(law, V1, phi_hat, h)
        assert_agree(ref, fast, f"phi_hat after h = {h}")
        assert np.all(fast >= 0.0)


TRAJECTORY_CASES = [
    (2, -0.2, (1.0, 2.0), "robust", Signal("worst_case", 0.0, 0.4)),
    (2, -0.2, (1.0, 2.0), "adaptive", Signal("random", 0.1, 0.4, freq=5.0, seed=2)),
    (3, -0.1, (1.0, 1.7, 5.0), "robust", Signal("sine", 0.0, 0.4, freq=1.0)),
    (3, -0.1, (1.0, 1.7, 5.0), "adaptive", Signal("worst_case", 0.1, 0.3)),
    (3, -0.1, (1.0, 1.7, 5.0), "nominal", Signal("constant", 0.0)),
]


@needs_kernel
@pytest.mark.parametrize("period", [1e-2, 1e-3])
@pytest.mark.parametrize("r,k,gains,kind,phi", TRAJECTORY_CASES,
                         ids=[f"r{c[0]}-{c[3]}-{c[4].kind}" for c in TRAJECTORY_CASES])
def test_whole_trajectories_agree(r, k, gains, kind, phi, period):
    """simulate_chain native vs NumPy: every recorded field of every sample, 16 initial states,
    through the transient into the chattering phase (3 s; the r = 2 bound T(z0) is ~2 s)."""
    hong = HongController(r, k, gains)
    law = {"nominal": NominalLaw(hong), "robust": RobustLaw(hong, 0.5, 0.8),
           "adaptive": AdaptiveLaw(hong, 1.0, 0.5, 2.0, 0.5, 0.05)}[kind]
    z0 = np.random.default_rng(3).uniform(-2.0, 2.0, (16, r))
    args = (law, z0, period, 3.0, phi, Signal("sine", 1.0, 0.2, freq=0.5))
    ref = simulate_chain(*args, substeps=2)
    fast = simulate_chain(*args, substeps=2, native=True)
    assert np.array_equal(ref.t, fast.t)
    for name in ("z", "u", "u0", "V1", "dV1_dzr", "phi_hat", "gamma_hat", "phi", "gamma", "z_final"):
        assert_agree(getattr(ref, name), getattr(fast, name), name)
    assert np.max(ref.V1[-1]) < 1e-2 * np.max(ref.V1[0])  # the run did reach the chattering phase


@needs_kernel
def test_single_state_chain_keeps_shapes():
    law = AdaptiveLaw(HongController(2, -0.2, (1.0, 2.0)), 1.0, 0.5, 2.0, 0.5, 0.05)
    ref = simulate_chain(law, [1.0, -0.5], 1e-2, 1.0, phi_hat0=0.3)
    fast = simulate_chain(law, [1.0, -0.5], 1e-2, 1.0, phi_hat0=0.3, native=True)
    assert fast.z.shape == ref.z.shape == (100, 2) and fast.u.shape == (100,) and fast.z_final.shape == (2,)
    assert_agree(ref.z, fast.z, "z")


def test_auto_falls_back_and_says_so_once(monkeypatch, capsys):
    """Without a kernel: "auto" runs the reference and prints one line, once; True is an error."""
    monkeypatch.setattr(native, "LIB", None)
    monkeypatch.setattr(native, "UNAVAILABLE_REASON", "the C kernel was not built (test)")
    monkeypatch.setattr(native, "_told", False)
    law = RobustLaw(HongController(2, -0.2, (1.0, 2.0)), 0.5, 0.8)
    a = simulate_chain(law, [1.0, 0.0], 1e-2, 0.5, native="auto")
    b = simulate_chain(law, [1.0, 0.0], 1e-2, 0.5, native="auto")
    ref = simulate_chain(law, [1.0, 0.0], 1e-2, 0.5)
    assert np.array_equal(a.z, ref.z) and np.array_equal(b.z, ref.z)
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not built (test)" in err and "pure NumPy" in err
    with pytest.raises(native.NativeUnavailable, match="not built"):
        simulate_chain(law, [1.0, 0.0], 1e-2, 0.5, native=True)
    with pytest.raises(native.NativeUnavailable, match="not built"):
        native.law_output(law, [1.0, 0.0])


def test_bad_native_choice_is_a_parameter_error():
    law = NominalLaw(HongController(2, -0.2, (1.0, 2.0)))
    with pytest.raises(ValueError, match="native"):
        simulate_chain(law, [1.0, 0.0], 1e-2, 0.1, native="yes")


@needs_kernel
def test_law_the_kernel_cannot_take_falls_back_under_auto():
    hong = HongController(9, -0.01, tuple(float(i) for i in range(1, 10)), check_hurwitz=False)
    law = NominalLaw(hong)
    assert not native.use_native("auto", law)
    with pytest.raises(native.NativeUnavailable, match="r <= 8"):
        native.use_native(True, law)


@needs_kernel
def test_chain_threads_do_not_change_the_result():
    """The batch split over threads writes disjoint columns: bit-identical to one thread."""
    law = AdaptiveLaw(HongController(2, -0.2, (1.0, 2.0)), 1.0, 0.5, 2.0, 0.5, 0.05)
    z0 = np.random.default_rng(4).uniform(-2.0, 2.0, (37, 2))
    t_sub = np.arange(200)[:, None] * 1e-2
    runs = []
    for threads in (1, 3, 64):
        phi_in, keep = native.chain_input(Signal("sine", 0.0, 0.4, freq=1.0), t_sub)
        gam_in, _ = native.chain_input(Signal("worst_case", 1.0, 0.2), t_sub)
        Phi, G = np.array([[1.0, 1e-2], [0.0, 1.0]]), np.array([0.5e-4, 1e-2])
        z, ph = z0.copy(), np.zeros(37)
        zs, rec = native.simulate_chain_kernel(law, z, ph, 200, 1, 1e-2, Phi, G, phi_in, gam_in, threads)
        runs.append((zs, rec, z, ph))
    for zs, rec, z, ph in runs[1:]:
        assert np.array_equal(zs, runs[0][0]) and np.array_equal(z, runs[0][2]) and np.array_equal(ph, runs[0][3])
        assert all(np.array_equal(rec[k], runs[0][1][k]) for k in rec)


@needs_kernel
@pytest.mark.parametrize("law", all_laws())
def test_one_state_at_a_time_is_bit_identical(law):
    """What the run loop's Python path computes (the law on one state z (r,), its powers those of NumPy
    scalars) is what the kernel computes, bit for bit: V1's |a|^(b+1) taken as |a|^b |a| on both, and
    phi_hat's decay squared by the ufunc, not by a NumPy scalar's ** (libm's pow, not correctly rounded).
    A rounding between the paths was fed back by the adaptive law and grew to 1e-7 on arm3_adaptive."""
    rng = np.random.default_rng(3)
    z = random_states(rng, 300, law.hong.r)
    phi_hat = rng.uniform(0.0, 3.0, 300)
    fast = native.law_output(law, z, phi_hat)
    for i in range(len(z)):
        one = law.output(z[i], phi_hat[i])
        for name in one._fields:
            assert np.float64(getattr(one, name)).tobytes() == np.float64(getattr(fast, name)[i]).tobytes(), (name, i)
    if isinstance(law, AdaptiveLaw):
        V1 = law.eps * rng.uniform(0.0, 2.0, 300)  # the three regimes of nu_eps
        ref = [advance_phi_hat(law, V1[i], phi_hat[i], 1e-3) for i in range(300)]
        assert np.array_equal(np.ravel(ref), native.advance_phi_hat(law, V1, phi_hat, 1e-3))

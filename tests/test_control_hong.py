"""Hong's controller: homogeneity, condition (condition_theorem2), the k = 0 limit, V1's properties."""

import numpy as np
import pytest

from ftstab_mj.control import HongController, gains_for_polynomial, is_hurwitz, nested_polynomial
from ftstab_mj.config.errors import ParameterError

RS = range(1, 7)


def hurwitz_gains(r, pole=-1.0):
    """Gains placing every linear closed-loop pole at ``pole`` (an independent route to Hurwitz gains)."""
    return gains_for_polynomial(np.poly([pole] * r))


def random_states(r, n=2000, seed=0):
    rng = np.random.default_rng(seed)
    return rng.standard_normal((n, r)) * 10.0 ** rng.uniform(-2, 1, size=(n, 1))


@pytest.mark.parametrize("r", RS)
def test_homogeneity_full_form(r):
    """u0(D_lam z) = lam^{p_{r+1}} u0(z) and V1(D_lam z) = lam^{2+k} V1(z) (weights p_i = 1 + (i-1) k)."""
    k = -0.6 / r
    hong = HongController(r, k, hurwitz_gains(r))
    rng = np.random.default_rng(r)
    z = random_states(r, seed=r)
    lam = 10.0 ** rng.uniform(-1, 1, size=len(z))
    u, V = hong.u0(z), hong.V1(z)
    ud, Vd = hong.u0(hong.dilate(z, lam)), hong.V1(hong.dilate(z, lam))
    np.testing.assert_allclose(ud, lam ** (1 + r * k) * u, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(Vd, lam ** (2 + k) * V, rtol=1e-9, atol=1e-14)
    # dV1/dz_r has degree (2 + k) - p_r, hence alpha' = 1 - p_r / (2 + k).
    dVd = hong.dV1_dzr(hong.dilate(z, lam))
    np.testing.assert_allclose(dVd, lam ** (2 + k - (1 + (r - 1) * k)) * hong.dV1_dzr(z), rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("form", ["full", "simplified"])
@pytest.mark.parametrize("r", RS)
def test_condition_theorem2(r, form):
    """dV1/dz_r * u0 <= 0 everywhere, and u0 = 0 implies dV1/dz_r = 0 (paper, condition_theorem2)."""
    k = -0.5 / (r + 1)
    hong = HongController(r, k, hurwitz_gains(r), form=form)
    z = random_states(r, seed=10 + r)
    out = hong.evaluate(z)
    assert np.all(out.dV1_dzr * out.u0 <= 0.0)
    assert np.all(np.sign(out.dV1_dzr) == -np.sign(out.u0))
    # States on the switching surface {u0 = 0}: put z_r on the virtual control v_{r-1}.
    _, v = hong._chain(z)
    z_on = z.copy()
    z_on[:, -1] = v[-2]
    on = hong.evaluate(z_on)
    assert np.all(on.u0 == 0.0)
    assert np.all(on.dV1_dzr == 0.0)


@pytest.mark.parametrize("form", ["full", "simplified"])
@pytest.mark.parametrize("r", RS)
def test_k_zero_is_linear_backstepping(r, form):
    """At k = 0 both forms are u0 = K z, with K the linear backstepping gain built in matrix form,
    and the closed-loop characteristic polynomial is the nested polynomial of the gains."""
    gains = hurwitz_gains(r, pole=-1.3)
    hong = HongController(r, 0.0, gains, form=form)
    # Matrix form of v_{i+1} = -l_{i+1} (z_{i+1} - v_i): rows K_i with v_i = K_i z.
    K = np.zeros(r)
    for i in range(r):
        e = np.zeros(r)
        e[i] = 1.0
        K = -gains[i] * (e - K)
    z = random_states(r, seed=20 + r)
    np.testing.assert_allclose(hong.u0(z), z @ K, rtol=1e-12, atol=1e-12)
    A = np.eye(r, k=1)
    A[-1] += K
    np.testing.assert_allclose(np.poly(A), nested_polynomial(gains), rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(A)), -1.3 * np.ones(r), atol=2e-2)


@pytest.mark.parametrize("form", ["full", "simplified"])
@pytest.mark.parametrize("r", RS)
def test_V1_positive_definite_and_gradient(r, form):
    """V1 >= 0, V1(0) = 0 only there; dV1/dz_r and the Lie derivative agree with central differences."""
    k = -0.5 / (r + 1)
    hong = HongController(r, k, hurwitz_gains(r), form=form)
    z = random_states(r, n=500, seed=30 + r)
    V = hong.V1(z)
    assert np.all(V > 0.0)
    assert hong.V1(np.zeros(r)) == 0.0
    h = 1e-6 * (1.0 + np.abs(z[:, -1]))
    zp, zm = z.copy(), z.copy()
    zp[:, -1] += h
    zm[:, -1] -= h
    fd = (hong.V1(zp) - hong.V1(zm)) / (2 * h)
    np.testing.assert_allclose(hong.dV1_dzr(z), fd, rtol=1e-5, atol=1e-6)
    d = np.random.default_rng(r).standard_normal(z.shape)
    # Step scaled to the state: some states are ~1e-3 in size, where an absolute 1e-6 is too coarse.
    eps = 1e-6 * (np.linalg.norm(z, axis=1) / np.linalg.norm(d, axis=1))[:, None]
    fd_dir = (hong.V1(z + eps * d) - hong.V1(z - eps * d)) / (2 * eps[:, 0])
    np.testing.assert_allclose(hong.lie_derivative(z, d), fd_dir, rtol=1e-4, atol=1e-5)


def test_single_state_and_batch_agree():
    hong = HongController(3, -0.1, (1.0, 1.7, 5.0))
    z = random_states(3, n=7)
    batch = hong.evaluate(z)
    for i in range(len(z)):
        one = hong.evaluate(z[i])
        assert np.shape(one.u0) == ()
        # NumPy's vectorised pow may differ from the scalar one in the last bit: compare at 1e-14.
        np.testing.assert_allclose([one.u0, one.V1, one.dV1_dzr],
                                   [batch.u0[i], batch.V1[i], batch.dV1_dzr[i]], rtol=1e-14)


def test_nested_polynomial_and_gains_inverse():
    # r = 3: y^3 + l3 y^2 + l3 l2 y + l3 l2 l1, Hurwitz iff l3 > l1 (Routh-Hurwitz).
    np.testing.assert_allclose(nested_polynomial([2.0, 3.0, 5.0]), [1, 5, 15, 30])
    assert is_hurwitz([1.0, 2.0, 3.0]) and not is_hurwitz([3.0, 2.0, 1.0])
    assert is_hurwitz([1.0, 1.0]) and is_hurwitz([0.01, 100.0])  # r = 2: every positive pair
    for r in RS:
        g = tuple(np.random.default_rng(r).uniform(0.5, 3.0, r))
        np.testing.assert_allclose(gains_for_polynomial(nested_polynomial(g)), g, rtol=1e-12)


@pytest.mark.parametrize("args, name", [
    ((0, -0.1, ()), "r"),
    ((2, 0.1, (1, 2)), "k"),
    ((2, -0.5, (1, 2)), "k"),  # full form needs k > -1/r
    ((2, -0.34, (1, 2), "simplified"), "k"),  # simplified needs k > -1/(r+1)
    ((2, -0.2, (1,)), "gains"),
    ((2, -0.2, (1, -2)), "gains[1]"),
    ((2, -0.2, (1, float("nan"))), "gains[1]"),
    ((3, -0.1, (3, 2, 1)), "gains"),  # not Hurwitz (l_3 < l_1)
    ((2, -0.2, (1, 2), "other"), "form"),
])
def test_parameter_validation_names_the_parameter(args, name):
    with pytest.raises(ParameterError) as err:
        HongController(*args)
    assert isinstance(err.value, ValueError)
    assert err.value.name.startswith(name)
    assert "expected" in str(err.value) and "got" in str(err.value)


def test_full_form_accepts_k_close_to_minus_one_over_r():
    hong = HongController(2, -0.49, (1.0, 2.0))
    assert np.isfinite(hong.u0(np.array([0.3, -0.2])))


def _V1_u0_exact(r, k, gains, z):
    """(V1, u0) of the full form at z (r mpf numbers), mpmath at the current precision, from the
    paper's formulas (not the package's): p_i = 1 + (i-1) k, beta_i = (2 + k)/p_{i+1} - 1, v_0 = 0,
    v_{i+1} = -l_{i+1} sig(sig(z_{i+1}, beta_i) - sig(v_i, beta_i), p_{i+2}/(p_{i+1} beta_i)),
    V1 = sum_j W(z_j, v_{j-1}, beta_{j-1}); k and the gains are the floats taken exactly."""
    import mpmath as mp

    k = mp.mpf(float(k))
    p = [1 + i * k for i in range(r + 1)]
    sig = lambda a, e: mp.sign(a) * abs(a) ** e  # noqa: E731
    v, V = mp.mpf(0), mp.mpf(0)
    for i in range(r):
        b = (2 + k) / p[i] - 1
        V += (abs(z[i]) ** (b + 1) - abs(v) ** (b + 1)) / (b + 1) - sig(v, b) * (z[i] - v)
        v = -mp.mpf(float(gains[i])) * sig(sig(z[i], b) - sig(v, b), p[i + 1] / (p[i] * b))
    return V, v


def _dV1dt_exact(r, k, gains, z):
    """dV1/dt along z' = (z_2, .., z_r, u0) at the float state z taken exactly: d/dt V1(z + t z') at
    t = 0 (mpmath's numerical derivative at the current precision; V1 is C^1)."""
    import mpmath as mp

    z = [mp.mpf(float(x)) for x in z]
    zdot = z[1:] + [_V1_u0_exact(r, k, gains, z)[1]]
    return mp.diff(lambda t: _V1_u0_exact(r, k, gains, [a + t * b for a, b in zip(z, zdot)])[0], 0)


# gains spanning decades (the certificate's K0 sets): the worst conditioned ones at each r
SPREAD_GAINS = {2: (0.1, 1e5), 3: (0.1, 45.94, 1e5), 4: (1.253, 3.042, 50.211, 1e5), 5: (0.65, 1.2, 1.62, 12.63, 1000.0)}


@pytest.mark.parametrize("r", [2, 3, 4, 5])
def test_float_dV1dt_is_backward_stable_over_the_whole_range_of_k(r):
    """closed_loop_dV1dt at a float state z is, to rounding, the exact dV1/dt (mpmath, 40 digits) at
    a state a couple of ulps from z, for k over the whole admissible range (-1/r, 0): its error is
    at most 2 D + 64 eps |exact|, D = sum over the coordinates of |exact(z + 2 ulp e_j) - exact(z)|
    (each move taken both ways, the mean). Measured: error / bound <= 0.44 (r = 2..5, k = -0.1/r ..
    -0.999/r, 16 states each; outside the suite, 60 states each: error <= 4 D). The relative error is the
    function's conditioning, not the evaluation's: it grows with gains spanning decades as k nears
    -1/r (see HongController.lie_derivative). States near the zeros of the recursion variables
    (log-uniform moduli 1e-6..1), where the small exponents act. Teeth: the controller at z
    (1 + 1e-12), i.e. a backward error of ~4500 ulps, fails the bound on most states."""
    import mpmath as mp

    from ftstab_mj.control.hong_terms import Terms

    gains, n, eps = SPREAD_GAINS[r], 16, np.finfo(float).eps
    rng = np.random.default_rng(300 + r)
    for f in (0.1, 0.5, 0.9, 0.99, 0.999):
        k = -f / r
        hong = HongController(r, k, gains, check_hurwitz=False)
        s = np.sign(rng.uniform(-1, 1, (n, r))) * 10.0 ** rng.uniform(-6, 0, (n, r))
        s[np.arange(n), rng.integers(0, r, n)] = 1.0
        z = np.stack(Terms(r, k, gains).z_of([s[:, i] for i in range(r)])[0], axis=-1)
        got, off = hong.closed_loop_dV1dt(z), hong.closed_loop_dV1dt(z * (1 + 1e-12))
        worst, caught = 0.0, 0
        with mp.workdps(40):
            for zi, g, o in zip(z, got, off):
                ex = _dV1dt_exact(r, k, gains, zi)
                D = mp.mpf(0)
                for j in range(r):
                    for d in (-1.0, 1.0):
                        zz = zi.copy()
                        zz[j] += d * 2.0 * np.spacing(zi[j])
                        D += abs(_dV1dt_exact(r, k, gains, zz) - ex) / 2
                bound = 2 * D + 64 * eps * abs(ex)
                worst = max(worst, float(abs(mp.mpf(g) - ex) / bound))
                caught += abs(mp.mpf(o) - ex) > bound
        print(f"r = {r}, k = -{f}/r: largest error / bound {worst:.3g}; z (1 + 1e-12) beyond it on {caught} of {n}")
        assert worst <= 1.0, (r, k)
        assert caught >= n // 2, (r, k)

"""The limit of c as k -> 0 from below (linear_limit.limit_c), against the controller's own Lie
derivative; and the zero-set search that starts from its maximisers.

As k -> 0- the factors b |z_i|^(b - 1) and g |s_i|^(g - 1) of the recursion tend to 1 off their
zero sets and stay 0 on them, so lim c is the smallest, over the choices of zero sets, of the linear
law's c with those factors removed and the state restricted to the sets. The first-order gap at
k < 0: every exponent differs from its limit by at most 2 r |k|, and a gain enters as l^b =
l l^(b - 1), so a term moves by a relative ~2 r |k| ln(l_max) (1.4e-4 at r = 6, k = -1e-6,
l_max = 1e5; the measured gaps are 0.3 to 1.2 times that); the tests allow twice it.
"""

import math

import numpy as np
import pytest

from ftstab_mj.control import HongController, certify
from ftstab_mj.control.certificate import Ratio, _zero_set_witness, onto_zero_set, zero_set_starts
from ftstab_mj.control.hong_terms import Terms
from ftstab_mj.control.linear_limit import limit_c, limit_forms, linear_c

# r = 6: the limit optimum for gains <= 1e5; the certificate table's 6-decade row; r = 5 k = -0.01's
G6_LIMIT = (0.55176, 1.0437, 1.3353, 3.3293, 46.148, 1e5)
G6_DECADES = (0.62, 1.15, 1.54, 3.88, 39.13, 1e5)
G5 = (0.65, 1.2, 1.62, 12.63, 1000.0)
G3 = (1.0, 1.7, 5.0)  # the paper's r = 3 row


def _first_order(r, k, gains):
    return 2 * r * abs(k) * math.log(max(gains))


def _linear_v(z, gains):
    """v_0 .. v_r (r + 1,) of the k = 0 law at the state z (r,): v_i = -l_i (z_i - v_{i-1})."""
    v = np.zeros(len(z) + 1)
    for i in range(1, len(z) + 1):
        v[i] = -gains[i - 1] * (z[i - 1] - v[i - 1])
    return v


def test_the_limit_is_the_linear_c_with_every_factor_one_and_never_above_it():
    """On 60 random gain sets (r = 1..6, log-uniform in [0.1, 1e5]): the choice with no zero set is
    linear_c (the same form, another construction: relative 1e-9); limit_c is never above it; for
    r <= 2 there is no factor, so they are equal."""
    rng = np.random.default_rng(3)
    for r in range(1, 7):
        for _ in range(10):
            gains = tuple(np.sort(10.0 ** rng.uniform(-1.0, 5.0, r)))
            forms = list(limit_forms(gains))
            plain = [f for f in forms if not f.z_zero and not f.s_zero]
            assert len(plain) == 1 and plain[0].c == pytest.approx(linear_c(gains), rel=1e-9, abs=1e-12)
            assert limit_c(gains).c <= plain[0].c
            if r <= 2:
                assert len(forms) == 1


def test_gains_that_overflow_floats_have_no_limit_value_as_no_linear_value():
    """Gains whose products overflow floats (1e100 each at r = 6: l^5 = 1e500): limit_c is -inf, as
    linear_c is (no value, not an error); gains of 10 have a finite one."""
    assert linear_c((1e100,) * 6) == -np.inf and limit_c((1e100,) * 6).c == -np.inf
    assert np.isfinite(limit_c((10.0,) * 6).c)


def test_every_limit_state_lies_on_its_zero_sets_with_its_value():
    """Each choice's state z has z_i = 0 on its z-sets and e_i = z_i - v_{i-1} = 0 on its s-sets
    (k = 0 law: v_i = -l_i e_i), |e| = 1, and there the limit's dV1/dt, recomputed here from the
    state with the recursion of w (those factors 0), is -c |e|^2 / 2 (c = -2 lambda_max)."""
    for gains in (G6_LIMIT, G5):
        r = len(gains)
        l = np.asarray(gains)
        for f in limit_forms(gains):
            z = f.z
            v = _linear_v(z, gains)
            e = z - v[:r]
            assert np.linalg.norm(e) == pytest.approx(1.0, rel=1e-9)
            assert all(z[i - 1] == 0.0 for i in f.z_zero)
            assert all(abs(e[i - 1]) <= 1e-9 * np.abs(e).max() for i in f.s_zero)
            # dV1/dt = sum_j e_j z_{j+1} - e_j w_{j-1}, w_i = -l_i G_i (B_i z_{i+1} - w_{i-1})
            znext = np.append(z[1:], v[r])
            w = np.zeros(r)
            w[1] = -l[0] * z[1] if r >= 2 else 0.0
            for i in range(2, r):
                B = 0.0 if i in f.z_zero else 1.0
                G = 0.0 if i in f.s_zero else 1.0
                w[i] = -l[i - 1] * G * (B * z[i] - w[i - 1])
            dV = float(np.sum(e * znext) - np.sum(e * w))  # w[0] = w_0 = 0
            assert dV == pytest.approx(-f.c / 2.0, rel=1e-7, abs=1e-9 * max(gains)), (f.z_zero, f.s_zero)


@pytest.mark.parametrize("gains", [G3, G5, G6_LIMIT, G6_DECADES], ids=["r3", "r5", "r6-limit", "r6-decades"])
def test_every_choice_is_the_limit_of_the_certificates_own_ratio_on_its_sets(gains):
    """Every choice of zero sets, the s_i = 0 ones included (the controller's own Lie derivative is
    NaN at an exact s_i = 0, 0 * inf in its chain rule, and |s_i|^(g_i - 1) is still ~1 at
    |s_i| = 1e-300 for k = -1e-6; the test above checks those only against its own copy of the
    recursion): the certificate's own float R (hong_terms.Terms, whose recursion variables are
    the coordinates, so s_i = 0 and z_i = 0 are exact) at the choice's state put on its sets (s = e
    of the limit state, s_i = 0, then s_i = -S_{i-1} for z_i = 0, in order of i) is within twice
    the first-order gap of -c at k = -1e-5, and the gap falls with |k| (first order: 10x from -1e-5
    to -1e-6; measured 8.7x to 10.1x, largest gap 1.18 times the first-order one)."""
    r = len(gains)
    for f in limit_forms(gains):
        v = _linear_v(f.z, gains)
        gaps = []
        for k in (-1e-5, -1e-6):
            t = Terms(r, k, gains)
            s = (f.z - v[:r])[None, :].copy()
            for i in range(2, r):
                if i in f.s_zero:
                    s[0, i - 1] = 0.0
                if i in f.z_zero:
                    onto_zero_set(t, s, i)
            gaps.append(abs(Ratio(t, "c").floats(s)[0] + f.c) / abs(f.c))
        assert gaps[0] <= 2 * _first_order(r, -1e-5, gains), (f.z_zero, f.s_zero, gaps)
        assert gaps[1] < gaps[0] / 3, (f.z_zero, f.s_zero, gaps)


@pytest.mark.parametrize("gains", [G6_LIMIT, G6_DECADES, G5], ids=["r6-limit", "r6-decades", "r5"])
def test_the_limit_is_the_controllers_own_maximum_on_the_zero_set(gains):
    """At k = -1e-6 and -1e-5, on the zero set where limit_c is attained, the controller's own
    dV1/dt / V1^alpha (HongController, z_i = 0 exactly) at the zero-set start of the certificate
    (the limit maximiser, s_r re-optimised) is within twice the first-order gap of -limit_c, and the
    gap falls with |k| (measured at r = 6: 1.4e-4 relative at k = -1e-6, 1.4e-3 at -1e-5)."""
    r = len(gains)
    lim = limit_c(gains)
    assert len(lim.z_zero) == 1 and not lim.s_zero  # the binding set of these gains
    i = lim.z_zero[0]
    gaps = []
    for k in (-1e-5, -1e-6):
        t = Terms(r, k, gains)
        s = zero_set_starts(Ratio(t, "c"))[i]
        z = np.stack(t.z_of([s[:, j] for j in range(r)])[0], axis=-1)
        assert np.all(np.abs(z[:, i - 1]) <= 1e-15 * np.abs(z).max())  # on the set up to rounding
        z[:, i - 1] = 0.0
        h = HongController(r, k, gains, check_hurwitz=False)
        R = float(np.max(h.closed_loop_dV1dt(z) / h.V1(z) ** ((2 + 2 * k) / (2 + k))))
        gap = abs(R + lim.c) / abs(lim.c)
        assert gap <= 2 * _first_order(r, k, gains), (k, R, lim.c)
        gaps.append(gap)
    assert gaps[1] < gaps[0] / 3


def _zero_set_start_one_set(obj, f):
    """The zero-set start of one set, the slow reference path: its own golden section on s_r, the
    two trial points evaluated one after the other (as zero_set_starts did before it ran every set
    at once)."""
    from ftstab_mj.control.certificate import GOLDEN, LAST_SWEEP, onto_faces

    t, r = obj.t, obj.r
    s = onto_zero_set(t, onto_faces(t, np.stack([f.z, -f.z])), f.z_zero[0])
    grid = LAST_SWEEP[None, :] * np.abs(s[:, r - 1:]).clip(1e-300, 1.0)
    trial = np.repeat(s, grid.shape[1], axis=0)
    trial[:, r - 1] = grid.ravel()
    j = obj.floats(trial).reshape(2, -1).argmax(axis=1).clip(1, grid.shape[1] - 2)
    a, b = grid[[0, 1], j - 1], grid[[0, 1], j + 1]
    for _ in range(60):
        x1, x2 = b - GOLDEN * (b - a), a + GOLDEN * (b - a)
        s[:, r - 1] = x1
        R1 = obj.floats(s)
        s[:, r - 1] = x2
        left = R1 >= obj.floats(s)
        a, b = np.where(left, a, x1), np.where(left, x2, b)
    s[:, r - 1] = (a + b) / 2.0
    return s


@pytest.mark.parametrize("r, k, gains", [(3, -0.1, (1.3643, 2.5353, 100.0)), (5, -0.02, (0.70391, 1.2469, 1.7225, 8.962, 1000.0)),
                                          (6, -0.002, G6_DECADES)])
def test_the_joint_golden_section_is_each_sets_own_bit_for_bit(r, k, gains):
    """zero_set_starts runs the golden sections of every zero set (and both signs) in one array, both
    trial points in one evaluation; the float R is elementwise in the states, so each set's start is
    exactly the one its own section gives (no tolerance: the same floats)."""
    obj = Ratio(Terms(r, k, gains), "c")
    joint = zero_set_starts(obj)
    forms = limit_forms(list(gains), single=True)
    assert sorted(joint) == sorted(f.z_zero[0] for f in forms) == list(range(2, r))
    for f in forms:
        assert np.array_equal(joint[f.z_zero[0]], _zero_set_start_one_set(obj, f))


def test_r6_gains_refuted_on_a_zero_set_fail_the_limit_condition():
    """The r = 6 gains certify refutes on z_4 = 0 at k = -0.002 (the 6-decade row; the designer's
    first k = -0.005 candidate) have linear_c > 0 but limit_c < 0 on z_4 = 0: no certificate for any
    k close enough to 0. The limit's optimum for gains <= 1e5 has limit_c > 0 on every set."""
    for gains in (G6_DECADES, (0.6588, 1.1168, 1.4924, 3.3762, 43.835, 1e5)):
        lim = limit_c(gains)
        assert linear_c(gains) > 0.05 and lim.c < -0.05 and lim.z_zero == (4,), (gains, lim)
    assert limit_c(G6_LIMIT).c > 0.02


def test_the_zero_set_search_reaches_the_limit_value():
    """r = 6, k = -0.0005, the limit optimum for gains <= 1e5 (lim c = 0.02125): the guaranteed
    value of dV1/dt / V1^alpha that certify's zero-set search finds is within twice the first-order
    gap (2.8 %) of -lim c, so c <= ~0.022 there (measured -0.02167; from sampled states alone the
    same search reached -0.084, i.e. claimed only c <= 0.084)."""
    k = -0.0005
    lo, z = _zero_set_witness(Ratio(Terms(6, k, G6_LIMIT), "c"), 0)
    lim = limit_c(G6_LIMIT).c
    assert abs(lo + lim) <= 2 * _first_order(6, k, G6_LIMIT) * lim, (lo, lim)
    assert (z[1:-1] == 0.0).any()


def test_certify_reports_the_zero_set_value_as_its_c_upper():
    """certify's c_upper takes the zero-set state's guaranteed value where it is tighter than the
    sampled witness (it was reported only when it refuted): r = 6, k = -0.0005, the limit optimum
    for gains <= 1e5: c_upper within twice the first-order gap of lim c (sampled witness: 0.084),
    the witness has a z_i exactly 0 and V1 = 1, and the controller's own dV1/dt / V1^alpha there is
    -c_upper within 1e-4 relative (measured 3.8e-6: c_upper is the low end of R's enclosure at the
    state before its dilation onto V1 = 1, whose rounding l_6 = 1e5 magnifies in s_6)."""
    k = -0.0005
    h = HongController(6, k, G6_LIMIT)
    cert = certify(h, budget=2.0)
    lim = limit_c(G6_LIMIT).c
    assert cert.status != "not certified" and abs(cert.c_upper - lim) <= 2 * _first_order(6, k, G6_LIMIT) * lim
    w = np.array([cert.witness])
    assert (w[0, 1:-1] == 0.0).any() and abs(h.V1(w)[0] - 1.0) < 1e-9
    R = float(h.closed_loop_dV1dt(w)[0] / h.V1(w)[0] ** ((2 + 2 * k) / (2 + k)))
    assert R == pytest.approx(-cert.c_upper, rel=1e-4)

"""Adversarial checks of control/interval.py, the arithmetic the certificate's bounds rest on: every
operation's result encloses the exact value (mpmath at 80 digits) at points of its argument
intervals, on random intervals mixing zeros of both signs, subnormals, the largest floats and
infinite (unbounded) ends; and the one platform assumption the power enclosure makes: np.power
(the SIMD array path and the scalar one) errs by less than the margin every power bound is widened
by (interval._POW_ULPS - 1 ulps: round_down/round_up move a float at least that far)."""

import mpmath as mp
import numpy as np
import pytest

from ftstab_mj.control.interval import _POW_ULPS, Exp, Iv, minus_one

TRUSTED_ULPS = _POW_ULPS - 1  # how far np.power may err for the power bounds to hold

MAX = np.finfo(float).max
SPECIAL = np.array([0.0, -0.0, 5e-324, -5e-324, 2.0 ** -1022, -2.0 ** -1022, 1e-310, MAX, -MAX, 1.0, -1.0,
                    1e308, -1e-300, 1e-20, 3.0])


def _floats(rng, n):
    kind = rng.integers(0, 4, n)
    return np.select([kind == 0, kind == 1, kind == 2],
                     [rng.choice(SPECIAL, n), rng.standard_normal(n) * 10.0 ** rng.uniform(-320, 308, n),
                      rng.standard_normal(n)], rng.uniform(-2.0 ** -1020, 2.0 ** -1020, n))


def _intervals(rng, n):
    a, b = _floats(rng, n), _floats(rng, n)
    b = np.where(rng.random(n) < 0.3, a, b)  # degenerate intervals too
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    return np.where(rng.random(n) < 0.05, -np.inf, lo), np.where(rng.random(n) < 0.05, np.inf, hi)


def _points(rng, lo, hi):
    """Finite points (mpf) of each [lo, hi]: its finite ends, two interior points, 0 when inside."""
    out = []
    for a, b in zip(lo, hi):
        A = mp.mpf(a) if np.isfinite(a) else mp.mpf(-MAX)
        B = mp.mpf(b) if np.isfinite(b) else mp.mpf(MAX)
        out.append([A, B] + [A + (B - A) * mp.mpf(float(t)) for t in rng.random(2)] + ([mp.mpf(0)] if A <= 0 <= B else []))
    return out


def _assert_encloses(name, iv, exact):
    """exact[i]: the exact values (None: undefined) that element i of iv must hold."""
    for i, values in enumerate(exact):
        lo, hi = iv.lo.flat[i], iv.hi.flat[i]
        assert not (np.isnan(lo) or np.isnan(hi)), (name, i)
        for v in values:
            if v is not None:
                assert mp.mpf(lo) <= v <= mp.mpf(hi), (name, i, v, lo, hi)


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")  # the largest floats overflow to inf, on purpose
@pytest.mark.parametrize("seed", [1, 2])
def test_every_operation_encloses_the_exact_result_on_hostile_intervals(seed):
    mp.mp.dps = 80
    rng = np.random.default_rng(seed)
    n = 120
    al, ah = _intervals(rng, n)
    bl, bh = _intervals(rng, n)
    A, B = Iv(al, ah), Iv(bl, bh)
    pa, pb = _points(rng, al, ah), _points(rng, bl, bh)
    pairs = [(xs, ys) for xs, ys in zip(pa, pb)]
    _assert_encloses("add", A + B, [[x + y for x in xs for y in ys] for xs, ys in pairs])
    _assert_encloses("sub", A - B, [[x - y for x in xs for y in ys] for xs, ys in pairs])
    _assert_encloses("mul", A * B, [[x * y for x in xs for y in ys] for xs, ys in pairs])
    _assert_encloses("div", A / B, [[x / y if y else None for x in xs for y in ys] for xs, ys in pairs])
    _assert_encloses("sq", A.sq(), [[x * x for x in xs] for xs in pa])
    point = np.where(np.isfinite(bl), bl, 2.5)  # a point interval (lo is hi: the two-product path)
    for prod in (A * Iv(point), Iv(point) * A):
        _assert_encloses("point mul", prod, [[x * mp.mpf(y) for x in xs] for xs, y in zip(pa, point)])

    def power(x, p):  # |x|^p; 0^p undefined for p <= 0
        return abs(x) ** p if x else (mp.mpf(0) if p > 0 else None)

    for _ in range(3):
        p0 = float(rng.uniform(0.02, 3.0))
        ulp = float(np.spacing(p0))
        for e in (Exp(p0), Exp(p0, p0 + 64 * ulp), Exp(p0, p0 + 1e-12), Exp(p0, p0 + float(rng.uniform(1e-12, 0.5))),
                  Exp(-p0), Exp(-p0 - 3 * ulp, -p0), Exp(-0.1, 0.2)):
            ps = [mp.mpf(e.lo), mp.mpf(e.hi), (mp.mpf(e.lo) + mp.mpf(e.hi)) / 2]
            _assert_encloses(f"pabs {e.lo} {e.hi}", A.pabs(e), [[power(x, p) for x in xs for p in ps] for xs in pa])
            if e.lo > 0:
                _assert_encloses(f"sig {e.lo} {e.hi}", A.sig(e),
                                 [[power(x, p) * (1 if x >= 0 else -1) for x in xs for p in ps] for xs in pa])
            m = minus_one(e)
            assert mp.mpf(m.lo) <= mp.mpf(e.lo) - 1 and mp.mpf(e.hi) - 1 <= mp.mpf(m.hi)


def _ulp_errors(x, p, y):
    """|y - x^p| in units of the float spacing at the exact x^p (an overflow to inf counts as exact)."""
    out = []
    for xi, pi, yi in zip(x, p, y):
        exact = mp.mpf(xi) ** mp.mpf(pi)
        if exact > MAX:
            out.append(0.0 if yi == np.inf else np.inf)
            continue
        out.append(float(abs(mp.mpf(yi) - exact) / max(np.spacing(abs(float(exact))), 2.0 ** -1074)))
    return np.array(out)


def test_numpy_power_errs_by_less_than_the_widening_the_enclosure_assumes():
    """The power enclosure trusts np.power to within _POW_ULPS - 1 = 15 ulps (measured here <= 0.75):
    checked on this platform's array and scalar paths where libm is hardest: bases near 1 with
    large exponents, results near overflow and in the subnormals, subnormal bases."""
    mp.mp.dps = 60
    rng = np.random.default_rng(3)
    n = 400
    cases = {
        "broad": (10.0 ** rng.uniform(-320, 308, n), rng.uniform(-3, 3, n)),
        "base near 1": (1 + rng.uniform(-1e-3, 1e-3, n), rng.uniform(-3e5, 3e5, n)),
        "subnormal results": (x := 10.0 ** rng.uniform(-20, -1, n), rng.uniform(300, 330, n) / -np.log10(x)),
        "near overflow": (x := 10.0 ** rng.uniform(1, 20, n), rng.uniform(300, 308.2, n) / np.log10(x)),
        "subnormal bases": (rng.uniform(0, 2.0 ** -1022, n), rng.uniform(0.02, 1.5, n)),
    }
    with np.errstate(over="ignore"):
        for name, (x, p) in cases.items():
            assert _ulp_errors(x, p, np.power(x, p)).max() < TRUSTED_ULPS, name
            scalar = np.array([np.power(float(a), float(b)) for a, b in zip(x[:100], p[:100])])
            assert _ulp_errors(x[:100], p[:100], scalar).max() < TRUSTED_ULPS, name


@pytest.mark.parametrize("op", ["sig", "pabs"])
def test_the_affine_remainder_encloses_phi_minus_its_slope_at_its_true_extrema(op):
    """interval.affine_remainder: D holds phi_p(t) - a t (phi_p = sig(., p) or |.|^p) at every t of
    [lo, hi] and every p of the exponent interval, checked in mpmath at 60 digits at the ends, at 0,
    at random points and at the exact stationary points t* = +-(|a|/p)^(1/(p - 1)) (where the
    extremum inside the interval is); on intervals near and across 0, with the secant slope and with
    a perturbed one (any slope must be sound). The check has teeth: at the stationary points
    the remainder leaves the hull of its values at the ends and at 0 (what D would be without them)
    on most intervals."""
    from ftstab_mj.control.interval import affine_remainder, secant_slope

    mp.mp.dps = 60
    rng = np.random.default_rng(5 if op == "sig" else 6)
    n, beyond, checked = 60, 0, 0
    for p0 in (0.984, 0.5, 0.002, 1.002, 1.6):
        for e in (Exp(p0), Exp(p0, p0 + 64 * float(np.spacing(p0)))):
            c = np.sign(rng.uniform(-1, 1, n)) * 10.0 ** rng.uniform(-8, 0, n)
            w = np.abs(c) * 10.0 ** rng.uniform(-1, 1, n)
            lo, hi = c - w, c + np.where(rng.random(n) < 0.2, 0.0, w)
            lo = np.where(rng.random(n) < 0.2, 0.0, lo)  # boxes with an end at 0, as the B&B makes them
            x = Iv(np.minimum(lo, hi), np.maximum(lo, hi))
            a = secant_slope(x, e, op)
            a = np.where(rng.random(n) < 0.3, a * rng.uniform(0.5, 1.5, n), a)
            D = affine_remainder(x, e, op, a)
            for i in range(n):
                L, H, A = mp.mpf(x.lo[i]), mp.mpf(x.hi[i]), mp.mpf(a[i])
                for p in (mp.mpf(e.lo), mp.mpf(e.hi)):
                    def delta(t):
                        v = abs(t) ** p if t else mp.mpf(0)
                        return (v * (1 if t >= 0 else -1) if op == "sig" else v) - A * t
                    ends = [L, H] + ([mp.mpf(0)] if L < 0 < H else [])
                    stat = []
                    if A != 0:
                        ts = (abs(A) / p) ** (1 / (p - 1))
                        signs = ([1, -1] if A > 0 else []) if op == "sig" else [1 if A > 0 else -1]
                        stat = [s * ts for s in signs if L <= s * ts <= H]
                    inner = [L + (H - L) * mp.mpf(float(t)) for t in rng.random(4)]
                    for t in ends + stat + inner:
                        assert mp.mpf(D.lo[i]) <= delta(t) <= mp.mpf(D.hi[i]), (op, float(p), i, float(t), D.lo[i], D.hi[i])
                        checked += 1
                    naive = [delta(t) for t in ends]
                    beyond += any(not (min(naive) <= delta(t) <= max(naive)) for t in stat)
    print(f"affine remainder ({op}): {checked} values enclosed; the stationary points leave the ends' hull on {beyond} intervals")
    assert beyond > 100


def test_the_reciprocal_of_a_positive_quantity_with_a_loose_lower_bound():
    """Iv.recip_pos: [1/hi, 1/lo] where lo > 0, [1/hi, inf] where the enclosure reaches 0 (the
    quantity is known to be > 0: V1 on the faces), each end outward-rounded."""
    x = Iv(np.array([0.5, 0.0, -1e-300, 3.0]), np.array([2.0, 4.0, 1e-3, 3.0]))
    r = x.recip_pos()
    assert np.all(r.lo < np.array([0.5, 0.25, 1e3, 1 / 3])) and np.all(r.lo > np.array([0.5, 0.25, 1e3, 1 / 3]) * (1 - 1e-15))
    assert r.hi[0] > 2.0 and r.hi[3] > 1 / 3 and np.isinf(r.hi[1]) and np.isinf(r.hi[2])

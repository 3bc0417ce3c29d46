"""Adversarial checks of control/interval.py, the arithmetic the certificate's bounds rest on: every
operation's result encloses the exact value (mpmath at 80 digits) at points of its argument
intervals, on random intervals mixing zeros of both signs, subnormals, the largest floats and
infinite (unbounded) ends; and the one platform assumption the power enclosure makes: np.power
(the SIMD array path and the scalar one) errs by less than the margin every power bound is widened
by (interval._POW_ULPS - 1 ulps: _dn/_up move a float at least that far)."""

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

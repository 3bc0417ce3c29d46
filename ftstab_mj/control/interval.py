"""Outward-rounded interval arithmetic over NumPy arrays, with an optional enclosure of the gradient.

``Iv(lo, hi)`` holds one interval per array element (any shape, all elements evaluated at once).
Every operation rounds its result outward: the bounds of ``+ - * /`` (correctly rounded in IEEE
754, error <= 1/2 ulp) are moved outward by d = |x| 2^-52 + 2^-1074 >= 1 ulp(x) (``round_up``/``round_down``:
the rounded x + d is at least the next float; a few array operations, half the cost of
``np.nextafter``: benchmarks/certificate_table.py --rounding). ``x ** p`` (NumPy's power, measured within 1 ulp
against mpmath on this machine's SIMD path) is moved outward by 16 ulps relative, on both paths. An exponent is
itself an interval (``Exp``): the exponents of Hong's controller are rational functions of k that a
float does not hold exactly. One power at the lower end serves the whole exponent interval:
x^p = x^p_lo x^(p - p_lo) and |ln x| <= 745 for every positive double, so the factor is within
1 +- 746 (p_hi - p_lo) (p_hi - p_lo is a few ulps of p: a relative widening of ~1e-13).

Unbounded is allowed: an infinite bound means "no bound known" (``0 * inf`` is taken as 0, the
product of 0 with an unbounded real). NaN never appears in a result.

``Dual(v, g)``: an interval ``v`` and a list of intervals ``g`` enclosing the gradient of the same
quantity over a box (forward-mode differentiation over intervals). The mean-value form
f(X) <= f(c) + sum_j max|g_j| |X_j - c_j| then tightens the bound on small boxes (second order in
the box width) where the plain interval enclosure is only first order.
"""

from __future__ import annotations

import numpy as np

_INF = np.inf


_MAX = np.finfo(float).max
_ULP = 2.0 ** -52  # >= ulp(x) / |x| for every normal x
_TINY = 2.0 ** -1074  # the ulp of the subnormals
_POW_ULPS = 16  # outward margin of every x ** p bound, in ulps: NumPy's power errs by <= 1 ulp here


def round_down(x, n=1):
    """A float <= x - n ulp(x) for n <= 2, <= x - (n - 1) ulp(x) for any n (NaN stays NaN; +inf, an
    overflow, becomes the largest float)."""
    return np.minimum(x - (np.minimum(np.abs(x), _MAX) * (n * _ULP) + n * _TINY), _MAX)


def round_up(x, n=1):
    """A float >= x + n ulp(x) for n <= 2, >= x + (n - 1) ulp(x) for any n (NaN stays NaN; -inf
    becomes minus the largest float)."""
    return np.maximum(x + (np.minimum(np.abs(x), _MAX) * (n * _ULP) + n * _TINY), -_MAX)


class Exp:
    """An exponent known to lie in [lo, hi] (floats); ``mid`` is the float a point computation uses."""

    __slots__ = ("lo", "hi", "mid")

    def __init__(self, lo, hi=None, mid=None):
        self.lo, self.hi = float(lo), float(lo if hi is None else hi)
        self.mid = float(mid) if mid is not None else 0.5 * (self.lo + self.hi)

    @classmethod
    def of(cls, iv: "Iv") -> "Exp":
        lo, hi = float(iv.lo), float(iv.hi)
        return cls(lo, hi, 0.5 * (lo + hi))

    def is_exactly(self, x: float) -> bool:
        return self.lo == x and self.hi == x

    def iv(self) -> "Iv":
        return Iv(self.lo, self.hi)


def _pow_widen(a, e: "Exp"):
    """The absolute widening that makes [a - w, a + w] hold x^p for every p in e, a = x^e.lo >= 0
    (computed; e narrow and of one sign, see _narrow)."""
    rel = _POW_ULPS * _ULP + 746.0 * (e.hi - e.lo)
    return np.minimum(a, _MAX) * rel + _POW_ULPS * _TINY


def _narrow(e: "Exp") -> bool:
    """One power serves e: a width of at most 1e-12 and no sign change (x = 0 or inf is then the
    same for every p in e)."""
    return e.hi - e.lo <= 1e-12 and (e.lo > 0 or e.hi < 0 or e.lo == e.hi)


def _pow_pos(x, e: Exp, lower: bool):
    """A bound on x ** p for every p in e, x >= 0 elementwise (lower or upper)."""
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        if not _narrow(e):  # the end points bound it (monotone in p for fixed x)
            a, b = np.power(x, e.lo), np.power(x, e.hi)
            # the same 16-ulp margin as the narrow path: libm's power is not correctly rounded (within
            # 1 ulp here), and a less accurate one elsewhere must not make the bound wrong
            return round_down(np.minimum(a, b), _POW_ULPS) if lower else round_up(np.maximum(a, b), _POW_ULPS)
        a = np.power(x, e.lo)
    w = _pow_widen(a, e)
    return np.clip(a - w, 0.0, _MAX) if lower else a + w  # an overflow's lower bound is the largest float


def _clean(lo, hi):
    return Iv(np.where(np.isnan(lo), -_INF, lo), np.where(np.isnan(hi), _INF, hi))


class Iv:
    """Intervals [lo, hi] elementwise (arrays of one shape, or scalars)."""

    __slots__ = ("lo", "hi")
    __array_ufunc__ = None  # ndarray (op) Iv defers to Iv's reflected operator

    def __init__(self, lo, hi=None):
        self.lo = np.asarray(lo, dtype=float)
        self.hi = self.lo if hi is None else np.asarray(hi, dtype=float)

    # -- helpers --------------------------------------------------------------------------------
    @staticmethod
    def lift(x) -> "Iv":
        """An Iv from an Iv or an exact float / float array (a point interval)."""
        return x if isinstance(x, Iv) else Iv(x)

    def mag(self):
        """max |x| over the interval."""
        return np.maximum(np.abs(self.lo), np.abs(self.hi))

    def mig(self):
        """min |x| over the interval."""
        return np.where((self.lo <= 0) & (self.hi >= 0), 0.0, np.minimum(np.abs(self.lo), np.abs(self.hi)))

    def mid_float(self) -> float:
        """The midpoint of a scalar interval, as a float."""
        return float(0.5 * (self.lo + self.hi))

    def __repr__(self):
        return f"Iv({self.lo!r}, {self.hi!r})"

    # -- arithmetic -----------------------------------------------------------------------------
    def __neg__(self):
        return Iv(-self.hi, -self.lo)

    def __add__(self, o):
        if isinstance(o, Dual):
            return o + self
        o = Iv.lift(o)
        return Iv(round_down(self.lo + o.lo), round_up(self.hi + o.hi))

    __radd__ = __add__

    def __sub__(self, o):
        if isinstance(o, Dual):
            return -o + self
        o = Iv.lift(o)
        return Iv(round_down(self.lo - o.hi), round_up(self.hi - o.lo))

    def __rsub__(self, o):
        return Iv.lift(o) - self

    def __mul__(self, o):
        if isinstance(o, Dual):
            return o * self
        o = Iv.lift(o)
        a = self
        if a.lo is a.hi:  # a point times an interval: two products
            a, o = o, a
        with np.errstate(invalid="ignore"):
            if o.lo is o.hi:
                p1, p2 = a.lo * o.lo, a.hi * o.lo
                if np.isnan(p1 + p2).any():
                    p1, p2 = np.where(np.isnan(p1), 0.0, p1), np.where(np.isnan(p2), 0.0, p2)
                return Iv(round_down(np.minimum(p1, p2)), round_up(np.maximum(p1, p2)))
            p = [a.lo * o.lo, a.lo * o.hi, a.hi * o.lo, a.hi * o.hi]
            if np.isnan(p[0] + p[1] + p[2] + p[3]).any():  # rare: only then look for 0 * inf
                p = [np.where(np.isnan(q), 0.0, q) for q in p]  # 0 * inf: 0 times an unbounded real
        return Iv(round_down(np.minimum(np.minimum(p[0], p[1]), np.minimum(p[2], p[3]))),
                  round_up(np.maximum(np.maximum(p[0], p[1]), np.maximum(p[2], p[3]))))

    __rmul__ = __mul__

    def recip(self):
        """1 / x; unbounded where the interval reaches 0 (only used on positive intervals)."""
        pos = self.lo > 0
        neg = self.hi < 0
        with np.errstate(divide="ignore"):
            lo = np.where(pos | neg, round_down(1.0 / np.where(pos | neg, self.hi, 1.0)), -_INF)
            hi = np.where(pos | neg, round_up(1.0 / np.where(pos | neg, self.lo, 1.0)), _INF)
        return Iv(lo, hi)

    def __truediv__(self, o):
        return self * Iv.lift(o).recip()

    def recip_pos(self):
        """1 / x for a quantity known to be > 0 whose enclosure may reach down to 0 or below (a loose
        lower bound): [1/hi, 1/lo], or [1/hi, inf] where lo <= 0 ([0, inf] where hi <= 0)."""
        with np.errstate(divide="ignore"):
            lo = np.where(self.hi > 0, round_down(1.0 / np.where(self.hi > 0, self.hi, 1.0)), 0.0)
            hi = np.where(self.lo > 0, round_up(1.0 / np.where(self.lo > 0, self.lo, 1.0)), _INF)
        return Iv(lo, hi)

    def abs(self):
        return Iv(self.mig(), self.mag())

    def sign(self):
        """sign(x): monotone, so [sign(lo), sign(hi)]."""
        return Iv(np.sign(self.lo), np.sign(self.hi))

    def sq(self):
        m, M = self.mig(), self.mag()
        return Iv(round_down(m * m), round_up(M * M))

    def pabs(self, e: Exp):
        """|x| ** p for p in e (any sign of p; |x| ** 0 = 1, also at x = 0)."""
        if e.is_exactly(1.0):
            return self.abs()
        if e.is_exactly(0.0):
            return Iv(np.ones(np.shape(self.lo)))
        m, M = self.mig(), self.mag()
        if e.lo >= 0:
            return Iv(_pow_pos(m, e, True), _pow_pos(M, e, False))
        if e.hi <= 0:  # decreasing in |x|
            return Iv(_pow_pos(M, e, True), _pow_pos(m, e, False))
        lo = np.minimum(_pow_pos(m, e, True), _pow_pos(M, e, True))
        return Iv(lo, np.maximum(_pow_pos(m, e, False), _pow_pos(M, e, False)))

    def sig(self, e: Exp):
        """sig(x, p) = |x|^p sign(x) for p in e, p > 0: increasing in x, so bounded at the ends."""
        if e.is_exactly(1.0):
            return self
        return Iv(_sig_end(self.lo, e, True), _sig_end(self.hi, e, False))

    def hull(self, o: "Iv") -> "Iv":
        return Iv(np.minimum(self.lo, o.lo), np.maximum(self.hi, o.hi))


def _sig_end(x, e: Exp, lower: bool):
    """A lower (upper) bound on sig(x, p), p in e > 0, at the array of floats x."""
    if not _narrow(e):
        ax = np.abs(x)
        return np.where(x >= 0, _pow_pos(ax, e, lower), -_pow_pos(ax, e, not lower))
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        a = np.power(np.abs(x), e.lo)
    w = _pow_widen(a, e)
    a = np.copysign(a, x)
    return np.minimum(a - w, _MAX) if lower else np.maximum(a + w, -_MAX)


class Dual:
    """An interval ``v`` with the enclosure ``g`` (list of Iv, one per box coordinate) of its gradient."""

    __slots__ = ("v", "g")
    __array_ufunc__ = None

    def __init__(self, v: Iv, g: list):
        self.v, self.g = v, g

    @staticmethod
    def lift(x, d: int) -> "Dual":
        if isinstance(x, Dual):
            return x
        return Dual(Iv.lift(x), [None] * d)  # None: a zero gradient component

    def __neg__(self):
        return Dual(-self.v, [None if g is None else -g for g in self.g])

    def __add__(self, o):
        if not isinstance(o, Dual):
            return Dual(self.v + o, self.g)
        return Dual(self.v + o.v, [grad_add(a, b) for a, b in zip(self.g, o.g)])

    __radd__ = __add__

    def __sub__(self, o):
        return self + (-o if isinstance(o, Dual) else -Iv.lift(o))

    def __rsub__(self, o):
        return (-self) + o

    def __mul__(self, o):
        if not isinstance(o, Dual):
            o = Iv.lift(o)
            return Dual(self.v * o, [None if g is None else g * o for g in self.g])
        return Dual(self.v * o.v, [grad_add(None if a is None else a * o.v, None if b is None else b * self.v)
                                   for a, b in zip(self.g, o.g)])

    __rmul__ = __mul__

    def _chain(self, v: Iv, dfdx: Iv) -> "Dual":
        return Dual(v, [None if g is None else dfdx * g for g in self.g])

    def recip(self):
        r = self.v.recip()
        return self._chain(r, -(r * r))

    def __truediv__(self, o):
        return self * (o.recip() if isinstance(o, Dual) else Iv.lift(o).recip())

    def recip_pos(self):
        r = self.v.recip_pos()
        return self._chain(r, -(r * r))

    def abs(self):
        return self._chain(self.v.abs(), self.v.sign())

    def sq(self):
        return self._chain(self.v.sq(), 2.0 * self.v)

    def pabs(self, e: Exp):
        """|x|^p: derivative p |x|^(p-1) sign(x)."""
        if e.is_exactly(0.0):
            return Dual(self.v.pabs(e), [None] * len(self.g))
        return self._chain(self.v.pabs(e), e.iv() * self.v.pabs(minus_one(e)) * self.v.sign())

    def sig(self, e: Exp):
        """sig(x, p): derivative p |x|^(p-1)."""
        if e.is_exactly(1.0):
            return self
        return self._chain(self.v.sig(e), e.iv() * self.v.pabs(minus_one(e)))


def minus_one(e: Exp) -> Exp:
    """e - 1; exact for a point exponent in [0.5, 2] (Sterbenz), outward-rounded otherwise."""
    if e.lo == e.hi and 0.5 <= e.lo <= 2.0:
        return Exp(e.lo - 1.0)
    d = Iv(e.lo, e.hi) - 1.0
    return Exp(d.lo, d.hi, e.mid - 1.0)


def grad_add(a, b):
    if a is None:
        return b
    if b is None:
        return a
    return a + b


def secant_slope(x: Iv, e: Exp, op: str):
    """The slope (phi(hi) - phi(lo)) / (hi - lo) of phi = sig(., e) (op "sig") or |.|^e (op "pabs")
    over each interval of x, in floats at e.mid; 0 where it is not a finite number (a point or an
    unbounded interval) and, for |.|^e, where the interval holds 0 (phi is not monotone there: a
    free variable, slope 0, serves as well). Any float is a valid slope for affine_remainder."""
    lo, hi = x.lo, x.hi
    with np.errstate(all="ignore"):
        if op == "sig":
            f_lo, f_hi = np.copysign(np.abs(lo) ** e.mid, lo), np.copysign(np.abs(hi) ** e.mid, hi)
        else:
            f_lo, f_hi = np.abs(lo) ** e.mid, np.abs(hi) ** e.mid
        a = (f_hi - f_lo) / (hi - lo)
    ok = np.isfinite(a) & (hi > lo)
    if op != "sig":
        ok &= (lo > 0) | (hi < 0)
    return np.where(ok, a, 0.0)


def affine_remainder(x: Iv, e: Exp, op: str, a) -> Iv:
    """An enclosure D of delta(t) = phi_p(t) - a t over every t in each interval of x and every
    exponent p in e: phi_p = sig(., p) (op "sig") or |.|^p (op "pabs"), p > 0 and e on one side of 1;
    a a float array (any slope). delta is continuous on [lo, hi] and differentiable but at t = 0, so
    its extremes lie at lo, hi, 0 or a stationary point, phi_p'(t) = a: |t| = (|a| / p)^(1/(p - 1))
    (for sig both signs, a > 0; for |.|^p the sign of a). D is the hull of delta's interval
    evaluation at the two ends, at 0 where inside, and over the enclosure of each stationary point
    (for all p in e) intersected with [lo, hi]."""
    if not (e.lo > 0 and (e.hi < 1.0 or e.lo > 1.0)):
        raise ValueError(f"affine_remainder needs an exponent in (0, 1) or (1, inf), got [{e.lo}, {e.hi}]")
    A = Iv(np.asarray(a, dtype=float))
    phi = (lambda t: t.sig(e)) if op == "sig" else (lambda t: t.pabs(e))

    def delta(t: Iv) -> Iv:
        return phi(t) - A * t

    with np.errstate(all="ignore"):
        D = delta(Iv(x.lo)).hull(delta(Iv(x.hi)))
        zero = (x.lo < 0) & (x.hi > 0)
        D = _hull_where(D, delta(Iv(np.zeros_like(x.lo))), zero)
        E = e.iv()
        power = Iv(1.0) / (E - 1.0)  # 1/(p - 1) for every p in e (one sign: e is on one side of 1)
        t = (Iv(np.abs(A.lo)) / E).pabs(Exp(float(power.lo), float(power.hi)))
        for sign, has in ((1.0, A.lo > 0), (-1.0, (A.lo > 0) if op == "sig" else (A.lo < 0))):
            tlo, thi = (t.lo, t.hi) if sign > 0 else (-t.hi, -t.lo)
            clo, chi = np.maximum(tlo, x.lo), np.minimum(thi, x.hi)
            inside = has & (clo <= chi) & np.isfinite(clo) & np.isfinite(chi)
            if inside.any():
                D = _hull_where(D, delta(Iv(np.where(inside, clo, 0.0), np.where(inside, chi, 0.0))), inside)
    return _clean(D.lo, D.hi)


def _hull_where(a: Iv, b: Iv, mask) -> Iv:
    """The hull of a and b where mask, a elsewhere."""
    return Iv(np.where(mask, np.minimum(a.lo, b.lo), a.lo), np.where(mask, np.maximum(a.hi, b.hi), a.hi))

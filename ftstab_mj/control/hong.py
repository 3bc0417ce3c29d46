"""Hong's homogeneous finite-time controller for the chain of integrators (the paper's full form and its Proposition 1, the simplified form).

Plain NumPy, vectorised over leading batch axes: a state ``z`` has shape ``(..., r)``
(``(r,)`` for one state, ``(n, r)`` for a batch) and every scalar output has shape ``(...)``.

Two forms:

* ``"full"``: the paper's eq. (Hongfunction) with the beta_i of Hong, whose V1 (eq. Lyap-Hong)
  is homogeneous of degree ``2 + k`` with weights ``p_i = 1 + (i-1) k``. Admissible ``-1/r < k <= 0``.
* ``"simplified"``: Proposition 1 (all beta_i = 1), exponents as printed: homogeneous of degree
  ``k/(1+k)`` with weights ``(1 + i k)/(1 + k)`` (not degree k); admissible ``-1/(r+1) < k <= 0``.
  Its companion ``V1 = sum (z_j - v_{j-1})^2 / 2`` is not homogeneous and not a Lyapunov function:
  a law built on this form has no proof.

``k = 0`` is accepted in both forms: it is the linear backstepping law (the tests use it).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from typing import NamedTuple

import numpy as np

from ftstab_mj.config.errors import ParameterError

FORMS = ("full", "simplified")


def sig(a, p):
    """``|a|^p sign(a)`` with ``sign(0) = 0`` (the paper's floor-ceil bracket), elementwise."""
    return np.sign(a) * np.abs(a) ** p


def _dsig(a, p):
    """d sig(a, p) / da = p |a|^(p-1); infinite at a = 0 when p < 1 (callers guard that case)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return p * np.abs(a) ** (p - 1.0)


def nested_polynomial(gains) -> np.ndarray:
    """Coefficients (highest degree first) of y^r + l_r (y^{r-1} + l_{r-1}(... + l_2 (y + l_1))).

    This is the closed-loop characteristic polynomial of the k = 0 (linear) law.
    """
    poly = np.array([1.0, float(gains[0])])  # P_1 = y + l_1
    for l_i in gains[1:]:
        poly = _shift_add(poly, float(l_i))  # P_i = y^i + l_i P_{i-1}
    return poly


def _shift_add(poly: np.ndarray, l_i: float) -> np.ndarray:
    """y^(deg+1) + l_i * poly for a polynomial of degree deg (one nesting level)."""
    out = np.zeros(len(poly) + 1)
    out[0] = 1.0
    out[1:] += l_i * poly
    return out


def gains_for_polynomial(coeffs) -> tuple[float, ...]:
    """Inverse of :func:`nested_polynomial`: the gains l_1..l_r whose nested polynomial is the given
    monic polynomial (highest degree first). Peeling one level: P_i - y^i = l_i P_{i-1}, so l_i is
    the coefficient of y^(i-1) in P_i. E.g. ``gains_for_polynomial(np.poly([-1] * r))`` places every
    linear closed-loop pole at -1. Raises ParameterError when a gain would not be positive.
    """
    poly = np.asarray(coeffs, dtype=float)
    if poly.ndim != 1 or len(poly) < 2 or poly[0] != 1.0:
        raise ParameterError("coeffs", "a monic polynomial of degree >= 1 (highest degree first)", coeffs)
    gains = []
    while len(poly) > 1:
        l_i = poly[1]
        if not l_i > 0:
            raise ParameterError("coeffs", "a polynomial with a nested form of positive gains", tuple(coeffs))
        gains.append(float(l_i))
        poly = poly[1:] / l_i  # P_{i-1}, monic
    return tuple(reversed(gains))


def is_hurwitz(gains) -> bool:
    """True when every root of :func:`nested_polynomial` has a negative real part."""
    return _is_hurwitz(tuple(float(g) for g in gains))


@lru_cache(maxsize=256)  # np.roots costs ~75 us; a sweep builds the same law 2-3 times per row (validation, run)
def _is_hurwitz(gains: tuple[float, ...]) -> bool:
    roots = np.roots(nested_polynomial(gains))
    return bool(np.all(roots.real < 0.0))


class HongOutput(NamedTuple):
    """Controller output for a state (or batch): each field has the batch shape ``(...)``."""

    u0: np.ndarray  # control of the nominal chain z_r' = u0, chain units
    V1: np.ndarray  # Lyapunov function value
    dV1_dzr: np.ndarray  # partial derivative of V1 with respect to z_r


@dataclass(frozen=True)
class HongController:
    """Hong's controller u0(z), its Lyapunov function V1(z) and dV1/dz_r(z).

    r: chain length (>= 1); k: homogeneity degree; gains: (l_1, ..., l_r) > 0; form: "full"|"simplified".
    Construction validates every parameter and raises :class:`ParameterError`.
    """

    r: int
    k: float
    gains: tuple
    form: str = "full"
    check_hurwitz: bool = True
    # Derived exponents, filled in __post_init__ (see the class docstring).
    p: np.ndarray = field(init=False, repr=False, compare=False)  # p_1..p_{r+1}, shape (r+1,)
    beta: np.ndarray = field(init=False, repr=False, compare=False)  # beta_0..beta_{r-1}, shape (r,)
    expo: np.ndarray = field(init=False, repr=False, compare=False)  # outer exponent of v_{i+1}, shape (r,)

    def __post_init__(self):
        validate_hong(self.r, self.k, self.gains, self.form, self.check_hurwitz)
        object.__setattr__(self, "gains", tuple(float(g) for g in self.gains))
        r, k = self.r, float(self.k)
        object.__setattr__(self, "k", k)
        p = 1.0 + np.arange(r + 1) * k  # p[i-1] = p_i
        if self.form == "full":
            beta = (2.0 + k) / p[:r] - 1.0  # beta_i = (beta_0 + 1)/p_{i+1} - 1, beta_0 = p_2
            alpha = p[1:] / p[:r]  # alpha_{i+1} = p_{i+2}/p_{i+1}, i = 0..r-1
            expo = alpha / beta
        else:
            beta = np.ones(r)
            i = np.arange(r)
            expo = (1.0 + (i + 2) * k) / (1.0 + (i + 1) * k)
        for name, arr in (("p", p), ("beta", beta), ("expo", expo)):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    # -- degrees of homogeneity (full form) ---------------------------------------------------
    @property
    def degree_V1(self) -> float:
        """Homogeneity degree of V1 (full form): 2 + k."""
        return 2.0 + self.k

    @property
    def degree_u0(self) -> float:
        """Homogeneity degree of u0: p_{r+1} = 1 + r k."""
        return float(self.p[self.r])

    def dilate(self, z, lam):
        """D_lam z: z_i -> lam^{p_i} z_i. z (..., r), lam broadcastable to (...)."""
        lam = np.asarray(lam, dtype=float)[..., None]
        return np.asarray(z, dtype=float) * lam ** self.p[: self.r]

    # -- evaluation ------------------------------------------------------------------------------
    def _chain(self, z):
        """Virtual controls v_0..v_r, each of shape (...): returns a list of r + 1 arrays."""
        z = np.asarray(z, dtype=float)
        if z.shape[-1:] != (self.r,):
            raise ParameterError("z", f"an array whose last axis has length r = {self.r}", z.shape)
        v = [np.zeros(z.shape[:-1])]
        for i in range(self.r):
            b, e, zi = self.beta[i], self.expo[i], z[..., i]
            s = zi - v[i] if self.form == "simplified" else sig(zi, b) - sig(v[i], b)
            v.append(-self.gains[i] * sig(s, e))
        return z, v

    def evaluate(self, z) -> HongOutput:
        """u0, V1 and dV1/dz_r at z (..., r) in one pass."""
        z, v = self._chain(z)
        V1 = np.zeros(z.shape[:-1])
        for j in range(self.r):
            V1 = V1 + _W(z[..., j], v[j], self.beta[j])
        b = self.beta[-1]
        dV = z[..., -1] - v[-2] if self.form == "simplified" else sig(z[..., -1], b) - sig(v[-2], b)
        return HongOutput(v[-1], V1, dV)

    def u0(self, z):
        """Nominal control u0 = v_r, shape (...)."""
        return self.evaluate(z).u0

    def V1(self, z):
        """Lyapunov function V1, shape (...)."""
        return self.evaluate(z).V1

    def dV1_dzr(self, z):
        """dV1/dz_r, shape (...)."""
        return self.evaluate(z).dV1_dzr

    def lie_derivative(self, z, zdot):
        """Directional derivative of V1 at z along zdot (both (..., r)): dV1/dt when z' = zdot.

        Forward-mode chain rule through the recursion of the v_i. Where an intermediate
        derivative is singular (an argument of a fractional power is exactly 0, a set of measure
        zero), the result is NaN; callers sampling random states drop those points.

        Rounding: the result is the exact dV1/dt at a state a couple of ulps from z (backward stable,
        tested against mpmath for every admissible k). Its relative error is the function's own
        conditioning: near a zero of s_i = sig(z_i, beta_{i-1}) - sig(v_{i-1}, beta_{i-1}) the two
        terms nearly cancel, and they are large where the gains span decades and beta_{i-1} grows
        as k nears -1/r. Measured, states near those zeros (moduli 1e-6..1), median / worst of 60:
        r = 3, gains 0.1 .. 1e5: 7e-15 / 5e-13 at k = -0.1/r, 8e-13 / 1e-9 at -0.7/r, 2e-11 / 6e-8 at
        -0.9/r, 3e-10 / 2e-6 at -0.99/r; r = 4, gains 1.25 .. 1e5: 2e-13 / 4e-11, 2e-10 / 7e-8,
        1e-7 / 3e-4, 4e-5 / 4e-2. Gains within a decade (1 .. 5 at r = 3): below 5e-14 for every k.
        """
        z = np.asarray(z, dtype=float)
        zdot = np.asarray(zdot, dtype=float)
        z, v = self._chain(z)
        dv = [np.zeros(z.shape[:-1])]
        with np.errstate(invalid="ignore", divide="ignore"):
            for i in range(self.r):
                b, e, zi, dzi = self.beta[i], self.expo[i], z[..., i], zdot[..., i]
                if self.form == "simplified":
                    s, ds = zi - v[i], dzi - dv[i]
                else:
                    # v_0 = 0 is constant: its term is dropped (0 * inf would be NaN when beta_0 < 1).
                    s = sig(zi, b) - sig(v[i], b)
                    ds = _dsig(zi, b) * dzi - (_dsig(v[i], b) * dv[i] if i > 0 else 0.0)
                dv.append(-self.gains[i] * _dsig(s, e) * ds)
            dV = np.zeros(z.shape[:-1])
            for j in range(self.r):
                b, zj, a = self.beta[j], z[..., j], v[j]
                dV = dV + (sig(zj, b) - sig(a, b)) * zdot[..., j]
                if j > 0:  # dW/da = -b |a|^(b-1) (z - a)
                    dV = dV - _dsig(a, b) * (zj - a) * dv[j]
        return dV

    def closed_loop_dV1dt(self, z):
        """dV1/dt along the nominal chain z_i' = z_{i+1}, z_r' = u0(z). Shape (...)."""
        z = np.asarray(z, dtype=float)
        zdot = np.concatenate([z[..., 1:], self.u0(z)[..., None]], axis=-1)
        return self.lie_derivative(z, zdot)


def _W(z, a, b):
    """W(z, a, b) = integral_a^z (sig(s,b) - sig(a,b)) ds >= 0, elementwise.

    |x|^(b+1) is taken as |x|^b |x|, the operations of the C kernel (native/laws.c hong_eval, which
    reuses the |x|^b of the recursion): the two paths then give the same V1 bit for bit. A rounding
    of V1 between them was fed back by the adaptive law (nu(V1)) and grew to 1e-7 over 10 s of a
    coupled arm, beyond `replay --verify`'s cross-path tolerance."""
    az, aa = np.abs(z), np.abs(a)
    return (az ** b * az - aa ** b * aa) / (b + 1.0) - sig(a, b) * (z - a)


def validate_hong(r, k, gains, form="full", check_hurwitz=True) -> None:
    """Raise :class:`ParameterError` unless (r, k, gains, form) define an admissible controller."""
    if form not in FORMS:
        raise ParameterError("form", "one of " + ", ".join(repr(f) for f in FORMS), form)
    if isinstance(r, bool) or not isinstance(r, (int, np.integer)) or r < 1:
        raise ParameterError("r", "an integer >= 1", r)
    try:
        k = float(k)
    except (TypeError, ValueError):
        raise ParameterError("k", "a real number", k) from None
    lo, lo_txt = (-1.0 / r, f"-1/r = {-1.0 / r:.6g}") if form == "full" else (
        -1.0 / (r + 1), f"-1/(r+1) = {-1.0 / (r + 1):.6g}")
    if not (lo < k <= 0.0) or not np.isfinite(k):
        raise ParameterError("k", f"{lo_txt} < k <= 0 for the {form} form with r = {r}", k)
    gains = tuple(gains)
    if len(gains) != r:
        raise ParameterError("gains", f"{r} gains (one per integrator, r = {r})", f"{len(gains)} gains {gains}")
    for i, g in enumerate(gains):
        if isinstance(g, bool) or not isinstance(g, (int, float, np.integer, np.floating)) or not np.isfinite(g) or g <= 0:
            raise ParameterError(f"gains[{i}] (l_{i + 1})", "a finite number > 0", g)
    with np.errstate(over="ignore"):  # an overflow is the answer here, not a warning
        finite = bool(np.all(np.isfinite(nested_polynomial(gains))))
    if check_hurwitz and not finite:  # np.roots needs finite coefficients
        raise ParameterError("gains", "gains whose products (the nested polynomial's coefficients) are below "
                             "1.8e308, the largest float", gains)
    if check_hurwitz and not is_hurwitz(gains):
        raise ParameterError(
            "gains",
            "gains whose nested polynomial y^r + l_r(y^{r-1} + ... + l_2(y + l_1)) is Hurwitz"
            + (" (for r = 3: l_3 > l_1)" if r == 3 else ""),
            gains,
        )

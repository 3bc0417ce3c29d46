"""The field's standard finite-time laws, to compare with the paper's on the same chain z_r' = phi + gamma u.

Plain NumPy, batched over leading axes like hong.py: a state ``z`` has shape ``(..., r)`` and every
scalar has shape ``(...)``. ``sig(a, p) = |a|^p sign(a)``, ``sign(0) = 0``.

Levant's r-sliding controllers (sigma = z_1, its derivatives z_2..z_r; weights r, r-1, ..., 1, so the
closed loop is homogeneous of degree -1 and, with the control held over a sampling period tau,
z_i = O(tau^(r-i+1)): Levant 2003, Int. J. Control 76(9/10):924, Theorem 5):

* nested (Levant 2003, section 4): psi_0 = z_1, psi_i = z_{i+1} + beta_i N_i sign(psi_{i-1}),
  u = -alpha sign(psi_{r-1}), with N_i = (sum_{j=1..i} |z_j|^(q/(r-j+1)))^((r-i)/q). We use q = 6
  (r = 3) and q = 12 (r = 4), beta = (1,), (1, 2), (1, 2, 3) after the paper's list:
    r = 2: u = -alpha sign(z_2 + |z_1|^(1/2) sign z_1)
    r = 3: u = -alpha sign(z_3 + 2 (|z_2|^3 + |z_1|^2)^(1/6) sign(z_2 + |z_1|^(2/3) sign z_1))
    r = 4: u = -alpha sign(z_4 + 3 (z_3^6 + z_2^4 + |z_1|^3)^(1/12)
                               sign(z_3 + (z_2^4 + |z_1|^3)^(1/6) sign(z_2 + 0.5 |z_1|^(3/4) sign z_1)))
  (r = 4's innermost coefficient is Levant's 0.5; beta = (0.5, 1, 3) for r = 4.)
* quasi-continuous (Levant 2005, IEEE TAC 50(11):1812, section III): phi_0 = z_1, N_0 = |z_1|,
  Psi_i = phi_i / N_i, phi_i = z_{i+1} + beta_i N_{i-1}^((r-i)/(r-i+1)) Psi_{i-1},
  N_i = |z_{i+1}| + beta_i N_{i-1}^((r-i)/(r-i+1)), u = -alpha Psi_{r-1}, with Psi = 0 where N = 0
  (the controller is continuous except at the origin). beta = (1,), (1, 2), (0.5, 1, 3): e.g.
    r = 2: u = -alpha (z_2 + |z_1|^(1/2) sign z_1) / (|z_2| + |z_1|^(1/2))
    r = 3: u = -alpha [z_3 + 2 (|z_2| + |z_1|^(2/3))^(-1/2) (z_2 + |z_1|^(2/3) sign z_1)]
               / [|z_3| + 2 (|z_2| + |z_1|^(2/3))^(1/2)]
  Both need alpha large enough for the bounds (alpha gamma_m > phibar plus the law's own margin;
  Levant gives no closed form for it, so it is a tuning parameter).

First-order sliding surface s = z_r + sum_{i<r} c_i z_i (``surface`` = (c_1, ..., c_{r-1})). Its known
drift a(z) = sum_{i<r} c_i z_{i+1} is cancelled, u = -a(z) + w, so that with gamma = 1 the surface
sees s' = phi + w exactly (with gamma != 1 the residual (gamma - 1) u adds to the disturbance; on
s = 0 the reduced chain has the characteristic polynomial y^(r-1) + c_{r-1} y^(r-2) + ... + c_1):

* super-twisting (Levant 1993; gains after Levant 1998): w = -k1 sig(s, 1/2) + v, v' = -k2 sign s.
  For |phi'| <= L the usual tuning is k1 = 1.5 sqrt(L), k2 = 1.1 L (the defaults when only L is
  given); s and s' then vanish in finite time (Moreno & Osorio 2012, IEEE TAC 57(4):1035, give a
  strict Lyapunov function and a time estimate that need the unknown phi, so none is logged).
* adaptive first-order sliding mode (Plestan, Shtessel, Bregeault, Poznyak 2010, Int. J. Control
  83(9):1907, eq. (8)): w = -K sign s, K' = Kbar |s| sign(|s| - eps) when K > mu, K' = mu otherwise
  (mu > 0 keeps K positive). K grows until |s| < eps, then decreases, so K tracks the disturbance.

Linear state feedback: u = -(a_r z_1 + a_{r-1} z_2 + ... + a_1 z_r), with y^r + a_1 y^(r-1) + ... + a_r
the monic polynomial of the given closed-loop poles. It is Hong's law at k = 0 with the gains
``gains_for_polynomial(np.poly(poles))`` (hong.py). Its quadratic Lyapunov function V = z^T P z,
A^T P + P A = -I for the closed-loop companion matrix A, is logged as V1.

Discretization (``discretization = "explicit" | "implicit"``) of the discontinuous term of the
first-order surface laws: explicit evaluates sign(s_k) at the sample; implicit (Acary & Brogliato
2010, Systems & Control Letters 59:284) takes it at the predicted next value s_{k+1} = s_k + h w
(zero-order hold, phi unknown so taken as 0) and solves the inclusion exactly (ftstab_mj.control.implicit).

Every law returns a :class:`~ftstab_mj.control.laws.LawOutput`; its fields read, for these laws:
u the control; u0 the continuous part (Levant: the degree-0 function Psi in [-1, 1], u = alpha u0);
V1, dV1_dzr the law's own Lyapunov function and its partial in z_r where it has one (linear:
z^T P z; surface laws: s^2/2 and s, the reaching function, no certificate), NaN otherwise;
gamma_hat the gain multiplying u0 (Levant alpha, otherwise 1); phi_hat the law's own state
(super-twisting v, Plestan K; 0 when it has none). A law's own state is advanced once per control
period by :meth:`advance` (the derivative held over the period, as u is), never inside ``output``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ftstab_mj.control import implicit
from ftstab_mj.control.hong import sig
from ftstab_mj.control.laws import LawOutput
from ftstab_mj.errors import ParameterError

DISCRETIZATIONS = ("explicit", "implicit")
LEVANT_ORDERS = (1, 2, 3, 4)
# Levant's coefficients beta_1..beta_{r-1} (2003 nested list, 2005 quasi-continuous list) and the
# nested q (any q > 0 gives a homogeneous law; these reproduce the published formulas).
LEVANT_BETA = {1: (), 2: (1.0,), 3: (1.0, 2.0), 4: (0.5, 1.0, 3.0)}
NESTED_Q = {1: 1.0, 2: 2.0, 3: 6.0, 4: 12.0}


def _number(name, value, check, text):
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    if not (ok and np.isfinite(value) and check(value)):
        raise ParameterError(name, text, value)
    return float(value)


def _positive(name, value):
    return _number(name, value, lambda v: v > 0, "a finite number > 0")


def _order(r, allowed=None):
    if isinstance(r, bool) or not isinstance(r, (int, np.integer)) or r < 1 or (allowed and r not in allowed):
        raise ParameterError("r", "an integer in " + ", ".join(map(str, allowed)) if allowed else "an integer >= 1", r)
    return int(r)


def _z(z, r):
    z = np.asarray(z, dtype=float)
    if z.shape[-1:] != (r,):
        raise ParameterError("z", f"an array whose last axis has length r = {r}", z.shape)
    return z


def _nan_like(a):
    return np.full(np.shape(a), np.nan)


# -- Levant's r-sliding controllers ---------------------------------------------------------------

@dataclass(frozen=True)
class _Levant:
    """What both Levant controllers share: r in 1..4, gain alpha > 0, u = alpha u0 with u0 = -psi(z)."""

    r: int
    alpha: float

    def __post_init__(self):
        object.__setattr__(self, "r", _order(self.r, LEVANT_ORDERS))
        object.__setattr__(self, "alpha", _positive("alpha", self.alpha))

    def output(self, z, state=0.0) -> LawOutput:
        u0 = -self.psi(z)
        nan = _nan_like(u0)
        return LawOutput(self.alpha * u0, u0, nan, nan, np.full(np.shape(u0), self.alpha), np.zeros(np.shape(u0)))

    def advance(self, z, state, h):
        """No state of its own: zeros of the batch shape."""
        return np.zeros(np.shape(z)[:-1])


@dataclass(frozen=True)
class LevantNested(_Levant):
    """Levant's nested r-sliding controller, u = -alpha sign(psi_{r-1}(z)) (module docstring); r in 1..4."""

    name = "levant_nested"

    def psi(self, z):
        """sign(psi_{r-1}(z)) in {-1, 0, 1}, shape (...)."""
        z = _z(z, self.r)
        r, q, beta = self.r, NESTED_Q[self.r], LEVANT_BETA[self.r]
        a = np.abs(z)
        psi = z[..., 0]
        acc = np.zeros(z.shape[:-1])  # sum_{j<=i} |z_j|^(q/(r-j+1))
        for i in range(1, r):
            acc = acc + a[..., i - 1] ** (q / (r - i + 1))
            psi = z[..., i] + beta[i - 1] * acc ** ((r - i) / q) * np.sign(psi)
        return np.sign(psi)


@dataclass(frozen=True)
class LevantQuasiContinuous(_Levant):
    """Levant's quasi-continuous r-sliding controller, u = -alpha Psi_{r-1}(z) (module docstring); r in 1..4."""

    name = "levant_qc"

    def psi(self, z):
        """Psi_{r-1}(z) in [-1, 1], 0 where its denominator vanishes, shape (...)."""
        z = _z(z, self.r)
        r, beta = self.r, LEVANT_BETA[self.r]
        phi = z[..., 0]
        N = np.abs(phi)
        Psi = np.sign(phi)  # phi_0 / N_0, 0 at N_0 = 0
        for i in range(1, r):
            term = beta[i - 1] * N ** ((r - i) / (r - i + 1))
            phi = z[..., i] + term * Psi
            N = np.abs(z[..., i]) + term
            with np.errstate(invalid="ignore", divide="ignore"):
                Psi = np.where(N > 0.0, phi / np.where(N > 0.0, N, 1.0), 0.0)
        return Psi


# -- first-order sliding surface laws --------------------------------------------------------------

def _surface(surface, r):
    c = tuple(surface)
    if len(c) != r - 1:
        raise ParameterError("surface", f"{r - 1} coefficients c_1..c_{r - 1} of s = z_r + sum c_i z_i", c)
    c = tuple(_positive(f"surface[{i}] (c_{i + 1})", v) for i, v in enumerate(c))
    if r > 1:  # on s = 0 the reduced chain has polynomial y^(r-1) + c_{r-1} y^(r-2) + ... + c_1
        roots = np.roots(np.r_[1.0, c[::-1]])
        if not np.all(roots.real < 0.0):
            raise ParameterError("surface", "coefficients whose polynomial y^(r-1) + c_{r-1} y^(r-2) + ... + c_1 "
                                 "is Hurwitz (the motion on s = 0 must be stable)", c)
    return c


def _discretization(d):
    if d not in DISCRETIZATIONS:
        raise ParameterError("discretization", "one of " + ", ".join(repr(x) for x in DISCRETIZATIONS), d)
    return d


@dataclass(frozen=True)
class SlidingSurface:
    """s = z_r + sum c_i z_i and its known drift a(z) = sum c_i z_{i+1}; c = (c_1, ..., c_{r-1})."""

    r: int
    c: tuple

    def __post_init__(self):
        object.__setattr__(self, "r", _order(self.r))
        object.__setattr__(self, "c", _surface(self.c, self.r))

    def value(self, z):
        """(s, a): the sliding variable and its drift, each (...)."""
        z = _z(z, self.r)
        c = np.asarray(self.c)
        s = z[..., -1] + z[..., :-1] @ c if self.r > 1 else z[..., 0]
        a = z[..., 1:] @ c if self.r > 1 else np.zeros(z.shape[:-1])
        return s, a


def _surface_output(u, u0, s, state) -> LawOutput:
    one = np.ones(np.shape(u))
    return LawOutput(u, u0, 0.5 * s * s, s, one, np.broadcast_to(np.asarray(state, dtype=float), np.shape(u)) + 0.0)


@dataclass(frozen=True)
class SuperTwisting:
    """Super-twisting on a first-order surface: u = -a(z) - k1 sig(s, 1/2) + v, v' = -k2 sign s.

    State: v (chain units of z_r', m/s^r), v(0) = 0. implicit needs ``period`` (s): the discrete law
    of Brogliato, Polyakov & Efimov 2020 (implicit.super_twisting_step). Use :meth:`from_bound` for
    the default gains from |phi'| <= L.
    """

    r: int
    surface: tuple
    k1: float
    k2: float
    discretization: str = "explicit"
    period: float | None = None
    name = "super_twisting"
    _s: SlidingSurface = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        object.__setattr__(self, "_s", SlidingSurface(self.r, self.surface))
        object.__setattr__(self, "surface", self._s.c)
        object.__setattr__(self, "r", self._s.r)
        for name in ("k1", "k2"):
            object.__setattr__(self, name, _positive(name, getattr(self, name)))
        _discretization(self.discretization)
        if self.discretization == "implicit":
            object.__setattr__(self, "period", _positive("period", self.period))

    @classmethod
    def from_bound(cls, r, surface, L, **kw):
        """The usual gains for |phi'| <= L: k1 = 1.5 sqrt(L), k2 = 1.1 L."""
        L = _positive("L", L)
        return cls(r, surface, 1.5 * np.sqrt(L), 1.1 * L, **kw)

    def _step(self, z, v):
        """(u, u0, s, v_next) for one period from the sample z with state v."""
        s, a = self._s.value(z)
        v = np.asarray(v, dtype=float)
        if self.discretization == "implicit":
            w, v_next = implicit.super_twisting_step(s, v, self.k1, self.k2, self.period)
            return -a + w, -a + w - v_next, s, v_next  # w = -k1 sig(s_{k+1}, 1/2) + v_{k+1}
        u0 = -a - self.k1 * sig(s, 0.5)
        return u0 + v, u0, s, None

    def output(self, z, state=0.0) -> LawOutput:
        u, u0, s, _ = self._step(z, state)
        return _surface_output(u, u0, s, state)

    def advance(self, z, state, h):
        """v after one period h: explicit v - h k2 sign(s_k) (exact with sign held); implicit the
        solution of the one-step inclusion."""
        u, u0, s, v_next = self._step(z, state)
        if v_next is not None:
            return v_next
        return np.asarray(state, dtype=float) - h * self.k2 * np.sign(s)


@dataclass(frozen=True)
class PlestanAdaptive:
    """Plestan et al. 2010 adaptive sliding mode: u = -a(z) - K sign s, K' = Kbar |s| sign(|s| - eps)
    if K > mu else mu. State: K (chain units of z_r'), K(0) = ``K0`` (default mu).

    implicit needs ``period`` (s): w = -proj_[-K, K](s / h) (implicit.sign_step)."""

    r: int
    surface: tuple
    Kbar: float
    mu: float
    eps: float
    K0: float | None = None
    discretization: str = "explicit"
    period: float | None = None
    name = "plestan_adaptive"
    _s: SlidingSurface = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        object.__setattr__(self, "_s", SlidingSurface(self.r, self.surface))
        object.__setattr__(self, "surface", self._s.c)
        object.__setattr__(self, "r", self._s.r)
        for name in ("Kbar", "mu", "eps"):
            object.__setattr__(self, name, _positive(name, getattr(self, name)))
        K0 = self.mu if self.K0 is None else self.K0
        object.__setattr__(self, "K0", _positive("K0", K0))
        _discretization(self.discretization)
        if self.discretization == "implicit":
            object.__setattr__(self, "period", _positive("period", self.period))

    def output(self, z, state=None) -> LawOutput:
        K = np.asarray(self.K0 if state is None else state, dtype=float)
        s, a = self._s.value(z)
        if self.discretization == "implicit":
            w = implicit.sign_step(s, 0.0, K, self.period)
        else:
            w = -K * np.sign(s)
        return _surface_output(-a + w, -a, s, K)

    def state_derivative(self, z, K):
        """K' = Kbar |s| sign(|s| - eps) where K > mu, mu elsewhere; shape (...)."""
        s, _ = self._s.value(z)
        K = np.asarray(K, dtype=float)
        return np.where(K > self.mu, self.Kbar * np.abs(s) * np.sign(np.abs(s) - self.eps), self.mu)

    def advance(self, z, state, h):
        """K after one period h with K' held at its value at the sample (explicit Euler of Plestan's law)."""
        return np.asarray(state, dtype=float) + h * self.state_derivative(z, state)


# -- linear state feedback --------------------------------------------------------------------------

def _lyapunov(A):
    """P with A^T P + P A = -I (A Hurwitz, small): the Kronecker form solved directly."""
    n = A.shape[0]
    eye = np.eye(n)
    M = np.kron(eye, A.T) + np.kron(A.T, eye)
    P = np.linalg.solve(M, -eye.reshape(-1)).reshape(n, n)
    return 0.5 * (P + P.T)


@dataclass(frozen=True)
class LinearLaw:
    """u = -K z with the closed-loop poles ``poles`` (real, < 0; s^-1) on the nominal chain z_r' = u.

    K = (a_r, ..., a_1) from the monic polynomial prod (y - p_i) = y^r + a_1 y^(r-1) + ... + a_r.
    V1 = z^T P z (A^T P + P A = -I), dV1_dzr = 2 (P z)_r.
    """

    poles: tuple
    name = "linear"
    K: np.ndarray = field(init=False, repr=False, compare=False)
    P: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        poles = tuple(self.poles)
        if not poles:
            raise ParameterError("poles", "one closed-loop pole per integrator", poles)
        poles = tuple(_number(f"poles[{i}]", p, lambda v: v < 0, "a finite real number < 0 (s^-1)")
                      for i, p in enumerate(poles))
        object.__setattr__(self, "poles", poles)
        coeffs = np.real(np.poly(poles))  # [1, a_1, ..., a_r]
        K = coeffs[1:][::-1].copy()  # (a_r, ..., a_1): the weight of z_1 first
        r = len(poles)
        A = np.zeros((r, r))
        A[np.arange(r - 1), np.arange(1, r)] = 1.0
        A[-1] = -K
        for name, arr in (("K", K), ("P", _lyapunov(A))):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @property
    def r(self) -> int:
        return len(self.poles)

    def output(self, z, state=0.0) -> LawOutput:
        z = _z(z, self.r)
        u = -(z @ self.K)
        Pz = z @ self.P
        one = np.ones(np.shape(u))
        return LawOutput(u, u, np.sum(z * Pz, axis=-1), 2.0 * Pz[..., -1], one, 0.0 * one)

    def advance(self, z, state, h):
        """No state of its own: zeros of the batch shape."""
        return np.zeros(np.shape(z)[:-1])

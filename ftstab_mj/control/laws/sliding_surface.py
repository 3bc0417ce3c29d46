"""First-order sliding-surface laws, registered as "super_twisting" and "plestan_adaptive".

Surface s = z_r + sum_{i<r} c_i z_i (``surface`` = (c_1, ..., c_{r-1}); the polynomial
y^(r-1) + c_{r-1} y^(r-2) + ... + c_1 must be Hurwitz, it is the motion on s = 0). Its known drift
a(z) = sum_{i<r} c_i z_{i+1} is cancelled, u = -a(z) + w, so that with gamma = 1 the surface obeys
s' = phi + w exactly. With a gain gamma(t) in [gamma_m, gamma_M], s' = phi + (1 - gamma) a(z) + gamma w:
the smooth part phi + (1 - gamma) a is the disturbance (its derivative carries phi', gamma' a and the
c_i z_{i+2} terms of a', bounded on a compact set), while gamma multiplies w and so scales the gains.
(gamma - 1) w is NOT a disturbance term: its derivative holds |s|^(-1/2) s', unbounded near s = 0.

* super-twisting (Levant 1993, IJC 58(6):1247; Moreno & Osorio 2012, IEEE TAC 57(4):1035):
  w = -k1 sig(s, 1/2) + v, v' = -k2 sign s. Gain conditions used, for s'' = C(t) + gamma(t) w' with
  |C| <= L, 0 < gamma_m <= gamma <= gamma_M:
  - Levant's sufficient condition: k2 > L / gamma_m and
    k1^2 >= 4 L gamma_M (k2 + L) / (gamma_m^2 (k2 - L));
  - Moreno & Osorio's strict Lyapunov function (quadratic in (sig(s, 1/2), v - the disturbance)),
    gamma = 1: finite-time convergence when k1 > 2 sqrt(L) and k2 > k1 (5 L k1 + 4 L^2) / (2 k1^2 - 8 L);
  - the field's usual tuning k1 = 1.5 sqrt(L), k2 = 1.1 L (Levant 1998, Automatica 34(3):379: the
    defaults when only ``L`` is given) meets neither sufficient condition (Levant's needs k1 >= 9.2
    sqrt(L) at k2 = 1.1 L, Moreno-Osorio's k1 > 2 sqrt(L)): it is validated by simulation, and no
    time bound is claimed for this law. With gamma != 1 divide L by gamma_m (Levant's condition).
  s and s' then vanish in finite time, and with
  sampling |s| = O(h^2). State (v,), v(0) = 0; v tends to -phi, so phi_hat = -v is logged as the
  disturbance estimate. Moreno & Osorio's strict Lyapunov function needs the unknown phi: none is
  logged (V1 = NaN).
* adaptive sliding mode (Plestan, Shtessel, Bregeault & Poznyak 2010, Int. J. Control 83(9):1907):
  w = -K sign s, K' = Kbar |s| sign(|s| - eps) if K > mu, K' = mu otherwise: K grows while
  |s| > eps until it dominates the disturbance, then decreases, so |s| stays O(eps) with a K that
  tracks the disturbance. State (K,), K(0) = mu; phi_hat = K is logged (the disturbance-bound
  estimate). K' is held over the period (explicit Euler of the paper's law).

``discretization`` of the discontinuous term (control/implicit.py): "explicit" evaluates sign(s_k);
"implicit" takes the set-valued sign at the predicted s_{k+1} = s_k + h w (phi left out) and solves
the one-step inclusion exactly (Acary & Brogliato 2010; for super-twisting Brogliato, Polyakov &
Efimov 2020), so u follows the equivalent control -a(z) - phi without numerical chattering.
u0 is NaN (no nominal part), gamma_hat = 1 (the laws assume a unit gain).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ftstab_mj.control import implicit
from ftstab_mj.control.hong import sig
from ftstab_mj.control.law import Law, LawOutput, Param, positive, register_law
from ftstab_mj.control.laws.paper import EPS
from ftstab_mj.config.errors import ParameterError


def _positive(name, value):
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) or not (
            np.isfinite(value) and value > 0):
        raise ParameterError(name, "a finite number > 0", value)
    return float(value)


def _all_positive(v):
    return None if all(c > 0 for c in v) else "coefficients c_1..c_{r-1} > 0"


SURFACE = Param("surface", tuple[float, ...], "coefficients c_1..c_{r-1} of s = z_r + sum c_i z_i", "1/s^(r-i)",
                _all_positive)


def surface_coefficients(surface, r) -> tuple:
    """Validated (c_1, ..., c_{r-1}): r - 1 numbers > 0 whose polynomial y^(r-1) + c_{r-1} y^(r-2) + ... + c_1 is Hurwitz."""
    c = tuple(surface)
    if len(c) != r - 1:
        raise ParameterError("surface", f"{r - 1} coefficients c_1..c_{r - 1} of s = z_r + sum c_i z_i (r = {r})", c)
    c = tuple(_positive(f"surface[{i}]", v) for i, v in enumerate(c))
    if r > 2 and not np.all(np.roots(np.r_[1.0, c[::-1]]).real < 0.0):
        raise ParameterError("surface", "coefficients whose polynomial y^(r-1) + c_{r-1} y^(r-2) + ... + c_1 is "
                             "Hurwitz (the motion on s = 0 must be stable)", c)
    return c


@dataclass(frozen=True)
class _SurfaceLaw(Law):
    """A law on s = z_r + sum c_i z_i with one state; ``period`` is set by :meth:`for_period`."""

    r: int
    surface: tuple
    discretization: str = "explicit"
    period: float | None = None

    def _check(self):
        if isinstance(self.r, bool) or not isinstance(self.r, (int, np.integer)) or self.r < 1:
            raise ParameterError("r", "an integer >= 1", self.r)
        object.__setattr__(self, "surface", surface_coefficients(self.surface, self.r))
        implicit.check_discretization(self.discretization)
        if self.period is not None:
            object.__setattr__(self, "period", _positive("period", self.period))

    def for_period(self, h):
        return replace(self, period=h)

    def sliding_variable(self, z):
        """(s, a): the sliding variable and its known drift, each (...)."""
        z = np.asarray(z, dtype=float)
        if z.shape[-1:] != (self.r,):
            raise ParameterError("z", f"an array whose last axis has length r = {self.r}", z.shape)
        c = np.asarray(self.surface)
        if self.r == 1:
            return z[..., 0], np.zeros(z.shape[:-1])
        return z[..., -1] + z[..., :-1] @ c, z[..., 1:] @ c

    def _implicit_period(self):
        if self.period is None:
            raise ParameterError("period", "the control period (the implicit discretization needs it: for_period(h))",
                                 None)
        return self.period

    @property
    def state_size(self) -> int:
        return 1

    def param_values(self) -> dict:
        return {p.name: getattr(self, p.name) for p in self.params if hasattr(self, p.name)}


@register_law
@dataclass(frozen=True)
class SuperTwisting(_SurfaceLaw):
    """u = -a(z) - k1 sig(s, 1/2) + v, v' = -k2 sign s (module docstring). State (v,)."""

    k1: float = 0.0
    k2: float = 0.0
    name = "super_twisting"
    native_code = 6
    summary = ("super-twisting on s = z_r + sum c_i z_i, u = -k1 |s|^(1/2) sign s + v, v' = -k2 sign s "
               "(Levant 1993; Moreno-Osorio 2012)")
    params = (
        SURFACE,
        Param("k1", float, "gain of -k1 |s|^(1/2) sign s (default 1.5 sqrt(L))", "chain units", positive, default=None),
        Param("k2", float, "gain of v' = -k2 sign s (default 1.1 L)", "chain units per s", positive, default=None),
        Param("L", float, "bound on |phi'| giving the default gains", "chain units per s", positive, default=None),
        implicit.DISCRETIZATION,
    )

    def __post_init__(self):
        self._check()
        for name in ("k1", "k2"):
            object.__setattr__(self, name, _positive(name, getattr(self, name)))

    @classmethod
    def from_bound(cls, r, surface, L, **kw):
        """The usual gains for |phi'| <= L: k1 = 1.5 sqrt(L), k2 = 1.1 L."""
        L = _positive("L", L)
        return cls(r, surface, k1=1.5 * np.sqrt(L), k2=1.1 * L, **kw)

    @classmethod
    def from_params(cls, r, values):
        k1, k2, L = values.get("k1"), values.get("k2"), values.get("L")
        if L is not None:
            if k1 is not None or k2 is not None:
                raise ParameterError("L", "either L (default gains) or k1 and k2, not both", L)
            return cls.from_bound(r, values["surface"], L, discretization=values["discretization"])
        if k1 is None or k2 is None:
            raise ParameterError("k1" if k1 is None else "k2", "k1 and k2, or L for the default gains", None)
        return cls(r, values["surface"], values["discretization"], k1=k1, k2=k2)

    def _step(self, z, v):
        """(u, s, v_next or None) for one period from the sample z with v."""
        s, a = self.sliding_variable(z)
        if self.discretization == "implicit":
            w, v_next = implicit.super_twisting_step(s, v, self.k1, self.k2, self._implicit_period())
            return -a + w, s, v_next
        return -a - self.k1 * sig(s, 0.5) + v, s, None

    def evaluate(self, z, state) -> LawOutput:
        v = np.asarray(state, dtype=float)[..., 0]
        u = self._step(z, v)[0]
        nan = np.full(np.shape(u), np.nan)
        return LawOutput(u, nan, nan, nan, np.ones(np.shape(u)), -v + 0.0 * u)

    def state_derivative(self, z, state, out):
        s, _ = self.sliding_variable(z)
        return (-self.k2 * np.sign(s))[..., None]

    def advance(self, z, state, out, h):
        """v one period later: explicit v - h k2 sign(s_k) (exact with the sign held), implicit the
        inclusion's solution."""
        v = np.asarray(state, dtype=float)[..., 0]
        _, s, v_next = self._step(z, v)
        if v_next is None:
            v_next = v - h * self.k2 * np.sign(s)
        return v_next[..., None]

    def param_values(self) -> dict:
        return {"surface": list(self.surface), "k1": self.k1, "k2": self.k2, "discretization": self.discretization}

    def native_params(self) -> dict:
        return {"par": (self.k1, self.k2, *self.surface)}


@register_law
@dataclass(frozen=True)
class PlestanAdaptive(_SurfaceLaw):
    """u = -a(z) - K sign s, K' = Kbar |s| sign(|s| - eps) if K > mu else mu (module docstring). State (K,)."""

    Kbar: float = 0.0
    mu: float = 0.0
    eps: float = 0.0
    name = "plestan_adaptive"
    native_code = 7
    summary = ("adaptive sliding mode on s = z_r + sum c_i z_i, u = -K sign s, K' = Kbar |s| sign(|s| - eps) "
               "(Plestan et al. 2010, IJC 83:1907)")
    params = (
        SURFACE,
        Param("Kbar", float, "adaptation gain of K", "1/s per unit of s", positive),
        Param("mu", float, "floor of K (K' = mu while K <= mu; K(0) = mu)", "chain units", positive),
        EPS,
        implicit.DISCRETIZATION,
    )

    def __post_init__(self):
        self._check()
        for name in ("Kbar", "mu", "eps"):
            object.__setattr__(self, name, _positive(name, getattr(self, name)))

    @classmethod
    def from_params(cls, r, values):
        return cls(r, values["surface"], values["discretization"], Kbar=values["Kbar"], mu=values["mu"],
                   eps=values["eps"])

    def initial_state(self):
        return np.array([self.mu])

    def evaluate(self, z, state) -> LawOutput:
        K = np.asarray(state, dtype=float)[..., 0]
        s, a = self.sliding_variable(z)
        if self.discretization == "implicit":
            w = implicit.sign_step(s, 0.0, K, self._implicit_period())
        else:
            w = -K * np.sign(s)
        u = -a + w
        nan = np.full(np.shape(u), np.nan)
        return LawOutput(u, nan, nan, nan, np.ones(np.shape(u)), K + 0.0 * u)

    def state_derivative(self, z, state, out):
        """K' = Kbar |s| sign(|s| - eps) where K > mu, mu elsewhere; shape (..., 1)."""
        s, _ = self.sliding_variable(z)
        K = np.asarray(state, dtype=float)[..., 0]
        return np.where(K > self.mu, self.Kbar * np.abs(s) * np.sign(np.abs(s) - self.eps), self.mu)[..., None]

    def param_values(self) -> dict:
        return {"surface": list(self.surface), "Kbar": self.Kbar, "mu": self.mu, "eps": self.eps,
                "discretization": self.discretization}

    def native_params(self) -> dict:
        return {"par": (self.Kbar, self.mu, self.eps, *self.surface)}

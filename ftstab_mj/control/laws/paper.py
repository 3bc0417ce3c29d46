"""The paper's three laws on the perturbed chain z_r' = phi + gamma u (Harmouche, Laghrouche, Chitour).

Registered as "nominal", "robust" and "adaptive" (protocol: ftstab_mj/control/law.py). Each is built
on Hong's homogeneous controller (k, gains, form: :class:`HongController`), which gives u0, the
Lyapunov function V1 and dV1/dz_r. All three share one structure, u = gamma_hat * u0 + phi_hat * sign(u0):

* nominal (Hong alone):     gamma_hat = 1,              phi_hat = 0
* robust (Theorem 2):       gamma_hat = 1 / gamma_m,    phi_hat = phibar / gamma_m   (constants)
* adaptive (Theorem 3):     gamma_hat = kappa + delta |u0|,  phi_hat is a state with
  phi_hat' = rate nu_eps(V1) - (1 - nu_eps(V1)) sig(phi_hat, eta)

so the logged gamma_hat / phi_hat mean the same thing for every law. Only the adaptive law has a
state (phi_hat, state_size 1); :meth:`AdaptiveLaw.phi_hat_rate` is phi_hat' and
:func:`advance_phi_hat` integrates it over a control period with V1 held, keeping phi_hat >= 0.
``output(z, phi_hat)`` is the maths API with a scalar phi_hat (...) (the ideal chain and the C twin
use it); ``evaluate(z, state)`` is the protocol's, with state (..., state_size).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ftstab_mj.control import implicit
from ftstab_mj.control.hong import HongController
from ftstab_mj.control.law import (COMPUTED, Law, LawOutput, Param, non_negative, one_of, open_unit_interval, positive,
                                   register_law)
from ftstab_mj.config.errors import ParameterError



def bound(check):
    """A robust bound: a number passing ``check``, or the word "computed"."""
    def check_bound(v):
        if isinstance(v, str):
            return None if v == COMPUTED else f'a number or "{COMPUTED}"'
        return check(v)
    return check_bound


# Shared with plestan_adaptive (one key, one meaning: the dead zone of an adaptation).
EPS = Param("eps", float, "adaptation dead zone: adaptive, the V1 level below which phi_hat decays; "
            "plestan_adaptive, the |s| level below which K decreases", "units of V1 (adaptive), of s (plestan_adaptive)",
            positive)

# Hong's controller, the base of the three laws (LoopInfo.hong).
HONG_PARAMS = (
    Param("k", float, "k: the full form's homogeneity degree, -1/r < k <= 0; the simplified form's degree is k/(1+k), -1/(r+1) < k <= 0", "dimensionless"),
    # l_i: at k = 0 the roots' scale of the nested polynomial, 1/s; at k < 0 the law is not dimensionally
    # homogeneous and l_i carries powers of the z_1 unit and of s set by k, i and the form (full form: l_1 in m^-k/s).
    Param("gains", tuple[float, ...], "Hong's gains l_1..l_r > 0 (Hurwitz nested polynomial)",
          "1/s at k = 0; at k < 0, m^a s^b with a, b set by k, i and the form (rad for m on a hinge)"),
    Param("form", str, "Hong's controller form: full (degree k, weights 1 + (i-1) k) | simplified (Proposition 1 "
          "as printed: degree k/(1+k), weights (1 + i k)/(1 + k); V1 not a Lyapunov function, no proof)",
          check=one_of("full", "simplified"), default="full"),
)


class _HongLaw(Law):
    """A law built on Hong's controller: r, V1 and dV1/dz_r come from ``self.hong``."""

    base_params = HONG_PARAMS
    lyapunov = True
    hong: HongController

    @property
    def r(self) -> int:
        return self.hong.r

    @classmethod
    def from_params(cls, r, values):
        hong = HongController(r, values["k"], values["gains"], form=values["form"])
        return cls(hong, **{p.name: values[p.name] for p in cls.params})

    def base_info(self) -> dict:
        h = self.hong
        return {"r": h.r, "k": h.k, "gains": list(h.gains), "form": h.form}

    def native_params(self) -> dict:
        """Hong's controller (exponents as HongController computed them) and the law's own parameters,
        by their names in the kernel's record."""
        h = self.hong
        own = {k: v for k, v in self.param_values().items() if k != "discretization"}  # the record's `implicit`
        return {"simplified": int(h.form == "simplified"), "gains": h.gains, "beta": h.beta, "expo": h.expo, **own}

    def evaluate(self, z, state) -> LawOutput:
        return self.output(z)


def _positive(name, value, allow_zero=False):
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    ok = ok and np.isfinite(value) and (value >= 0 if allow_zero else value > 0)
    if not ok:
        raise ParameterError(name, "a finite number " + (">= 0" if allow_zero else "> 0"), value)
    return float(value)


@register_law
@dataclass(frozen=True)
class NominalLaw(_HongLaw):
    """u = u0: Hong's controller alone, for the unperturbed chain."""

    name = "nominal"
    summary = "Hong's homogeneous controller alone, u = u0 (the paper, Theorem 1)"
    native_code = 0
    time_bound = u_bound_from_V1 = True
    u_continuous = True  # u0 is continuous (Hong 2002)
    hong: HongController

    @classmethod
    def bound_holds(cls, params, phibar, gamma_m, gamma_M):
        """Theorem 1 is for the unperturbed chain: no disturbance and gamma = 1."""
        return phibar == 0.0 and gamma_m == 1.0 and gamma_M == 1.0

    def output(self, z, phi_hat=0.0) -> LawOutput:
        u0, V1, dV = self.hong.evaluate(z)
        one = np.ones_like(u0)
        return LawOutput(u0, u0, V1, dV, one, 0.0 * one)


@register_law
@dataclass(frozen=True)
class RobustLaw(_HongLaw):
    """Theorem 2: u = (u0 + phibar sign(u0)) / gamma_m, for known bounds |phi| <= phibar, gamma >= gamma_m.

    discretization "implicit" (control/implicit.py): the sign term -P sign(sigma), P = phibar / gamma_m,
    sigma = z_r - v_{r-1}(z) (sign(u0) = -sign(sigma)), is taken at the predicted next sample,
    w = -proj_[-P, P]((sigma + h u0) / (h gamma_m)), u = u0 / gamma_m + w; it needs the control
    period h (``period``, set by :meth:`for_period`).
    """

    name = "robust"
    summary = "Hong's controller with known bounds, u = (u0 + phibar sign(u0)) / gamma_m (Theorem 2)"
    params = (
        Param("phibar", float | str, 'assumed bound on |phi|, or "computed"', "chain units, m/s^r or rad/s^2",
              bound(non_negative), plant_bound="phibar"),
        Param("gamma_m", float | str, 'assumed lower bound on gamma, or "computed"', "chain units",
              bound(positive), plant_bound="gamma_m"),
        implicit.DISCRETIZATION,
    )
    native_code = 1
    time_bound = u_bound_from_V1 = True
    hong: HongController
    phibar: float
    gamma_m: float

    @classmethod
    def bound_holds(cls, params, phibar, gamma_m, gamma_M):
        """Theorem 2: the true bounds are within the assumed ones."""
        return phibar <= params["phibar"] and gamma_m >= params["gamma_m"]
    discretization: str = "explicit"
    period: float | None = None

    def __post_init__(self):
        object.__setattr__(self, "phibar", _positive("phibar", self.phibar, allow_zero=True))
        object.__setattr__(self, "gamma_m", _positive("gamma_m", self.gamma_m))
        implicit.check_discretization(self.discretization)
        if self.period is not None:
            object.__setattr__(self, "period", _positive("period", self.period))

    def for_period(self, h):
        return replace(self, period=h) if self.discretization == "implicit" else self

    def output(self, z, phi_hat=0.0) -> LawOutput:
        u0, V1, dV = self.hong.evaluate(z)
        g_hat = np.full_like(u0, 1.0 / self.gamma_m)
        p_hat = np.full_like(u0, self.phibar / self.gamma_m)
        if self.discretization == "implicit":
            if self.period is None:
                raise ParameterError("period", "the control period (implicit discretization: for_period(h))", None)
            z, v = self.hong._chain(z)
            w = implicit.sign_step(z[..., -1] - v[-2], u0, p_hat, self.period, self.gamma_m)
            return LawOutput(g_hat * u0 + w, u0, V1, dV, g_hat, p_hat)
        return LawOutput(g_hat * u0 + p_hat * np.sign(u0), u0, V1, dV, g_hat, p_hat)


@register_law
@dataclass(frozen=True)
class AdaptiveLaw(_HongLaw):
    """Theorem 3: u = gamma_hat u0 + phi_hat sign(u0), with bounds unknown to the controller.

    kappa, delta > 0 (gamma_hat = kappa + delta |u0|); rate > 0 (the paper's adaptation rate 'k');
    eta in (0, 1); eps > 0 (the V1 level below which phi_hat decays). State: (phi_hat,).
    """

    name = "adaptive"
    summary = "Hong's controller with adapted gains, u = (kappa + delta |u0|) u0 + phi_hat sign(u0) (Theorem 3)"
    params = (
        Param("kappa", float, "gamma_hat = kappa + delta |u0|", "units of u per chain unit of u0 (m/s^r or rad/s^r)",
              positive),
        Param("delta", float, "gamma_hat = kappa + delta |u0|", "units of kappa per chain unit of u0", positive),
        Param("rate", float, "growth rate of phi_hat (the paper's 'k')", "chain units per s", positive),
        Param("eta", float, "decay exponent of phi_hat", "dimensionless", open_unit_interval),
        EPS,
    )
    native_code = 2
    hong: HongController
    kappa: float
    delta: float
    rate: float
    eta: float
    eps: float

    def __post_init__(self):
        for name in ("kappa", "delta", "rate", "eps"):
            object.__setattr__(self, name, _positive(name, getattr(self, name)))
        eta = self.eta
        if isinstance(eta, bool) or not isinstance(eta, (int, float, np.integer, np.floating)) or not (0.0 < eta < 1.0):
            raise ParameterError("eta", "a number in the open interval (0, 1)", eta)
        object.__setattr__(self, "eta", float(eta))

    def output(self, z, phi_hat) -> LawOutput:
        u0, V1, dV = self.hong.evaluate(z)
        g_hat = self.kappa + self.delta * np.abs(u0)
        p_hat = np.broadcast_to(np.asarray(phi_hat, dtype=float), u0.shape)
        return LawOutput(g_hat * u0 + p_hat * np.sign(u0), u0, V1, dV, g_hat, p_hat)

    @classmethod
    def ultimate_bound(cls, params):
        """Theorem 3's constants: its ultimate bounds hold for any true bounds (with a certificate)."""
        return {key: params[key] for key in ("kappa", "delta", "rate", "eps")}

    def nu(self, V1):
        """nu_eps(V1) = 0.5 + 0.5 sat((|V1| - 0.75 eps) / (0.25 eps)), in [0, 1]."""
        x = (np.abs(V1) - 0.75 * self.eps) / (0.25 * self.eps)
        return 0.5 + 0.5 * x / np.maximum(1.0, np.abs(x))

    def phi_hat_rate(self, V1, phi_hat):
        """phi_hat' = rate nu - (1 - nu) sig(phi_hat, eta), shape of the broadcast of V1 and phi_hat."""
        nu = self.nu(V1)
        return self.rate * nu - (1.0 - nu) * np.sign(phi_hat) * np.abs(phi_hat) ** self.eta

    # -- the protocol: state (..., 1) = phi_hat ---------------------------------------------------
    @property
    def state_size(self) -> int:
        return 1

    def evaluate(self, z, state) -> LawOutput:
        return self.output(z, state[..., 0])

    def state_derivative(self, z, state, out):
        return self.phi_hat_rate(out.V1, state[..., 0])[..., None]

    def advance(self, z, state, out, h):
        return advance_phi_hat(self, out.V1, state[..., 0], h)[..., None]


def advance_phi_hat(law, V1, phi_hat, h, substeps: int = 8):
    """Integrate phi_hat over a period h with V1 held (zero-order hold); result >= 0. Shapes (...).

    With V1 held, nu is constant and the ODE phi' = a - b phi^eta (a = rate nu, b = 1 - nu) is
    solved exactly where it has a closed form: b = 0 (ramp) and a = 0 (finite-time decay
    phi(t+h) = max(0, phi^(1-eta) - (1-eta) h)^(1/(1-eta))). In the transition band
    (0 < nu < 1) a > 0 keeps phi >= 0 and phi relaxes monotonically towards (a/b)^(1/eta); there
    RK4 with ``substeps`` sub-steps is used, clipped at 0 as a guard.
    """
    if not isinstance(law, AdaptiveLaw):
        return np.asarray(phi_hat, dtype=float) + 0.0
    V1, phi = np.broadcast_arrays(np.asarray(V1, dtype=float), np.maximum(np.asarray(phi_hat, dtype=float), 0.0))
    nu = law.nu(V1)
    eta = law.eta
    ramp = phi + law.rate * h
    # np.power, not **: np.maximum returns a NumPy scalar for one state (the run loop's Python path),
    # whose ** is libm's pow, not correctly rounded at 2.0 (eta = 0.5), where the ufunc and laws.c square
    decay = np.power(np.maximum(0.0, phi ** (1.0 - eta) - (1.0 - eta) * h), 1.0 / (1.0 - eta))
    out = np.where(nu >= 1.0, ramp, decay)
    band = (nu > 0.0) & (nu < 1.0)
    if np.any(band):
        a, b, x = law.rate * nu[band], 1.0 - nu[band], phi[band]
        dt = h / substeps

        def f(y):
            return a - b * np.maximum(y, 0.0) ** eta

        for _ in range(substeps):
            k1 = f(x)
            k2 = f(x + 0.5 * dt * k1)
            k3 = f(x + 0.5 * dt * k2)
            k4 = f(x + dt * k3)
            x = np.maximum(0.0, x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4))
        out = np.array(out, copy=True)
        out[band] = x
    return out

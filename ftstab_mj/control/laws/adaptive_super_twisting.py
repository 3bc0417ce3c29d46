"""Adaptive-gain super-twisting, registered as "adaptive_super_twisting".

Shtessel, Taleb and Plestan, "A novel adaptive-gain supertwisting sliding mode controller:
methodology and application", Automatica 48(5):759-769, 2012 (the controller and its gain adaptation;
equation numbers not quoted here). On the surface s = z_r + sum_{i<r} c_i z_i (as for "super_twisting": the known drift
a(z) = sum c_i z_{i+1} is cancelled, u = -a(z) + w):

    w  = -alpha sig(s, 1/2) + v,      v' = -beta sign(s),      beta = 2 epsilon alpha
    alpha' = omega1 sqrt(gamma1 / 2) sign(|s| - mu)   if alpha > alpha_m
           = eta_floor                                 if alpha <= alpha_m

The gains grow while |s| > mu until they dominate the disturbance's derivative (which the controller
does not know), the 2-sliding mode is then established (in real sliding, |s| of the order of mu)
and the gains decrease again, so they follow the disturbance instead of its worst case (Shtessel et
al. 2012: the adapted gains stay bounded and s, s' reach a neighbourhood of 0 in finite time). Sampled,
alpha falls as soon as |s| < mu, until the 2-sliding mode is lost and |s| grows again: the gains
oscillate (measured on the cart of scenarios/compare/field_r2.toml: final |z_1| 2e-3 m at 0.5 ms,
1.2e-2 m at 1 ms, 1.8e-5 m at 4 ms, where |s| rarely drops below mu).
Gain uncertainty gamma != 1 joins the disturbance as for super-twisting.

State (v, alpha), v(0) = 0, alpha(0) = ``alpha0`` (``alpha_min`` by default). v tends to -phi, so
phi_hat = -v is logged as the disturbance estimate (as "super_twisting"); gamma_hat = 1; no Lyapunov
function is logged. :meth:`AdaptiveSuperTwisting.advance` holds sign(s) over the period: alpha moves
by h alpha' (clipped at 0), and v by -2 epsilon sign(s) times the integral of alpha, the trapezoid,
exact since alpha is linear over the period.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ftstab_mj.control.hong import sig
from ftstab_mj.control.law import Law, LawOutput, Param, positive, register_law
from ftstab_mj.control.laws.sliding_surface import SURFACE, surface_coefficients
from ftstab_mj.control.laws.terminal import positive_number
from ftstab_mj.config.errors import ParameterError


def sliding_variable(surface, z):
    """(s, a) on s = z_r + sum c_i z_i: the sliding variable and its known drift a = sum c_i z_{i+1}."""
    r = len(surface) + 1
    z = np.asarray(z, dtype=float)
    if z.shape[-1:] != (r,):
        raise ParameterError("z", f"an array whose last axis has length r = {r}", z.shape)
    if r == 1:
        return z[..., 0], np.zeros(z.shape[:-1])
    c = np.asarray(surface)
    return z[..., -1] + z[..., :-1] @ c, z[..., 1:] @ c


@register_law
@dataclass(frozen=True)
class AdaptiveSuperTwisting(Law):
    """Shtessel, Taleb & Plestan's adaptive-gain super-twisting on s = z_r + sum c_i z_i. State (v, alpha)."""

    r: int
    surface: tuple
    omega1: float
    gamma1: float
    mu_band: float
    alpha_min: float
    epsilon: float
    eta_floor: float = 0.01
    alpha0: float | None = None
    u_continuous = True  # -alpha |s|^(1/2) sign s + v, v integrates the relay: continuous
    name = "adaptive_super_twisting"
    native_code = 12
    summary = ("super-twisting with adapted gains, alpha' = omega1 sqrt(gamma1/2) sign(|s| - mu), beta = 2 epsilon alpha "
               "(Shtessel, Taleb, Plestan 2012, Automatica 48:759)")
    params = (
        SURFACE,
        Param("omega1", float, "adaptation rate factor: alpha' = omega1 sqrt(gamma1/2) sign(|s| - mu_band)", "units of alpha", positive),
        Param("gamma1", float, "adaptation rate factor (see omega1)", "1/s^2", positive),
        Param("mu_band", float, "the |s| level below which the gains decrease (the paper's mu)", "units of s", positive),
        Param("alpha_min", float, "floor of alpha: below it alpha' = eta_floor (the paper's alpha_m)", "chain units per (units of s)^(1/2)", positive),
        Param("epsilon", float, "beta = 2 epsilon alpha", "(units of s)^(1/2) per s", positive),
        Param("eta_floor", float, "alpha' while alpha <= alpha_min (the paper's eta)", "units of alpha per s", positive,
              default=0.01),
        Param("alpha0", float, "alpha(0) (default alpha_min)", "units of alpha", positive, default=None),
    )

    def __post_init__(self):
        object.__setattr__(self, "surface", surface_coefficients(self.surface, self.r))
        for name in ("omega1", "gamma1", "mu_band", "alpha_min", "epsilon", "eta_floor"):
            object.__setattr__(self, name, positive_number(name, getattr(self, name)))
        object.__setattr__(self, "alpha0", self.alpha_min if self.alpha0 is None
                           else positive_number("alpha0", self.alpha0))

    @classmethod
    def from_params(cls, r, values):
        return cls(r, values["surface"], **{p.name: values[p.name] for p in cls.params[1:]})

    @property
    def state_size(self) -> int:
        return 2

    def initial_state(self):
        return np.array([0.0, self.alpha0])

    def evaluate(self, z, state) -> LawOutput:
        state = np.asarray(state, dtype=float)
        v, alpha = state[..., 0], state[..., 1]
        s, a = sliding_variable(self.surface, z)
        u = -a - alpha * sig(s, 0.5) + v
        nan = np.full(np.shape(u), np.nan)
        return LawOutput(u, nan, nan, nan, np.ones(np.shape(u)), -v + 0.0 * u)

    def alpha_rate(self, s, alpha):
        """alpha' (the adaptation law of the module docstring), shape of the broadcast of s and alpha."""
        grow = self.omega1 * np.sqrt(self.gamma1 / 2.0) * np.sign(np.abs(s) - self.mu_band)
        return np.where(alpha > self.alpha_min, grow, self.eta_floor)

    def state_derivative(self, z, state, out):
        state = np.asarray(state, dtype=float)
        s, _ = sliding_variable(self.surface, z)
        alpha = state[..., 1]
        return np.stack([-2.0 * self.epsilon * alpha * np.sign(s), self.alpha_rate(s, alpha)], axis=-1)

    def advance(self, z, state, out, h):
        state = np.asarray(state, dtype=float)
        v, alpha = state[..., 0], state[..., 1]
        s, _ = sliding_variable(self.surface, z)
        alpha_next = np.maximum(alpha + h * self.alpha_rate(s, alpha), 0.0)
        v_next = v - 2.0 * self.epsilon * np.sign(s) * 0.5 * h * (alpha + alpha_next)
        return np.stack([v_next, alpha_next], axis=-1)

    def param_values(self) -> dict:
        return {"surface": list(self.surface), **{p.name: getattr(self, p.name) for p in self.params[1:]}}

    def native_params(self) -> dict:
        return {"par": (self.omega1, self.gamma1, self.mu_band, self.alpha_min, self.epsilon, self.eta_floor,
                        *self.surface)}

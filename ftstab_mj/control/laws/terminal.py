"""Nonsingular terminal sliding mode (r = 2), registered as "terminal".

Feng, Yu and Man, "Non-singular terminal sliding mode control of rigid manipulators", Automatica
38(12):2159-2167, 2002 (the surface, the control and the sliding time below; their equation numbers
are not quoted here). For
x_1' = x_2, x_2' = f + b u they take the surface and the control

    s = x_1 + (1 / beta) x_2^(p/q),          p, q odd, 1 < p/q < 2
    u = -b^-1 (f + beta (q/p) x_2^(2 - p/q) + (eta + l) sign s)

Here f = 0 and b = 1 (the nominal chain z_2' = phi + gamma u); x^(p/q) with p, q odd is
sig(x, p/q) = |x|^(p/q) sign x, which is how it is computed (any ratio 1 < p/q < 2 is accepted):

    s = z_1 + sig(z_2, p/q) / beta,     u = -beta (q/p) sig(z_2, 2 - p/q) - switching sign(s).

With gamma = 1: s' = (p/q) |z_2|^(p/q - 1) (phi - switching sign s) / beta, so s s' < 0 where
z_2 != 0 when switching > |phi| (``switching`` is the paper's eta + l); the exponent 2 - p/q is in
(0, 1), so u stays bounded (the "nonsingular" of the title: the classical TSM s = z_1 + sig(z_2,...)
needs |z_1|^(q/p - 1) z_2, unbounded at z_1 = 0). Gain uncertainty gamma != 1 adds (gamma - 1) u to the
disturbance: switching must cover it too. z_2 = 0 with s != 0 is not an attractor (z_2' = phi -
switching sign s != 0), so s = 0 is reached in finite time. On s = 0, z_2 = -sig(beta z_1, q/p) and
z_1 reaches 0 in

    t_s = p / (beta^(q/p) (p - q)) |z_1(t_r)|^(1 - q/p)       (:meth:`Terminal.sliding_time`)

after the reaching time t_r. No Lyapunov function is logged; no state.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ftstab_mj.control.hong import sig
from ftstab_mj.control.law import Law, LawOutput, Param, positive, register_law
from ftstab_mj.config.errors import ParameterError

# Shared by the laws with a discontinuous term -switching sign(s) (terminal, fixed_time, integral_hosm).
SWITCHING = Param("switching", float, "gain of the discontinuous term -switching sign(s); must exceed the "
                  "disturbance (and gain-error) bound", "chain units, m/s^r or rad/s^r", positive)


def _ratio(v):
    return None if 1.0 < v < 2.0 else "a number in the open interval (1, 2)"


def positive_number(name, value):
    """``value`` as a float when it is a finite number > 0, else ParameterError naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) or not (
            np.isfinite(value) and value > 0):
        raise ParameterError(name, "a finite number > 0", value)
    return float(value)


def chain_state(z, r):
    z = np.asarray(z, dtype=float)
    if z.shape[-1:] != (r,):
        raise ParameterError("z", f"an array whose last axis has length r = {r}", z.shape)
    return z


@register_law
@dataclass(frozen=True)
class Terminal(Law):
    """Feng, Yu & Man's nonsingular terminal sliding mode on the double integrator (module docstring)."""

    r: int
    beta: float
    ratio: float
    switching: float
    name = "terminal"
    native_code = 9
    summary = ("nonsingular terminal sliding mode, s = z_1 + |z_2|^(p/q) sign(z_2) / beta, r = 2 "
               "(Feng, Yu, Man 2002, Automatica 38:2159)")
    params = (
        Param("beta", float, "terminal surface coefficient: s = z_1 + sig(z_2, p/q) / beta", "(m/s)^(p/q) per m", positive),
        Param("ratio", float, "terminal exponent p/q of the surface, 1 < p/q < 2", "dimensionless", _ratio),
        SWITCHING,
    )

    def __post_init__(self):
        if isinstance(self.r, bool) or not isinstance(self.r, (int, np.integer)) or self.r != 2:
            raise ParameterError("r", "2 (Feng et al.'s surface is for second-order systems)", self.r)
        object.__setattr__(self, "beta", positive_number("beta", self.beta))
        object.__setattr__(self, "switching", positive_number("switching", self.switching))
        ratio = positive_number("ratio", self.ratio)
        if not 1.0 < ratio < 2.0:
            raise ParameterError("ratio", "a number in the open interval (1, 2)", ratio)
        object.__setattr__(self, "ratio", ratio)

    @classmethod
    def from_params(cls, r, values):
        return cls(r, values["beta"], values["ratio"], values["switching"])

    def surface(self, z):
        z = chain_state(z, 2)
        return z[..., 0] + sig(z[..., 1], self.ratio) / self.beta

    def native_params(self) -> dict:
        return {"par": (self.beta, self.ratio, self.switching)}

    def evaluate(self, z, state=None) -> LawOutput:
        z = chain_state(z, 2)
        s = self.surface(z)
        u = -self.beta / self.ratio * sig(z[..., 1], 2.0 - self.ratio) - self.switching * np.sign(s)
        nan = np.full(np.shape(u), np.nan)
        return LawOutput(u, nan, nan, nan, nan, nan)

    def sliding_time(self, z1):
        """t_s: the time from a point on s = 0 with first coordinate z1 to the origin (Feng et al. 2002), s."""
        e = 1.0 / self.ratio  # q/p
        return np.abs(z1) ** (1.0 - e) / (self.beta ** e * (1.0 - e))

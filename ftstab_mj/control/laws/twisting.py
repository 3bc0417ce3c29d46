"""The twisting algorithm (r = 2), registered as "twisting".

u = -r1 sign(z_1) - r2 sign(z_2),  r1 > r2 > 0
(Levantovsky 1985; Levant 1993, "Sliding order and sliding accuracy in sliding mode control",
Int. J. Control 58(6):1247-1263, the twisting algorithm and its convergence conditions; also
Shtessel, Edwards, Fridman, Levant, "Sliding Mode Control and Observation", Birkhauser 2014, ch. 4).
Equation and section numbers are not quoted here: check them against the papers.

Gain condition. On z_1'' = phi + gamma u with |phi| <= C and 0 < Km <= gamma <= KM, the origin is
reached in finite time when

    (r1 - r2) Km > C   and   (r1 + r2) Km - C > (r1 - r2) KM + C        (Levant 1993)

(:meth:`Twisting.gain_condition`). The first makes z_1 turn back towards 0, the second makes every
half-turn around the origin contract.

Finite-time bound (the majorant curve of Levant 1993, written out here). Let c = (r1 - r2) Km - C,
b = (r1 - r2) KM + C and a = (r1 + r2) Km - C. From (x, 0), x > 0 (the case x < 0 is symmetric):
while z_1 > 0 > z_2, z_2' is in [-b, -c], so z_1 reaches 0 within sqrt(2 x / c) and then
z_2^2 <= 2 b x; while z_1 < 0 and z_2 < 0, z_2' >= a, so z_2 returns to 0 within |z_2| / a and
|z_1| <= z_2^2 / (2 a) <= (b / a) x there. Each half-turn thus lasts at most
K sqrt(x), K = sqrt(2 / c) + sqrt(2 b) / a, and multiplies |z_1| on the z_1 axis by at most q = b / a < 1:

    T(x) <= K sqrt(x) / (1 - sqrt(q))       (:meth:`Twisting.time_bound`, from z(0) = (x, 0)).

Sampling: the closed loop is homogeneous of degree -1 with weights (2, 1), so with u held over a
period h, |z_1| = O(h^2) and |z_2| = O(h) (Levant 1993; Levant 2003, IJC 76:924, Theorem 5).

No Lyapunov function is logged (V1, dV1_dzr, u0, gamma_hat, phi_hat are NaN); no state.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ftstab_mj.control.law import Law, LawOutput, Param, positive, register_law
from ftstab_mj.config.errors import ParameterError


def _number(name, value):
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) or not (
            np.isfinite(value) and value > 0):
        raise ParameterError(name, "a finite number > 0", value)
    return float(value)


@register_law
@dataclass(frozen=True)
class Twisting(Law):
    """u = -r1 sign(z_1) - r2 sign(z_2) on the double integrator (module docstring). No state."""

    r: int
    r1: float
    r2: float
    name = "twisting"
    native_code = 8
    summary = "twisting algorithm, u = -r1 sign(z_1) - r2 sign(z_2), r1 > r2 > 0, r = 2 (Levant 1993, IJC 58:1247)"
    params = (
        Param("r1", float, "twisting gain on sign(z_1), r1 > r2", "chain units, m/s^2 or rad/s^2", positive),
        Param("r2", float, "twisting gain on sign(z_2), 0 < r2 < r1", "chain units, m/s^2 or rad/s^2", positive),
    )

    def __post_init__(self):
        if isinstance(self.r, bool) or not isinstance(self.r, (int, np.integer)) or self.r != 2:
            raise ParameterError("r", "2 (the twisting algorithm is a second-order sliding controller)", self.r)
        r1, r2 = _number("r1", self.r1), _number("r2", self.r2)
        if not r2 < r1:
            raise ParameterError("r2", f"a number < r1 = {r1}", r2)
        object.__setattr__(self, "r1", r1)
        object.__setattr__(self, "r2", r2)

    @classmethod
    def from_params(cls, r, values):
        return cls(r, values["r1"], values["r2"])

    def native_params(self) -> dict:
        return {"par": (self.r1, self.r2)}

    def evaluate(self, z, state=None) -> LawOutput:
        z = np.asarray(z, dtype=float)
        if z.shape[-1:] != (2,):
            raise ParameterError("z", "an array whose last axis has length r = 2", z.shape)
        u = -self.r1 * np.sign(z[..., 0]) - self.r2 * np.sign(z[..., 1])
        nan = np.full(np.shape(u), np.nan)
        return LawOutput(u, nan, nan, nan, nan, nan)

    def gain_condition(self, C: float, Km: float, KM: float) -> bool:
        """Levant 1993's sufficient condition for |phi| <= C, Km <= gamma <= KM."""
        r1, r2 = self.r1, self.r2
        return (r1 - r2) * Km > C and (r1 + r2) * Km - C > (r1 - r2) * KM + C

    def time_bound(self, x0: float, C: float, Km: float, KM: float) -> float:
        """Upper bound on the time to reach the origin from z(0) = (x0, 0) (module docstring), s;
        inf when the gain condition fails."""
        if not self.gain_condition(C, Km, KM):
            return float("inf")
        r1, r2 = self.r1, self.r2
        c, b, a = (r1 - r2) * Km - C, (r1 - r2) * KM + C, (r1 + r2) * Km - C
        K = np.sqrt(2.0 / c) + np.sqrt(2.0 * b) / a
        return float(K * np.sqrt(abs(x0)) / (1.0 - np.sqrt(b / a)))

"""A law of your own, as a plugin: Bhat and Bernstein's finite-time controller of the double integrator.

    u = -k1 |z1|^(1/3) sign(z1) - k2 |z2|^(1/2) sign(z2)

(S. P. Bhat, D. S. Bernstein, "Continuous finite-time stabilization of the translational and rotational
double integrators", IEEE TAC 43(5):678-682, 1998: exponents a2 in (0, 1) and a1 = a2 / (2 - a2), here
a2 = 1/2.) A scenario names this file in `plugins = ["my_laws.py"]` and uses `law = "bhat_bernstein"`.
"""

from dataclasses import dataclass

import numpy as np

from ftstab_mj.control import Law, LawOutput, Param, register_law
from ftstab_mj.control.law import positive


def sig(x, a):
    """|x|^a sign(x)."""
    return np.sign(x) * np.abs(x) ** a


@register_law
@dataclass(frozen=True)
class BhatBernstein(Law):
    name = "bhat_bernstein"  # the scenario's `law = "bhat_bernstein"`
    summary = "u = -k1 sig(z1)^(1/3) - k2 sig(z2)^(1/2), r = 2 (Bhat, Bernstein 1998, IEEE TAC 43:678)"
    params = (Param("k1", float, "gain on sig(z1)^(1/3)", "m^(2/3)/s^2 (rad^(2/3)/s^2 on a hinge)", positive),
              Param("k2", float, "gain on sig(z2)^(1/2)", "m^(1/2)/s^(3/2) (rad^(1/2)/s^(3/2) on a hinge)", positive))
    r: int
    k1: float
    k2: float

    @classmethod
    def from_params(cls, r, values):  # values: every declared Param, defaults filled
        if r != 2:
            from ftstab_mj.config.errors import ParameterError

            raise ParameterError("law", "a plant of relative degree 2 for bhat_bernstein", f"r = {r}")
        return cls(r, float(values["k1"]), float(values["k2"]))

    def evaluate(self, z, state):  # z: (..., 2) in chain units
        z = np.asarray(z, dtype=float)
        u = -self.k1 * sig(z[..., 0], 1 / 3) - self.k2 * sig(z[..., 1], 1 / 2)
        nan = np.full_like(u, np.nan)  # no u0, no Lyapunov function, no estimates
        return LawOutput(u, nan, nan, nan, nan, nan)

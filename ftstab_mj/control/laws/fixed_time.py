"""A nonsingular sliding mode with a fixed-time sliding surface (r = 2), registered as "fixed_time".

The settling-time bound is Polyakov's (A. Polyakov, "Nonlinear feedback design for fixed-time
stabilization of linear control systems", IEEE TAC 57(8):2106-2110, 2012, Lemma 1): if
V' <= -(a V^p + b V^q)^k with a, b, k > 0, pk < 1 < qk, the origin is reached within
1 / (a^k (1 - pk)) + 1 / (b^k (qk - 1)) whatever the initial state. The surface is built so that the
motion on it is the scalar fixed-time system of that lemma, and made nonsingular as Feng, Yu and Man
(Automatica 38:2159, 2002) make the terminal surface nonsingular: z_1 is written as a function of
z_2, not the converse. (Polyakov's own chain controller, built on an implicit Lyapunov function
and an LMI, is not this law.)

With Psi(w) = a sig(w, 2/3) + b sig(w, 4/3) (odd, increasing) and G = Psi^-1, which has a closed
form (x = |w|^(1/3) solves a x^2 + b x^4 = |z_2|):

    G(z_2) = sign(z_2) X^(3/2),  X = 2 |z_2| / (a + sqrt(a^2 + 4 b |z_2|))
    s = z_1 + G(z_2)
    u = -n(z_2) - switching sign(s),  n(z_2) = Psi'(G(z_2)) z_2
      = (2a/3) sign(z_2) sqrt(|z_2| (a + sqrt(a^2 + 4 b |z_2|)) / 2) + (4b/3) z_2 sqrt(X)

n is continuous and n(0) = 0 (it grows like |z_2|^(1/2) near 0: the exponent 2/3 > 1/2 is Feng's
condition p/q < 2), so u is bounded on bounded sets. With gamma = 1,
s' = G'(z_2) (phi - switching sign s), G' = 1 / Psi'(G) > 0: s s' < 0 while switching > |phi|, and
z_2 = 0 with s != 0 is not an attractor (z_2' = phi - switching sign s), so s = 0 is reached in
finite time. On s = 0, z_2 = -Psi(z_1): z_1' = -a sig(z_1, 2/3) - b sig(z_1, 4/3), Polyakov's
lemma with V = |z_1|, k = 1, p = 2/3, q = 4/3, and exactly (x = V^(1/3), dV = 3 x^2 dx)

    T(z_1) = 3 / sqrt(ab) arctan(sqrt(b/a) |z_1|^(1/3)) < 3 pi / (2 sqrt(ab)) <= 3/a + 3/b

(:meth:`FixedTime.sliding_time`, :meth:`FixedTime.sliding_time_bound`; 3 pi / (2 sqrt(ab)) is the least
bound of this class, Aldana-Lopez et al. 2019, and 3/a + 3/b Polyakov's). What is fixed-time is the
motion on the surface: the reaching phase is finite-time but its duration grows with the initial
state (the term -n(z_2) is a damping; far from the surface z_1' is O(switching^(4/5))). Gain
uncertainty gamma != 1 adds (gamma - 1) u to the disturbance: ``switching`` must cover it.
No Lyapunov function is logged; no state.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ftstab_mj.control.law import Law, LawOutput, Param, positive, register_law
from ftstab_mj.control.laws.terminal import SWITCHING, chain_state, positive_number
from ftstab_mj.config.errors import ParameterError


@register_law
@dataclass(frozen=True)
class FixedTime(Law):
    """u = -Psi'(G(z_2)) z_2 - switching sign(z_1 + G(z_2)), G = Psi^-1 (module docstring)."""

    r: int
    ft_a: float
    ft_b: float
    switching: float
    name = "fixed_time"
    native_code = 10
    summary = ("nonsingular sliding mode with a fixed-time surface, z_1' = -a |z_1|^(2/3) - b |z_1|^(4/3) on it, r = 2; "
               "bound 3 pi / (2 sqrt(ab)) (Polyakov 2012, IEEE TAC 57:2106, Lemma 1)")
    params = (
        Param("ft_a", float, "fixed-time surface: z_1' = -ft_a sig(z_1, 2/3) - ft_b sig(z_1, 4/3) on s = 0",
              "m^(1/3)/s", positive),
        Param("ft_b", float, "fixed-time surface: the coefficient of sig(z_1, 4/3) (see ft_a)", "m^(-1/3)/s", positive),
        SWITCHING,
    )

    def __post_init__(self):
        if isinstance(self.r, bool) or not isinstance(self.r, (int, np.integer)) or self.r != 2:
            raise ParameterError("r", "2 (the fixed-time surface is for the double integrator)", self.r)
        for name in ("ft_a", "ft_b", "switching"):
            object.__setattr__(self, name, positive_number(name, getattr(self, name)))

    @classmethod
    def from_params(cls, r, values):
        return cls(r, values["ft_a"], values["ft_b"], values["switching"])

    def _X(self, z2):
        """X = |G(z_2)|^(2/3), the root of a X + b X^2 = |z_2| that is >= 0, and R = sqrt(a^2 + 4 b |z_2|)."""
        a, b = self.ft_a, self.ft_b
        R = np.sqrt(a * a + 4.0 * b * np.abs(z2))
        return 2.0 * np.abs(z2) / (a + R), R

    def inverse(self, z2):
        """G(z_2) = Psi^-1(z_2), shape of z2."""
        X, _ = self._X(z2)
        return np.sign(z2) * X ** 1.5

    def surface(self, z):
        z = chain_state(z, 2)
        return z[..., 0] + self.inverse(z[..., 1])

    def native_params(self) -> dict:
        return {"par": (self.ft_a, self.ft_b, self.switching)}

    def evaluate(self, z, state=None) -> LawOutput:
        z = chain_state(z, 2)
        z2 = z[..., 1]
        X, R = self._X(z2)
        n = (2.0 * self.ft_a / 3.0) * np.sign(z2) * np.sqrt(np.abs(z2) * (self.ft_a + R) / 2.0) \
            + (4.0 * self.ft_b / 3.0) * z2 * np.sqrt(X)
        u = -n - self.switching * np.sign(z[..., 0] + np.sign(z2) * X ** 1.5)
        nan = np.full(np.shape(u), np.nan)
        return LawOutput(u, nan, nan, nan, nan, nan)

    def sliding_time(self, z1):
        """The exact time from a point of s = 0 with first coordinate z1 to the origin, s."""
        a, b = self.ft_a, self.ft_b
        return 3.0 / np.sqrt(a * b) * np.arctan(np.sqrt(b / a) * np.abs(z1) ** (1.0 / 3.0))

    def sliding_time_bound(self) -> float:
        """The least upper bound of the time on s = 0, for every initial state: 3 pi / (2 sqrt(ab)), s."""
        return float(1.5 * np.pi / np.sqrt(self.ft_a * self.ft_b))

    def polyakov_bound(self) -> float:
        """Polyakov 2012 Lemma 1's bound 1/(a (1 - p)) + 1/(b (q - 1)) with p = 2/3, q = 4/3, s."""
        return 3.0 / self.ft_a + 3.0 / self.ft_b

"""Levant's arbitrary-order sliding controllers, registered as "levant_nested" and "levant_qc".

sigma = z_1 with its derivatives z_2..z_r; with weights r, r-1, ..., 1 for z_1..z_r both laws make the
closed loop homogeneous of degree -1 and u homogeneous of degree 0 (|u| <= alpha). With the control
held over a sampling period tau the accuracy is z_i = O(tau^(r-i+1)) (Levant 2003, Int. J. Control
76(9/10):924, Theorem 5): h^2 and h for r = 2, h^3, h^2, h for r = 3. Notation sig(a, p) = |a|^p sign a.

* nested (Levant 2003, section 4): psi_0 = z_1, psi_i = z_{i+1} + beta_i N_i sign(psi_{i-1}),
  u = -alpha sign(psi_{r-1}), N_i = (sum_{j=1..i} |z_j|^(q/(r-j+1)))^((r-i)/q). With q = 6 (r = 3),
  q = 12 (r = 4) and Levant's coefficients this gives the published list:
    r = 2: u = -alpha sign(z_2 + |z_1|^(1/2) sign z_1)
    r = 3: u = -alpha sign(z_3 + 2 (|z_2|^3 + |z_1|^2)^(1/6) sign(z_2 + |z_1|^(2/3) sign z_1))
    r = 4: u = -alpha sign(z_4 + 3 (z_3^6 + z_2^4 + |z_1|^3)^(1/12)
                           sign(z_3 + (z_2^4 + |z_1|^3)^(1/6) sign(z_2 + 0.5 |z_1|^(3/4) sign z_1)))
* quasi-continuous (Levant 2005, IEEE TAC 50(11):1812, section III): phi_0 = z_1, N_0 = |z_1|,
  Psi_i = phi_i / N_i, phi_i = z_{i+1} + beta_i N_{i-1}^((r-i)/(r-i+1)) Psi_{i-1},
  N_i = |z_{i+1}| + beta_i N_{i-1}^((r-i)/(r-i+1)), u = -alpha Psi_{r-1}, Psi = 0 where N = 0 (u is
  continuous except at the origin), e.g.
    r = 2: u = -alpha (z_2 + |z_1|^(1/2) sign z_1) / (|z_2| + |z_1|^(1/2))
    r = 3: u = -alpha [z_3 + 2 (|z_2| + |z_1|^(2/3))^(-1/2) (z_2 + |z_1|^(2/3) sign z_1)]
               / [|z_3| + 2 (|z_2| + |z_1|^(2/3))^(1/2)]
Coefficients beta_1..beta_{r-1}: (1), (1, 2), (0.5, 1, 3) for r = 2, 3, 4 (both papers' lists).
alpha must dominate the bounds (alpha gamma_m > phibar plus a margin the papers leave to tuning).

No Lyapunov function is logged (Levant's proofs use homogeneity, not a closed-form V): V1, dV1_dzr,
u0, gamma_hat and phi_hat are NaN; no time bound applies.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ftstab_mj.control.law import Law, LawOutput, Param, positive, register_law
from ftstab_mj.config.errors import ParameterError

ORDERS = (1, 2, 3, 4)
BETA = {1: (), 2: (1.0,), 3: (1.0, 2.0), 4: (0.5, 1.0, 3.0)}
NESTED_Q = {1: 1.0, 2: 2.0, 3: 6.0, 4: 12.0}
ALPHA = Param("alpha", float, "Levant's gain: |u| <= alpha", "chain units, m/s^r or rad/s^r", positive)


def _chain_state(z, r):
    z = np.asarray(z, dtype=float)
    if z.shape[-1:] != (r,):
        raise ParameterError("z", f"an array whose last axis has length r = {r}", z.shape)
    return z


@dataclass(frozen=True)
class _Levant(Law):
    """What both controllers share: r in 1..4, gain alpha > 0, u = -alpha psi(z), no state."""

    r: int
    alpha: float
    params = (ALPHA,)

    def __post_init__(self):
        if isinstance(self.r, bool) or not isinstance(self.r, (int, np.integer)) or self.r not in ORDERS:
            raise ParameterError("r", "a chain length in " + ", ".join(map(str, ORDERS)), self.r)
        a = self.alpha
        if isinstance(a, bool) or not isinstance(a, (int, float, np.integer, np.floating)) or not (np.isfinite(a) and a > 0):
            raise ParameterError("alpha", "a finite number > 0", a)
        object.__setattr__(self, "alpha", float(a))

    @classmethod
    def from_params(cls, r, values):
        return cls(r, values["alpha"])

    def native_params(self) -> dict:
        return {"par": (self.alpha, *BETA[self.r], *self.exponents)}

    def evaluate(self, z, state=None) -> LawOutput:
        u = -self.alpha * self.psi(z)
        nan = np.full(np.shape(u), np.nan)
        return LawOutput(u, nan, nan, nan, nan, nan)


@register_law
@dataclass(frozen=True)
class LevantNested(_Levant):
    """Levant's nested r-sliding controller, u = -alpha sign(psi_{r-1}(z)); r in 1..4."""

    name = "levant_nested"
    summary = "Levant's nested r-sliding controller, u = -alpha sign(psi_{r-1}) (Levant 2003, IJC 76:924)"
    native_code = 3

    @cached_property
    def exponents(self) -> tuple:
        """(q/(r-i+1) for i = 1..r-1, then (r-i)/q for i = 1..r-1): the powers of psi's recursion."""
        r, q = self.r, NESTED_Q[self.r]
        return tuple(q / (r - i + 1) for i in range(1, r)) + tuple((r - i) / q for i in range(1, r))

    def psi(self, z):
        """sign(psi_{r-1}(z)) in {-1, 0, 1}, shape (...)."""
        z = _chain_state(z, self.r)
        r, beta, e = self.r, BETA[self.r], self.exponents
        a = np.abs(z)
        psi = z[..., 0]
        acc = np.zeros(z.shape[:-1])  # sum_{j<=i} |z_j|^(q/(r-j+1))
        for i in range(1, r):
            acc = acc + a[..., i - 1] ** e[i - 1]
            psi = z[..., i] + beta[i - 1] * acc ** e[r - 2 + i] * np.sign(psi)
        return np.sign(psi)


@register_law
@dataclass(frozen=True)
class LevantQuasiContinuous(_Levant):
    """Levant's quasi-continuous r-sliding controller, u = -alpha Psi_{r-1}(z); r in 1..4."""

    name = "levant_qc"
    summary = "Levant's quasi-continuous r-sliding controller, u = -alpha Psi_{r-1} (Levant 2005, IEEE TAC 50:1812)"
    native_code = 4

    @cached_property
    def exponents(self) -> tuple:
        """(r-i)/(r-i+1) for i = 1..r-1: the powers of Psi's recursion."""
        return tuple((self.r - i) / (self.r - i + 1) for i in range(1, self.r))

    def psi(self, z):
        """Psi_{r-1}(z) in [-1, 1], 0 where its denominator vanishes, shape (...)."""
        z = _chain_state(z, self.r)
        r, beta, e = self.r, BETA[self.r], self.exponents
        phi = z[..., 0]
        N = np.abs(phi)
        Psi = np.sign(phi)  # phi_0 / N_0, 0 at N_0 = 0
        for i in range(1, r):
            term = beta[i - 1] * N ** e[i - 1]
            phi = z[..., i] + term * Psi
            N = np.abs(z[..., i]) + term
            with np.errstate(invalid="ignore", divide="ignore"):
                Psi = np.where(N > 0.0, phi / np.where(N > 0.0, N, 1.0), 0.0)
        return Psi

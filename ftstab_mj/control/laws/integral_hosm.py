"""Higher-order sliding mode by integral sliding mode, registered as "integral_hosm".

Laghrouche, Plestan and Glumineau, "Higher order sliding mode control based on integral sliding
mode", Automatica 43(3):531-537, 2007. The r-sliding problem z_r' = phi + gamma u is split in two:

* a nominal control u_nom that brings the unperturbed chain z_r' = u_nom from its state to the origin
  at a prescribed time t_F (their finite-time optimal control with a terminal constraint: here the
  minimum-energy one, min int u_nom^2 with z(t_F) = 0, in closed loop with the time to go T = t_F - t):

      u_nom = -B^T e^(A^T T) W(T)^-1 e^(A T) z = -sum_i c_i z_i / T^(r-i+1)

  (A the chain's shift matrix, B = e_r, W(T) the controllability Gramian over [0, T]; the c_i are
  those at T = 1 by the time scaling of the chain: r = 2, u_nom = -(6 z_1 + 4 T z_2) / T^2);
* an integral sliding variable s = z_r - z_r(0) - int_0^t u_nom, zero at t = 0, and
  u = u_nom - switching sign(s). Then s' = phi + (gamma - 1) u_nom - gamma switching sign s: with
  gamma switching > |phi + (gamma - 1) u_nom| the sliding mode s = 0 holds from t = 0 (no reaching
  phase), z_r' = u_nom exactly, and the chain arrives at the origin at t_F whatever the matched
  disturbance (the paper's main result; equation numbers not quoted here).

The minimum-energy gains grow without bound as T -> 0; the time to go is floored at ``t_hold``
(T = max(t_F - t, t_hold)), after which u_nom is the fixed linear feedback with poles
(-2 +- i sqrt 2) / t_hold (r = 2) and the sliding mode keeps the chain on it (not in the paper, which
stops at t_F; a sampled loop needs a feedback after t_F). With sampling, s = O(h) and the chain
stays O(h) from the nominal trajectory.

State (tau, J): tau the time since the start, J = z_r(0) + int u_nom (s = z_r - J). At tau = 0 the
law sets s = 0 (J takes the first sample's z_r in :meth:`IntegralHOSM.advance`), so the initial state
does not need z(0). u0 = u_nom is logged as the nominal part; no Lyapunov function.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from math import factorial

import numpy as np

from ftstab_mj.control.law import Law, LawOutput, Param, positive, register_law
from ftstab_mj.control.laws.terminal import SWITCHING, chain_state, positive_number
from ftstab_mj.config.errors import ParameterError


def min_energy_gains(r: int) -> np.ndarray:
    """(c_1, ..., c_r): u_nom = -sum c_i z_i / T^(r-i+1) steers z_r' = u_nom to 0 in time T with min int u^2.

    Exact rational arithmetic would give r = 2: (6, 4); r = 3: (60, 36, 9)."""
    W = np.array([[1.0 / (factorial(r - 1 - i) * factorial(r - 1 - j) * (2 * r - 1 - i - j)) for j in range(r)]
                  for i in range(r)])  # Gramian over [0, 1]: int tau^(r-1-i) tau^(r-1-j) / (..)! d tau
    eA = np.array([[1.0 / factorial(j - i) if j >= i else 0.0 for j in range(r)] for i in range(r)])
    Bt_eAt = eA[:, -1]  # B^T e^(A^T) = (e^A B)^T, the last column of e^A
    return Bt_eAt @ np.linalg.solve(W, eA)


@register_law
@dataclass(frozen=True)
class IntegralHOSM(Law):
    """u = u_nom(z, t_F - t) - switching sign(z_r - J), J' = u_nom (module docstring). State (tau, J)."""

    r: int
    t_final: float
    switching: float
    t_hold: float | None = None
    name = "integral_hosm"
    native_code = 11
    summary = ("integral sliding mode around a minimum-energy control reaching 0 at t_final "
               "(Laghrouche, Plestan, Glumineau 2007, Automatica 43:531)")
    params = (
        Param("t_final", float, "the time t_F at which the nominal control brings the chain to 0", "s", positive),
        SWITCHING,
        Param("t_hold", float, "floor of the time to go t_F - t (default t_final / 10)", "s", positive, default=None),
    )
    gains: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        if isinstance(self.r, bool) or not isinstance(self.r, (int, np.integer)) or not 1 <= self.r <= 8:
            raise ParameterError("r", "a chain length in 1..8", self.r)
        for name in ("t_final", "switching"):
            object.__setattr__(self, name, positive_number(name, getattr(self, name)))
        hold = self.t_final / 10.0 if self.t_hold is None else positive_number("t_hold", self.t_hold)
        if hold > self.t_final:
            raise ParameterError("t_hold", f"a time <= t_final = {self.t_final} s", hold)
        object.__setattr__(self, "t_hold", hold)
        g = min_energy_gains(self.r)
        g.setflags(write=False)
        object.__setattr__(self, "gains", g)

    @classmethod
    def from_params(cls, r, values):
        return cls(r, values["t_final"], values["switching"], values["t_hold"])

    @property
    def state_size(self) -> int:
        return 2

    def native_params(self) -> dict:
        return {"par": (self.t_final, self.switching, self.t_hold, *self.gains)}

    def nominal(self, z, tau):
        """u_nom at the time since the start tau (...), shape (...)."""
        z = chain_state(z, self.r)
        T = np.maximum(self.t_final - np.asarray(tau, dtype=float), self.t_hold)
        powers = np.arange(self.r, 0, -1)  # r - i + 1 for i = 1..r
        return -np.sum(self.gains * z / T[..., None] ** powers, axis=-1)

    def _s(self, z, state):
        state = np.asarray(state, dtype=float)
        tau, J = state[..., 0], state[..., 1]
        return np.where(tau > 0.0, z[..., -1] - J, 0.0)

    def evaluate(self, z, state) -> LawOutput:
        z = chain_state(z, self.r)
        u_nom = self.nominal(z, np.asarray(state, dtype=float)[..., 0])
        u = u_nom - self.switching * np.sign(self._s(z, state))
        nan = np.full(np.shape(u), np.nan)
        return LawOutput(u, u_nom + 0.0 * u, nan, nan, nan, nan)

    def state_derivative(self, z, state, out):
        """(tau', J') = (1, u_nom) (J's reset to z_r at tau = 0 is in :meth:`advance`)."""
        return np.stack([np.ones(np.shape(out.u0)), out.u0], axis=-1)

    def advance(self, z, state, out, h):
        z = chain_state(z, self.r)
        state = np.asarray(state, dtype=float)
        tau, J = state[..., 0], state[..., 1]
        J = np.where(tau > 0.0, J, z[..., -1])
        return np.stack([tau + h, J + h * out.u0], axis=-1)

"""The actuator of one loop: what the plant receives when the law asks for u (chain units).

Per control sample, the command the law asked for goes through, in this order:

1. a dead zone of half-width d: u - d sign(u) outside [-d, d], 0 inside (the continuous
   dead-zone nonlinearity, e.g. dry friction in a drive);
2. saturation at |u| <= u_max;
3. a rate limit |du/dt| <= rate_max: the command moves from the previous one by at most
   rate_max * period per sample (the previous command is state; 0 at rest before the run);
4. a first-order lag with time constant tau (unmodelled actuator dynamics, tau u_a' = u_c - u_a):
   realised as a filter state u_a (not MuJoCo's actuator dynamics, so that the same models serve
   every plant and the state sits with the other stages' in userdata), integrated exactly with
   the command held, u_a <- u_c + (u_a - u_c) exp(-h / tau) per physics step h; over each step
   the plant receives the mean of u_a over that step (the exact impulse), so the force moves
   within the control period (u_a = 0 at rest before the run). ``u_applied`` is the input of the
   period's first step. ``lag_order = 2`` puts two such lags in cascade (a second-order actuator,
   1 / (tau s + 1)^2), integrated and averaged exactly the same way.

Why a second order. The law's discontinuous term acts on a switching function of relative degree
1 in u. Closed through one first-order lag the loop has relative degree 2, and a relay around
1 / (s (tau s + 1)) has no finite-frequency limit cycle (its phase never reaches -180 degrees): the
chattering stays the one the sampling makes, whatever tau (measured on the cart: final |z_2|
slope 0.04 over tau = 1..50 ms). With a second-order actuator (relative degree 3) the relay
oscillates at about 1 / tau with an amplitude proportional to tau (describing function; Boiko &
Fridman, IEEE TAC 50(9):1442, 2005): the classic chattering of unmodelled actuator dynamics.

Every stage at its default (d = 0, u_max = rate_max = inf, tau = 0) is the identity, bit for bit.
State (3,): the last rate-limited command and the outputs of the two lags (the second unused at lag_order 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ftstab_mj.config.errors import ParameterError

STATE_SIZE = 3


def _number(name, value, lo, allow_inf):
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    ok = ok and not math.isnan(value) and (allow_inf or math.isfinite(value)) and value >= lo
    return ok


@dataclass(frozen=True)
class ActuatorModel:
    """u_max (> 0, inf: none), rate_max (> 0 per second, inf: none), tau (>= 0 s), dead_zone (>= 0),
    all in chain units of u; lag_order: 1 or 2 identical lags in cascade."""

    u_max: float = math.inf
    rate_max: float = math.inf
    tau: float = 0.0
    dead_zone: float = 0.0
    lag_order: int = 1

    def __post_init__(self):
        if self.lag_order not in (1, 2) or isinstance(self.lag_order, bool):
            raise ParameterError("lag_order", "1 or 2", self.lag_order)
        for name, allow_inf in (("u_max", True), ("rate_max", True), ("tau", False), ("dead_zone", False)):
            v = getattr(self, name)
            if not _number(name, v, 0.0, allow_inf) or (name in ("u_max", "rate_max") and v == 0):
                raise ParameterError(name, "a number > 0 (inf: none)" if allow_inf else "a finite number >= 0", v)
            object.__setattr__(self, name, float(v))

    @property
    def ideal(self) -> bool:
        return (self.u_max == math.inf and self.rate_max == math.inf and self.tau == 0.0
                and self.dead_zone == 0.0)

    def initial_state(self) -> np.ndarray:
        return np.zeros(STATE_SIZE)

    def saturated(self, u) -> np.ndarray:
        """True where the law asks for more than u_max (after the dead zone)."""
        return np.abs(u) - self.dead_zone > self.u_max

    def command(self, u, state, period: float) -> float:
        """Stages 1-3: the command u_c for a law output u (float) given the state."""
        if self.dead_zone:
            u = math.copysign(max(abs(u) - self.dead_zone, 0.0), u)
        if self.u_max != math.inf:
            u = min(max(u, -self.u_max), self.u_max)
        if self.rate_max != math.inf:
            step = self.rate_max * period
            prev = float(state[0])
            u = min(max(u, prev - step), prev + step)
        return u

    def steps(self, u_c: float, state, h: float, N: int):
        """Stage 4 over one period of N physics steps of h: (the input over each step (N,), new state).

        The lag's output moves within a step; the plant gets its average over the step (the exact
        impulse of the lagged force). With e_1 = x_1 - u_c, e_2 = x_2 - u_c and d = exp(-h/tau),
        exactly: e_1(t) = e_1 exp(-t/tau), e_2(t) = (e_2 + e_1 t/tau) exp(-t/tau); the mean of the
        output over a step is u_c + e (tau/h)(1 - d) for one lag (e = e_1) and
        u_c + (e_2 tau (1 - d) + e_1 (tau (1 - d) - h d)) / h for two. tau -> 0 gives u_c.
        new state = (u_c, x_1, x_2) at the end of the period.
        """
        if self.tau == 0.0:
            return np.full(N, u_c), np.array([u_c, u_c, u_c])
        tau = self.tau
        decay = math.exp(-h / tau)
        j = np.arange(N + 1)
        powers = decay ** j
        e1 = (float(state[1]) - u_c) * powers
        if self.lag_order == 1:
            out = u_c + e1[:N] * (tau / h * (1.0 - decay))
            return out, np.array([u_c, u_c + e1[N], u_c + e1[N]])
        e2 = ((float(state[2]) - u_c) + (float(state[1]) - u_c) * (j * (h / tau))) * powers
        out = u_c + (e2[:N] * (tau * (1.0 - decay)) + e1[:N] * (tau * (1.0 - decay) - h * decay)) / h
        return out, np.array([u_c, u_c + e1[N], u_c + e2[N]])

def control_needed(law, z0, samples: int = 20000, seed: int = 0) -> tuple[float | None, str]:
    """(u_needed, how it was found): the largest |u| the law's guarantee may ask for from z0, or
    None with the reason when it has no a priori bound.

    For the nominal and robust laws on Hong's full form, u = gamma_hat u0 + phi_hat sign(u0) with
    constant gamma_hat, phi_hat, and the guarantee keeps V1 <= V1(z0) along the solution (V1 is
    decreasing). u0 and V1 are homogeneous of degrees 1 + r k and 2 + k (same dilation), so
    sup_{V1 <= c} |u0| = c^((1 + r k) / (2 + k)) sup_{V1 = 1} |u0| (1 + r k > 0). The sup on
    {V1 = 1} is sampled (dilated random directions, then a local search: control/certificate.py),
    so u_needed is an estimate from below: u_max below it certainly starves the guarantee, u_max
    above it is only estimated to suffice.
    """
    from ftstab_mj.control.certificate import refine_max, unit_level_set_points

    hong = getattr(law, "hong", None)
    if not getattr(law, "u_bound_from_V1", False) or hong is None or hong.form != "full":
        return None, f"the {getattr(law, 'name', type(law).__name__)!r} law's guarantee has no a priori bound on |u|"
    z0 = np.asarray(z0, dtype=float)
    out = law.evaluate(z0, law.initial_state())
    V1_0 = float(out.V1)
    rng = np.random.default_rng(seed)
    z = unit_level_set_points(hong, samples, rng)

    def abs_u0(x):
        return np.abs(hong.evaluate(x)[0])

    vals = abs_u0(z)
    top = z[np.argsort(vals)[-64:]]
    sup1 = max(float(np.max(vals)), refine_max(hong, abs_u0, top, rng))
    sup_u0 = max(V1_0 ** (hong.degree_u0 / hong.degree_V1) * sup1, float(abs(out.u0)))
    need = float(out.gamma_hat) * sup_u0 + float(out.phi_hat)
    return need, (f"sup |u| over V1 <= V1(z0) = {V1_0:.4g}: gamma_hat sup|u0| + phi_hat, sup|u0| sampled on "
                  f"{samples} points of V1 = 1 (an estimate from below)")

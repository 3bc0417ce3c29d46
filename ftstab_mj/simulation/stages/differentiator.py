"""Levant's arbitrary-order robust exact differentiator and its filtering variant, sampled.

The problem. A signal f(t) with |f^(n+1)| <= L (L, the "Lipschitz constant", is known) is
measured at t_k = k tau, possibly with a bounded noise |eta| <= eps. The differentiator of order
n returns estimates z_0..z_n of f, f', ..., f^(n).

Continuous time (Levant 2003, Int. J. Control 76(9/10):924, section 4). The recursive form is

    z_0' = v_0,  v_0 = -lambda_n L^(1/(n+1)) sig(z_0 - f, n/(n+1)) + z_1
    z_i' = v_i,  v_i = -lambda_(n-i) L^(1/(n-i+1)) sig(z_i - v_(i-1), (n-i)/(n-i+1)) + z_(i+1)
    z_n' = -lambda_0 L sign(z_n - v_(n-1))

with sig(a, p) = |a|^p sign(a). Levant 2003 gives lambda_0..lambda_5 = 1.1, 1.5, 2, 3, 5, 8 as
sufficient for n <= 5 (the defaults here). Substituting v_(i-1) into each line gives the
equivalent non-recursive form (the one Livne & Levant 2014 discretize):

    z_i' = -lt_(n-i) L^((i+1)/(n+1)) sig(z_0 - f, (n-i)/(n+1)) + z_(i+1),   i = 0..n  (z_(n+1) = 0)

with lt_n = lambda_n and lt_m = lambda_m lt_(m+1)^(m/(m+1)) (:func:`nonrecursive_lambdas`; e.g.
n = 2: 1.1, 2.12, 2; n = 3: 1.1, 3.06, 4.16, 3).

Accuracy (Levant 2003, section 4). After a finite transient, without noise and with sampling
period tau, |z_i - f^(i)| <= mu_i L tau^(n-i+1); with noise of amplitude eps (and tau small
enough), |z_i - f^(i)| <= mu_i L^(i/(n+1)) eps^((n-i+1)/(n+1)). Both are asymptotically
optimal; tests/test_loop_stages.py fits these slopes.

Discretization (the one of Livne & Levant 2014, "Proper discretization of homogeneity-based
differentiators", Automatica 50(8):2007): the non-recursive form, one explicit step per sample
(f held), plus the Taylor terms of the integrator chain, which keep the accuracy above:

    z_i(k+1) = z_i(k) + tau * (-lt_(n-i) L^((i+1)/(n+1)) sig(z_0(k) - f_k, (n-i)/(n+1)))
               + sum_(j=1..n-i) tau^j / j! z_(i+j)(k)

Filtering variant (Levant & Livne 2020, "Robust exact filtering differentiators", European J.
Control 55:33): n_f >= 1 extra states w_1..w_(n_f) integrate the output error, which rejects
noise whose local average is small (even large, unbounded noise). With N = n + n_f and the
non-recursive coefficients lt of order N:

    w_j' = -lt_(N+1-j) L^(j/(N+1)) sig(w_1, (N+1-j)/(N+1)) + w_(j+1)     (j < n_f)
    w_nf' = -lt_(n+1) L^(n_f/(N+1)) sig(w_1, (n+1)/(N+1)) + z_0 - f
    z_i' = -lt_(n-i) L^((i+1+n_f)/(N+1)) sig(w_1, (n-i)/(N+1)) + z_(i+1)

discretized as in the discrete version of the same paper (and the Robust Exact Differentiator
toolbox of Andritsch et al. 2021): explicit Euler for the w_j, the Taylor terms above for the z_i.
With n_f = 0 this is exactly the plain differentiator.

State layout (last axis, size n + 1 + n_f): z_0..z_n, then w_1..w_(n_f). Every function is
vectorised over leading axes.
"""

from __future__ import annotations

from dataclasses import dataclass
from math import factorial

import numpy as np

from ftstab_mj.config.errors import ParameterError

# lambda_0..lambda_5 of the recursive form (Levant 2003, sufficient for n <= 5).
LEVANT_2003_LAMBDAS = (1.1, 1.5, 2.0, 3.0, 5.0, 8.0)
MAX_TOTAL_ORDER = len(LEVANT_2003_LAMBDAS) - 1


def lipschitz_rule(r: int, order: int, phibar: float, gamma_M: float, u_max: float | None) -> float | None:
    """The differentiator's L (chain units, m/s^(order+1)) for a loop of chain length r whose plant obeys
    z_r' = phi + gamma u with |phi| <= phibar, gamma <= gamma_M, and whose actuator saturates at u_max.

    Levant 2003 (section 4) assumes |f^(n+1)| <= L for the input f = z_1 along the whole run. With
    n = r - 1, f^(r) = phi + gamma u_applied, and the reachable set of |u_applied| is bounded by the
    saturation alone: whatever the estimation error drives the law to ask, |f^(r)| <= phibar + gamma_M u_max.
    That is the rule (the sup over the reachable set, not an estimate from a run). None when no such bound
    exists: no saturation (the law's u is then bounded only where the theorems hold, and a noisy estimate
    leaves that set: the differentiator's assumption fails, the loop can diverge), or n > r - 1 (the
    bound then needs phi's and u's derivatives)."""
    if order != r - 1 or u_max is None or not np.isfinite(u_max):
        return None
    return float(phibar + gamma_M * u_max)


def nonrecursive_lambdas(lambdas) -> tuple[float, ...]:
    """The coefficients lt_0..lt_N of the non-recursive form from lambda_0..lambda_N of the
    recursive one: lt_N = lambda_N, lt_m = lambda_m lt_(m+1)^(m/(m+1))."""
    lam = [float(x) for x in lambdas]
    lt = [0.0] * len(lam)
    lt[-1] = lam[-1]
    for m in range(len(lam) - 2, -1, -1):
        lt[m] = lam[m] * lt[m + 1] ** (m / (m + 1))
    return tuple(lt)


def _sig(a, p):
    return np.sign(a) * np.abs(a) ** p


@dataclass(frozen=True)
class LevantDifferentiator:
    """Sampled robust exact differentiator of order ``order`` (n >= 0) for |f^(n+1)| <= L.

    filter_order: n_f, 0 for Levant's differentiator, >= 1 for the filtering variant; n + n_f <= 5
    (the range of the default coefficients).
    """

    order: int
    L: float
    filter_order: int = 0

    def __post_init__(self):
        for name in ("order", "filter_order"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
                raise ParameterError(name, "an integer >= 0", v)
        if self.order + self.filter_order > MAX_TOTAL_ORDER:
            raise ParameterError("order", f"order + filter_order <= {MAX_TOTAL_ORDER} (Levant's coefficients)",
                                 self.order + self.filter_order)
        L = self.L
        if isinstance(L, bool) or not isinstance(L, (int, float, np.integer, np.floating)) or not (np.isfinite(L) and L > 0):
            raise ParameterError("L", "a finite number > 0", L)
        object.__setattr__(self, "L", float(L))
        N = self.order + self.filter_order
        lt = nonrecursive_lambdas(LEVANT_2003_LAMBDAS[:N + 1])
        n, nf = self.order, self.filter_order
        # Per z_i: gain lt_(n-i) L^((i+1+nf)/(N+1)) and exponent (n-i)/(N+1) of the error term.
        object.__setattr__(self, "_z_gain", np.array([lt[n - i] * self.L ** ((i + 1 + nf) / (N + 1)) for i in range(n + 1)]))
        object.__setattr__(self, "_z_pow", np.array([(n - i) / (N + 1) for i in range(n + 1)]))
        object.__setattr__(self, "_w_gain", np.array([lt[N + 1 - j] * self.L ** (j / (N + 1)) for j in range(1, nf + 1)]))
        object.__setattr__(self, "_w_pow", np.array([(N + 1 - j) / (N + 1) for j in range(1, nf + 1)]))

    @property
    def state_size(self) -> int:
        return self.order + 1 + self.filter_order

    def initial_state(self, f0) -> np.ndarray:
        """(..., state_size): z_0 = the first measurement, every derivative and w_j = 0."""
        f0 = np.asarray(f0, dtype=float)
        state = np.zeros(f0.shape + (self.state_size,))
        state[..., 0] = f0
        return state

    def estimate(self, state) -> np.ndarray:
        """z_0..z_n (..., n+1): the estimates of f, f', ..., f^(n) at the current sample."""
        return np.asarray(state)[..., :self.order + 1]

    def step(self, state, f, tau) -> np.ndarray:
        """The state one sample later, from the state and the measurement f at this sample.

        state (..., state_size); f (...); tau: sampling period (s), a number or (...) array.
        """
        state = np.asarray(state, dtype=float)
        n, nf = self.order, self.filter_order
        z, w = state[..., :n + 1], state[..., n + 1:]
        f = np.asarray(f, dtype=float)
        tau = np.asarray(tau, dtype=float)[..., None]
        e = w[..., 0] if nf else z[..., 0] - f
        out = np.empty(np.broadcast(state, tau).shape)
        # z part: explicit step of the correction terms plus the exact Taylor step of the chain
        # z_i <- sum_(j=0..n-i) tau^j/j! z_(i+j) (Livne & Levant 2014).
        out[..., :n + 1] = z - tau * self._z_gain * _sig(e[..., None], self._z_pow)
        for j in range(1, n + 1):
            out[..., :n + 1 - j] += tau ** j / factorial(j) * z[..., j:]
        if nf:  # filter part: explicit Euler
            drive = np.concatenate([w[..., 1:], (z[..., 0] - f)[..., None]], axis=-1)
            out[..., n + 1:] = w + tau * (drive - self._w_gain * _sig(e[..., None], self._w_pow))
        return out

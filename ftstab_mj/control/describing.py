"""Describing-function prediction of the limit cycle a law sustains through a lagged actuator.

The loop: the chain z_1^(r) = u_a (gamma = 1, no disturbance), an actuator 1 / (tau s + 1)^n
(n = 1 or 2, the actuator stage's lag_order) and a pure delay d between the law's output u and
u_a (the sampled law: its zero-order hold delays u by h / 2 on average). From u to z_1 the linear
part is

    W(jw) = exp(-j w d) / ((1 + j w tau)^n (j w)^r).

Harmonic balance: assume z_1 = Re(a e^(j w t)) with a > 0, hence z_i = Re(a (j w)^(i-1) e^(j w t)).
The law's output u(t) is then periodic; its first harmonic Re(U e^(j w t)) defines the describing
function N(a, w) = U / a (complex, chain units of u per unit of z_1), computed here numerically from
the law itself (:func:`describing_function`): for a relay c sign(z_1) it is -4 c / (pi a); for the
twisting law -4 (r1 + j r2) / (pi a); for super-twisting's integral term it brings the -j / w of the
integrator. A periodic solution of the first-harmonic approximation satisfies

    W(jw) N(a, w) = 1,

two real equations (|W N| = 1, arg(W N) = 0) in (a, w), solved by :func:`harmonic_balance` on a
log grid of (a, w), then refined. Laws with a state (super-twisting's integral, an adaptive gain)
are run along the harmonic for a few periods; when the first harmonic of u still changes from one
period to the next (an adaptive gain that drifts), N is undefined there (NaN) and no limit cycle is
predicted. Where several solutions exist the one of largest amplitude is returned (for the
relay-type laws it is the orbitally stable one, by Loeb's criterion).

Sources: Gelb & Vander Velde, "Multiple-input describing functions and nonlinear system design"
(1968); Boiko & Fridman, "Analysis of chattering in continuous sliding-mode controllers", IEEE TAC
50(9):1442, 2005 (super-twisting); Boiko, "Discontinuous control systems", Birkhauser 2009.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

SAMPLES = 256  # points per period of the harmonic (first-harmonic error O(1 / SAMPLES) for a relay)
PERIODS = 2  # periods a law with state is run along the harmonic: the second gives N, the first checks it
STATE_SAMPLES = 128  # points per period for a law with state (stepped one sample at a time: slower)
PERIODIC_RTOL = 1e-3  # |U_last - U_before| <= this |U_last|: the law's response is periodic


@dataclass(frozen=True)
class LimitCycle:
    """The predicted oscillation: frequency (Hz), first-harmonic amplitudes of z_1 (chain units, m
    or rad) and of the law's u (chain units of u)."""

    frequency: float
    amplitude_z1: float
    amplitude_u: float

    def as_dict(self) -> dict:
        return {"frequency": float(self.frequency), "amplitude_z1": float(self.amplitude_z1),
                "amplitude_u": float(self.amplitude_u)}


def linear_part(w, r: int, tau: float, lag_order: int, delay: float = 0.0):
    """W(jw) from u to z_1 (module docstring), w (rad/s) an array."""
    jw = 1j * np.asarray(w, dtype=float)
    return np.exp(-jw * delay) / ((1.0 + jw * tau) ** lag_order * jw ** r)


def describing_function(law, a, w, samples: int | None = None, periods: int = PERIODS):
    """N(a, w) = U / a (complex, broadcast shape of a and w): the first harmonic U of the law's u when
    z_1 = a cos(theta), z_i = Re(a (jw)^(i-1) e^(j theta)) (a in chain units, w in rad/s). NaN where a
    law with state does not respond periodically. samples per period: SAMPLES, or STATE_SAMPLES for a
    law with a state."""
    if samples is None:
        samples = SAMPLES if law.state_size == 0 else STATE_SAMPLES
    a, w = np.broadcast_arrays(np.asarray(a, dtype=float), np.asarray(w, dtype=float))
    shape = a.shape
    a, w = a.ravel(), w.ravel()
    r = law.r
    theta = 2.0 * np.pi * (np.arange(samples) + 0.5) / samples  # midpoints: no sample on a switch of sign(z_i)
    phasors = a[:, None] * (1j * w[:, None]) ** np.arange(r)  # (m, r)
    e = np.exp(1j * theta)
    if law.state_size == 0:
        z = np.real(phasors[:, None, :] * e[None, :, None])  # (m, samples, r)
        u = np.asarray(law.evaluate(z, None).u, dtype=float)
        U = 2.0 * np.mean(u * np.conj(e)[None, :], axis=1)
    else:  # run the law's state along the harmonic, one w at a time (advance takes one step h)
        U = np.empty(len(a), dtype=complex)
        for wk in np.unique(w):
            sel = np.flatnonzero(w == wk)
            U[sel] = _stateful_harmonic(law, phasors[sel], e, 2.0 * np.pi / (samples * wk), periods)
    return (U / a).reshape(shape)


def _stateful_harmonic(law, phasors, e, dt: float, periods: int):
    """First harmonic of u (m,) for z_i = Re(phasors[:, i] e), the law's state from its initial value
    advanced by dt s per sample; NaN where the last two periods' harmonics differ (no periodic response)."""
    state = np.broadcast_to(law.initial_state(), (len(phasors), law.state_size)).astype(float)
    U_prev = U = None
    for _ in range(periods):
        acc = np.zeros(len(phasors), dtype=complex)
        for ek in e:
            z = np.real(phasors * ek)
            out = law.evaluate(z, state)
            acc += np.asarray(out.u, dtype=float) * np.conj(ek)
            state = law.advance(z, state, out, dt)
        U_prev, U = U, 2.0 * acc / len(e)
    return np.where(np.abs(U - U_prev) > PERIODIC_RTOL * np.abs(U), np.nan, U)


def _crossings(x):
    """Indices i with x[i] and x[i + 1] of opposite signs (x[i] != 0), along the last axis."""
    return np.flatnonzero((np.sign(x[:-1]) * np.sign(x[1:]) < 0))


def harmonic_balance(law, tau: float, lag_order: int, delay: float = 0.0, w_range=None,
                     a_range=(1e-12, 1e2), n_w: int = 60, n_a: int = 60) -> LimitCycle | None:
    """The limit cycle the first-harmonic balance W N = 1 predicts (module docstring), None when it has
    no solution in w_range (rad/s; default 1e-2 / tau .. 1e2 / tau, and below pi / delay' where a delay
    is given) and a_range (chain units of z_1). tau > 0 s, lag_order 1 or 2, delay >= 0 s."""
    if not tau > 0:
        return None
    lo, hi = w_range if w_range is not None else (1e-2 / tau, 1e2 / tau)
    sols = _solve(law, tau, lag_order, delay, np.geomspace(lo, hi, n_w), np.geomspace(*a_range, n_a))
    if not sols:
        return None
    a, w = max(sols)
    N = complex(describing_function(law, a, w))
    return LimitCycle(frequency=float(w) / (2 * math.pi), amplitude_z1=float(a), amplitude_u=abs(N) * float(a))


def _residuals(law, tau, lag_order, delay, ws, As):
    """log |W N| and arg(W N) on the grid (len(As), len(ws))."""
    A, Wg = np.meshgrid(As, ws, indexing="ij")
    G = linear_part(Wg, law.r, tau, lag_order, delay) * describing_function(law, A, Wg)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.log(np.abs(G)), np.angle(G)


def _solve(law, tau, lag_order, delay, ws, As, refine: int = 2) -> list:
    """[(a, w)] solutions: per w, the amplitudes where |W N| crosses 1; along them, the w where the
    phase crosses 0 (not through +-pi); each refined on a finer local grid ``refine`` times."""
    mag, ph = _residuals(law, tau, lag_order, delay, ws, As)
    branch = {}  # crossing index along a -> list of (w index, log a*, phase at a*)
    for j in range(len(ws)):
        for n, i in enumerate(_crossings(mag[:, j])):
            f = mag[i, j] / (mag[i, j] - mag[i + 1, j])
            la = (1 - f) * np.log(As[i]) + f * np.log(As[i + 1])
            p = (1 - f) * ph[i, j] + f * ph[i + 1, j] if abs(ph[i, j] - ph[i + 1, j]) < np.pi else np.nan
            branch.setdefault(n, []).append((j, la, p))
    out = []
    for pts in branch.values():
        for (j0, la0, p0), (j1, la1, p1) in zip(pts, pts[1:]):
            if j1 != j0 + 1 or not (np.isfinite(p0) and np.isfinite(p1)) or p0 * p1 >= 0:
                continue
            if abs(p0 - p1) > np.pi / 2:  # a jump through +-pi, not a zero of the phase
                continue
            a_lo, a_hi = sorted((math.exp(la0), math.exp(la1)))
            if refine:
                # one coarse step of margin each side: the finer grid moves the crossing a little
                w_lo, w_hi = ws[max(j0 - 1, 0)], ws[min(j1 + 1, len(ws) - 1)]
                sub = _solve(law, tau, lag_order, delay, np.geomspace(w_lo, w_hi, 13),
                             np.geomspace(a_lo / 3, a_hi * 3, 33), refine - 1)
                out.extend(sub)
            else:
                f = p0 / (p0 - p1)
                out.append((math.exp((1 - f) * la0 + f * la1), (1 - f) * ws[j0] + f * ws[j1]))
    return out

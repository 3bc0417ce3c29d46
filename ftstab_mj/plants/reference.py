"""References to track: ``[loops.<name>.reference]``, the chain error z_i = q^(i-1) - ref^(i-1)(t).

A loop regulates to a set point (``ref = x``: the constant reference) or tracks ref(t). The run loop
subtracts ref and its derivatives from the plant's chain state at every sample (z_1 = q - ref,
z_2 = q' - ref', ...), starts the plant at q(0) = ref(0) + z0_1, q'(0) = ref'(0) + z0_2, ... and
records phi of the error chain: z_r' = q^(r) - ref^(r) = (phi_plant - ref^(r)) + gamma u, so
ref^(r) enters the recorded phi and, through :meth:`Reference.max_abs`, the bound phibar that a
"computed" robust law and Theorem 3 use.

Kinds and their keys (times in s, positions in m or rad)::

    constant   value                                ref = value
    sine       offset, amplitude, freq (Hz), phase  ref = offset + amplitude sin(2 pi freq t + phase)
    polynomial coeffs = [c0, c1, ...]               ref = c0 + c1 t + c2 t^2 + ...
    min_jerk   start, end, t_start, duration        from start to end over [t_start, t_start + duration]
                                                    (10 s^3 - 15 s^4 + 6 s^5), at rest before and after

Derivatives are exact (closed forms). A min_jerk's third derivative jumps at both ends (an r = 3
loop sees it in phi); its first two are continuous.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ftstab_mj.config.errors import ParameterError

KEYS_BY_KIND = {
    "constant": ("value",),
    "sine": ("offset", "amplitude", "freq", "phase"),
    "polynomial": ("coeffs",),
    "min_jerk": ("start", "end", "t_start", "duration"),
}
KINDS = tuple(KEYS_BY_KIND)
MAX_COEFFS = 12  # a polynomial of degree <= 11
MAX_VALUE = 1e9  # |ref| and its derivatives stay far below MuJoCo's 1e10 reset


@dataclass(frozen=True)
class Reference:
    """ref(t) of one loop (see the module docstring for each kind's keys; the others are unused)."""

    kind: str = "constant"
    value: float = 0.0
    offset: float = 0.0
    amplitude: float = 0.0
    freq: float = 0.0
    phase: float = 0.0
    coeffs: tuple[float, ...] = ()
    start: float = 0.0
    end: float = 0.0
    t_start: float = 0.0
    duration: float = 1.0

    def __post_init__(self):
        if self.kind not in KEYS_BY_KIND:
            raise ParameterError("kind", "one of " + ", ".join(KINDS), self.kind)
        for key in ("value", "offset", "amplitude", "freq", "phase", "start", "end", "t_start", "duration"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or abs(v) > MAX_VALUE:
                raise ParameterError(key, f"a finite number, |x| <= {MAX_VALUE:g}", v)
        if self.freq < 0:
            raise ParameterError("freq", "a frequency >= 0 (Hz)", self.freq)
        if self.duration <= 0:
            raise ParameterError("duration", "a duration > 0 (s)", self.duration)
        if self.t_start < 0:
            raise ParameterError("t_start", "a time >= 0 (s)", self.t_start)
        c = self.coeffs
        if not isinstance(c, tuple) or len(c) > MAX_COEFFS or any(
                isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x) or abs(x) > MAX_VALUE
                for x in c):
            raise ParameterError("coeffs", f"at most {MAX_COEFFS} finite numbers [c0, c1, ...] (ref = c0 + c1 t + ...)", c)
        if self.kind == "polynomial" and not c:
            raise ParameterError("coeffs", "at least one coefficient [c0, c1, ...]", c)

    @property
    def constant(self) -> bool:
        return self.kind == "constant"

    def derivatives(self, t, order: int) -> np.ndarray:
        """(len(t), order + 1): ref^(j)(t) for j = 0..order."""
        t = np.asarray(t, dtype=float)
        out = np.zeros((t.size, order + 1))
        if self.kind == "constant":
            out[:, 0] = self.value
        elif self.kind == "sine":
            w = 2.0 * math.pi * self.freq
            arg = w * t + self.phase
            for j in range(order + 1):
                # d^j/dt^j sin(arg) = w^j sin(arg + j pi / 2)
                out[:, j] = self.amplitude * w ** j * (np.sin(arg) if j % 4 == 0 else np.cos(arg) if j % 4 == 1
                                                       else -np.sin(arg) if j % 4 == 2 else -np.cos(arg))
            out[:, 0] += self.offset
        elif self.kind == "polynomial":
            c = np.array(self.coeffs, dtype=float)
            for j in range(order + 1):
                out[:, j] = np.polynomial.polynomial.polyval(t, c) if c.size else 0.0
                c = np.polynomial.polynomial.polyder(c) if c.size > 1 else np.zeros(0)
        else:  # min_jerk
            T, d = self.duration, self.end - self.start
            s = np.clip((t - self.t_start) / T, 0.0, 1.0)
            inside = (t > self.t_start) & (t < self.t_start + T)
            # the normalized profile's derivatives in s: p(s) = 10 s^3 - 15 s^4 + 6 s^5
            p = [10 * s**3 - 15 * s**4 + 6 * s**5, 30 * s**2 - 60 * s**3 + 30 * s**4, 60 * s - 180 * s**2 + 120 * s**3,
                 60 - 360 * s + 360 * s**2, -360 + 720 * s, np.full_like(s, 720.0)]
            out[:, 0] = self.start + d * p[0]
            for j in range(1, order + 1):
                out[:, j] = np.where(inside, d * p[j] / T**j, 0.0) if j < len(p) else 0.0
        return out

    def max_abs(self, order: int, horizon: float) -> np.ndarray:
        """(order + 1,): max over [0, horizon] of |ref^(j)|, j = 0..order (exact for a constant and a sine;
        a polynomial and a min_jerk on a grid of 20001 points, their interior extrema included to 1e-8
        relative)."""
        if self.kind == "constant":
            return np.array([abs(self.value)] + [0.0] * order)
        if self.kind == "sine":
            w = 2.0 * math.pi * self.freq
            return np.array([abs(self.offset) + abs(self.amplitude)] + [abs(self.amplitude) * w ** j
                                                                        for j in range(1, order + 1)])
        t = np.linspace(0.0, max(float(horizon), 0.0), 20001)
        if self.kind == "min_jerk":  # every breakpoint and the profile itself on a fine grid of its own
            t = np.concatenate([t, np.linspace(self.t_start, self.t_start + self.duration, 20001)])
            t = t[t <= max(float(horizon), 0.0)] if horizon > 0 else t[:1]
        return np.max(np.abs(self.derivatives(t, order)), axis=0)

    def describe(self, order: int, horizon: float) -> dict:
        """Plain data for the run's LoopInfo: the kind, its keys and max |ref^(j)|, j = 0..order."""
        out = {"kind": self.kind}
        for key in KEYS_BY_KIND[self.kind]:
            v = getattr(self, key)
            out[key] = list(v) if isinstance(v, tuple) else v
        out["max_abs"] = [float(x) for x in self.max_abs(order, horizon)]
        return out

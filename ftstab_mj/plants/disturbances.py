"""Seeded signal library for the disturbance phi(t) and the actuator gain gamma(t), in chain units.

A :class:`Signal` is ``offset + amplitude * shape(t)`` with ``|shape| <= 1``, so its range is
known exactly (:meth:`Signal.bounds`) and a scenario can be checked against the bounds a robust
law assumes. ``worst_case`` is state dependent: ``offset + amplitude * sign(dV1/dz_r)``, the
disturbance that pushes V1 up hardest, since its contribution to dV1/dt is dV1/dz_r * phi
(it maximises dV1/dt; the opposite sign, sometimes printed, helps the controller).

Times in seconds, frequencies in Hz. Every random signal takes its randomness from ``seed`` only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ftstab_mj.config.errors import ParameterError
from ftstab_mj.config.limits import MAX_STATE

KINDS = ("constant", "step", "sine", "square", "chirp", "random", "worst_case")
# The keys a scenario may give for each kind (the loader refuses the others: they would do nothing).
KEYS_BY_KIND = {
    "constant": ("offset",),
    "step": ("offset", "amplitude", "t_step"),
    "sine": ("offset", "amplitude", "freq", "phase"),
    "square": ("offset", "amplitude", "freq", "phase"),
    "chirp": ("offset", "amplitude", "freq", "freq_end", "duration", "phase"),
    "random": ("offset", "amplitude", "freq", "modes"),
    "worst_case": ("offset", "amplitude"),
}
MAX_MODES = 10_000  # each value sums `modes` sinusoids, at every physics step of the run
MAX_VALUE = MAX_STATE  # |offset| + |amplitude| in a scenario: an order below MuJoCo's 1e10 "huge value" of ctrl, qacc


@dataclass(frozen=True)
class Signal:
    """offset + amplitude * shape(t).

    kind: one of KINDS.
    offset, amplitude: value units (chain units of phi or gamma); amplitude >= 0, except for a step,
      whose amplitude is signed (a step down: an actuator that loses gain at t_step).
    freq: Hz (sine, square; chirp start; random: highest frequency of the band).
    freq_end: Hz, chirp end frequency reached at t = duration.
    duration: s, chirp sweep time.
    phase: rad (sine, square, chirp).
    t_step: s, step time (shape 0 before, 1 from t_step on).
    modes: number of sinusoids summed by ``random`` (1..MAX_MODES); seed: its randomness (0..2^64 - 1).
    KEYS_BY_KIND lists which of these each kind uses.
    """

    kind: str = "constant"
    offset: float = 0.0
    amplitude: float = 0.0
    freq: float = 1.0
    freq_end: float = 10.0
    duration: float = 10.0
    phase: float = 0.0
    t_step: float = 0.0
    modes: int = 8
    seed: int = 0
    _modes: tuple = field(init=False, repr=False, compare=False)  # (freqs, phases, weights) of random

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ParameterError("kind", "one of " + ", ".join(KINDS), self.kind)
        for name in ("offset", "amplitude", "freq", "freq_end", "duration", "phase", "t_step"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not np.isfinite(v):
                raise ParameterError(name, "a finite number", v)
            object.__setattr__(self, name, float(v))
        if self.amplitude < 0 and self.kind != "step":
            raise ParameterError("amplitude", "a number >= 0 (only a step's amplitude is signed)", self.amplitude)
        if self.freq < 0 or self.freq_end < 0:
            raise ParameterError("freq", "a frequency >= 0 Hz", self.freq if self.freq < 0 else self.freq_end)
        if self.duration <= 0:
            raise ParameterError("duration", "a number > 0 (s)", self.duration)
        if isinstance(self.modes, bool) or not isinstance(self.modes, (int, np.integer)) or not 1 <= self.modes <= MAX_MODES:
            raise ParameterError("modes", f"an integer in [1, {MAX_MODES}] (each value sums this many sinusoids, "
                                 "at every physics step)", self.modes)
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or not 0 <= self.seed < 2 ** 64:
            raise ParameterError("seed", "an integer in [0, 2^64)", self.seed)
        if self.kind == "random":
            rng = np.random.default_rng(self.seed)
            freqs = rng.uniform(0.0, self.freq, self.modes)
            phases = rng.uniform(0.0, 2 * np.pi, self.modes)
            w = rng.uniform(0.2, 1.0, self.modes)
            object.__setattr__(self, "_modes", (freqs, phases, w / w.sum()))  # sum of |weights| = 1
        else:
            object.__setattr__(self, "_modes", ())

    @property
    def state_dependent(self) -> bool:
        """True when the value needs dV1/dz_r (worst case)."""
        return self.kind == "worst_case"

    def bounds(self) -> tuple[float, float]:
        """(min, max) the signal can take."""
        if self.kind == "constant":
            return (self.offset, self.offset)
        if self.kind == "step":
            return (min(self.offset, self.offset + self.amplitude), max(self.offset, self.offset + self.amplitude))
        return (self.offset - self.amplitude, self.offset + self.amplitude)

    def shape(self, t, dV1_dzr=None):
        """The unit-bounded part, elementwise over t (and dV1_dzr for the worst case)."""
        t = np.asarray(t, dtype=float)
        k = self.kind
        if k == "constant":
            return np.zeros_like(t)
        if k == "step":
            return (t >= self.t_step).astype(float)
        if k == "sine":
            return np.sin(2 * np.pi * self.freq * t + self.phase)
        if k == "square":
            return np.sign(np.sin(2 * np.pi * self.freq * t + self.phase))
        if k == "chirp":
            tc = np.minimum(t, self.duration)  # hold the end frequency after the sweep
            ph = 2 * np.pi * (self.freq * tc + (self.freq_end - self.freq) * tc ** 2 / (2 * self.duration))
            ph = ph + 2 * np.pi * self.freq_end * (t - tc)
            return np.sin(ph + self.phase)
        if k == "random":
            f, p, w = self._modes
            return np.sin(2 * np.pi * f * t[..., None] + p) @ w
        # worst case: push V1 up, i.e. maximise dV1/dz_r * phi
        if dV1_dzr is None:
            raise ParameterError("dV1_dzr", "the controller's dV1/dz_r for a worst_case signal", None)
        return np.sign(np.broadcast_to(np.asarray(dV1_dzr, dtype=float), np.broadcast(t, dV1_dzr).shape))

    def __call__(self, t, dV1_dzr=None):
        """Signal value at time t (s), elementwise."""
        return self.offset + self.amplitude * self.shape(t, dV1_dzr)

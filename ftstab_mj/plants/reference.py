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
    file       path, smooth (default 3)             samples (t, value) of a CSV file, smoothed (below)

Derivatives are exact (closed forms). A min_jerk's third derivative jumps at both ends (an r = 3
loop sees it in phi); its first two are continuous.

A file's samples t_0 < t_1 < ... (``read_samples``: one "t, value" per line) are joined by
min-jerk-like steps: on [t_k, t_k+1], ref = v_k + (v_k+1 - v_k) p_m(s), s = (t - t_k) / (t_k+1 - t_k),
with p_m the smooth step of degree 2m + 1 (m = ``smooth``) whose first m derivatives vanish at both
ends (m = 2 is the min-jerk profile). What it guarantees: ref passes through every sample, stays
between consecutive ones (no overshoot), has m continuous derivatives and a bounded (piecewise
polynomial) ref^(m+1), so a loop of chain length r <= m + 1 sees a bounded ref^(r) in phi (the loader
refuses a longer one); ref rests at each sample (its velocity is 0 there), and holds the first value
before t_0 and the last after the final sample. The samples are kept in the scenario (``times``,
``values``), so a log re-runs without the file.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ftstab_mj.config.errors import ParameterError
from ftstab_mj.config.limits import MAX_FILE_BYTES, MAX_STATE

KEYS_BY_KIND = {
    "constant": ("value",),
    "sine": ("offset", "amplitude", "freq", "phase"),
    "polynomial": ("coeffs",),
    "min_jerk": ("start", "end", "t_start", "duration"),
    "file": ("path", "smooth", "times", "values"),
}
KINDS = tuple(KEYS_BY_KIND)
MAX_COEFFS = 12  # a polynomial of degree <= 11
MAX_VALUE = MAX_STATE  # |ref| and its derivatives stay far below MuJoCo's 1e10 reset
MAX_SAMPLES = 100_000  # samples of a file reference (a 1 MiB file holds about that many lines)
MAX_SMOOTH = 8  # continuous derivatives of a file reference (the certificate's r <= 8 needs 7)


def read_samples(path) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """(times, values) of a CSV file of samples: one "t, value" per line (s; m or rad), t strictly
    increasing; blank lines, lines starting with '#' and a first line of column names are skipped.
    ParameterError("path", ...) naming the file and line when it is not so."""
    from pathlib import Path

    from ftstab_mj.config.validate import not_regular

    p = Path(path)
    found = not_regular(p)
    if found:
        raise ParameterError("path", "a CSV file of samples t, value", f"{p.name}: {found}")
    size = p.stat().st_size
    if size > MAX_FILE_BYTES:
        raise ParameterError("path", f"a CSV file of at most {MAX_FILE_BYTES} bytes (a limit)", f"{p.name}: {size} bytes")
    try:
        text = p.read_bytes().decode("utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ParameterError("path", "a readable UTF-8 CSV file of samples t, value",
                             f"{p.name}: {getattr(exc, 'strerror', None) or exc}") from None
    times, values = [], []
    for n, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        cells = [c.strip() for c in line.split(",")]
        try:
            t, v = (float(c) for c in cells) if len(cells) == 2 else (None, None)
        except ValueError:
            t = v = None
        if t is None:
            if not times and n == 1 and len(cells) == 2:  # column names
                continue
            raise ParameterError("path", "lines of two numbers t, value", f"{p.name} line {n}: {line[:60]!r}")
        if times and not t > times[-1]:
            raise ParameterError("path", "times t strictly increasing", f"{p.name} line {n}: t = {t:g} after {times[-1]:g}")
        times.append(t)
        values.append(v)
        if len(times) > MAX_SAMPLES:
            raise ParameterError("path", f"at most {MAX_SAMPLES} samples (a limit)", f"{p.name}: more")
    if len(times) < 2:
        raise ParameterError("path", "at least two samples t, value", f"{p.name}: {len(times)}")
    return tuple(times), tuple(values)


def smooth_step(m: int) -> list[np.ndarray]:
    """Coefficients (increasing powers) of p_m and its derivatives, j = 0..2m+1: p_m(s) = s^(m+1)
    sum_k C(m+k, k) (1-s)^k, p(0) = 0, p(1) = 1, p^(j)(0) = p^(j)(1) = 0 for j = 1..m."""
    P = np.polynomial.Polynomial
    p = P([0.0] * (m + 1) + [1.0]) * sum(math.comb(m + k, k) * P([1.0, -1.0]) ** k for k in range(m + 1))
    out = [p.coef]
    for _ in range(2 * m + 1):
        p = p.deriv()
        out.append(p.coef)
    return out


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
    path: str = ""
    smooth: int = 3
    times: tuple[float, ...] = ()
    values: tuple[float, ...] = ()

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
        if self.kind == "file":
            if isinstance(self.smooth, bool) or not isinstance(self.smooth, int) or not 1 <= self.smooth <= MAX_SMOOTH:
                raise ParameterError("smooth", f"an integer 1..{MAX_SMOOTH} (continuous derivatives of ref)", self.smooth)
            tv = (self.times, self.values)
            if not all(isinstance(x, tuple) and all(isinstance(y, (int, float)) and not isinstance(y, bool)
                                                    and math.isfinite(y) and abs(y) <= MAX_VALUE for y in x) for x in tv):
                raise ParameterError("times", f"finite numbers, |x| <= {MAX_VALUE:g}", "other values")
            if len(self.times) != len(self.values) or not 2 <= len(self.times) <= MAX_SAMPLES:
                raise ParameterError("times", f"as many times as values, 2 to {MAX_SAMPLES} (or a path to read them from)",
                                     f"{len(self.times)} times, {len(self.values)} values")
            if np.any(np.diff(self.times) <= 0):
                raise ParameterError("times", "times strictly increasing", "times that are not")

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
        elif self.kind == "file":
            T, V = np.array(self.times), np.array(self.values)
            k = np.clip(np.searchsorted(T, t, side="right") - 1, 0, T.size - 2)
            dt, dv = T[k + 1] - T[k], V[k + 1] - V[k]
            s = np.clip((t - T[k]) / dt, 0.0, 1.0)
            inside = (t > T[0]) & (t < T[-1])
            p = smooth_step(self.smooth)
            out[:, 0] = V[k] + dv * np.polynomial.polynomial.polyval(s, p[0])
            for j in range(1, min(order, len(p) - 1) + 1):
                out[:, j] = np.where(inside, dv * np.polynomial.polynomial.polyval(s, p[j]) / dt ** j, 0.0)
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
        if self.kind == "file":  # per segment reached by [0, horizon]: |dv| max |p^(j)| / dt^j (a whole segment's)
            T, V = np.array(self.times), np.array(self.values)
            k = np.arange(T.size - 1)
            k = k[(T[k + 1] > 0.0) & (T[k] <= max(float(horizon), 0.0))]
            s = np.linspace(0.0, 1.0, 20001)
            c = [float(np.max(np.abs(np.polynomial.polynomial.polyval(s, q)))) for q in smooth_step(self.smooth)]
            out = [float(np.max(np.abs(self.derivatives(np.array([0.0, horizon]), 0)[:, 0])))]
            if k.size:
                out[0] = max(out[0], float(np.max(np.abs(V[np.concatenate([k, k + 1])]))))  # p stays in [0, 1]
            for j in range(1, order + 1):
                out.append(float(np.max(np.abs(V[k + 1] - V[k]) * c[j] / (T[k + 1] - T[k]) ** j))
                           if k.size and j < len(c) else 0.0)
            return np.array(out)
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
        if self.kind == "file":
            out.pop("times"), out.pop("values")  # in the scenario already; the description stays short
            out["samples"] = len(self.times)
        out["max_abs"] = [float(x) for x in self.max_abs(order, horizon)]
        return out

"""The sensor of one loop: what the controller reads of the chain state z (r,).

Per control sample k, in this order:

1. selection: ``measured = "state"`` reads z_1..z_r, ``"position"`` reads z_1 only (m = r or 1
   channels; the observer then rebuilds the rest);
2. additive noise, amplitude a_c per channel: ``"uniform"`` draws from [-a_c, a_c] (bounded, the
   noise of Levant's accuracy theorems), ``"gaussian"`` from N(0, a_c^2) (a_c is the standard
   deviation; unbounded, so no accuracy bound covers it);
3. quantization with a quantum q_c per channel (an encoder's count): y = q_c round(y / q_c), ties
   to even; q_c = 0 leaves the channel continuous;
4. a delay of d whole control periods: the controller gets the reading taken d samples earlier;
   before d readings exist it gets the first one (the sensor's reading at rest).

The noise of sample k is a pure function of (seed, stream, k) (blocks of :data:`BLOCK` samples,
each drawn from its own seed sequence), so it needs no generator state: a run restored from a
saved state draws exactly the noise it would have drawn. The delay line is the sensor's only state
(d * m floats, oldest reading first).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ftstab_mj.config.errors import ParameterError

MEASURED = ("state", "position")
NOISE_KINDS = ("uniform", "gaussian")
BLOCK = 4096  # samples of noise drawn per seed sequence


@dataclass(frozen=True)
class SensorModel:
    """measured: "state" | "position"; noise, quantum: one value per measured channel (chain units of
    that component), () for none; noise_kind: "uniform" | "gaussian"; delay: control periods (int >= 0);
    seed: the noise's seed."""

    measured: str = "state"
    noise: tuple = ()
    noise_kind: str = "uniform"
    quantum: tuple = ()
    delay: int = 0
    seed: int = 0

    def __post_init__(self):
        if self.measured not in MEASURED:
            raise ParameterError("measured", " | ".join(map(repr, MEASURED)), self.measured)
        if self.noise_kind not in NOISE_KINDS:
            raise ParameterError("noise_kind", " | ".join(map(repr, NOISE_KINDS)), self.noise_kind)
        for name in ("noise", "quantum"):
            values = tuple(float(v) for v in getattr(self, name))
            if not all(np.isfinite(v) and v >= 0 for v in values):
                raise ParameterError(name, "finite numbers >= 0", getattr(self, name))
            object.__setattr__(self, name, values)
        if isinstance(self.delay, bool) or not isinstance(self.delay, (int, np.integer)) or self.delay < 0:
            raise ParameterError("delay", "a whole number of control periods >= 0", self.delay)
        object.__setattr__(self, "_cache", {})

    @property
    def ideal(self) -> bool:
        """True when the controller reads the exact state (today's behaviour)."""
        return self.measured == "state" and not any(self.noise) and not any(self.quantum) and self.delay == 0

    def channels(self, r: int) -> int:
        return r if self.measured == "state" else 1

    def check(self, r: int, path: str = "sensor") -> None:
        """ParameterError unless noise and quantum have one value per measured channel (or none)."""
        m = self.channels(r)
        for name in ("noise", "quantum"):
            if len(getattr(self, name)) not in (0, m):
                raise ParameterError(f"{path}.{name}", f"{m} value(s), one per measured channel", getattr(self, name))

    def state_size(self, r: int) -> int:
        return self.delay * self.channels(r)

    def _block(self, block: int, m: int, stream: int) -> np.ndarray:
        key = (block, m, stream)
        draws = self._cache.get(key)
        if draws is None:
            rng = np.random.default_rng([int(self.seed), int(stream), block])
            draws = (rng.uniform(-1.0, 1.0, (BLOCK, m)) if self.noise_kind == "uniform"
                     else rng.standard_normal((BLOCK, m)))
            if len(self._cache) > 4:  # a run moves forward: a few blocks are enough
                self._cache.clear()
            self._cache[key] = draws
        return draws

    def noise_at(self, k: int, m: int, stream: int = 0) -> np.ndarray:
        """The unit noise (m,) of sample k (before scaling by the amplitudes), stream: the loop's index."""
        block, i = divmod(int(k), BLOCK)
        return self._block(block, m, stream)[i]

    def noise_table(self, k0: int, n: int, m: int, stream: int = 0) -> np.ndarray:
        """The unit noise (n, m) of samples k0..k0+n-1 (the rows :meth:`noise_at` gives)."""
        out = np.empty((n, m))
        k = int(k0)
        while k < k0 + n:
            block, i = divmod(k, BLOCK)
            take = min(BLOCK - i, k0 + n - k)
            out[k - k0:k - k0 + take] = self._block(block, m, stream)[i:i + take]
            k += take
        return out

    def reading(self, z, k: int, stream: int = 0) -> np.ndarray:
        """Steps 1-3 for sample k: the selected, noisy, quantized components (m,) of z (r,)."""
        z = np.asarray(z, dtype=float)
        m = self.channels(len(z))
        y = z[:m].copy()
        if any(self.noise):
            y += np.asarray(self.noise) * self.noise_at(k, m, stream)
        if any(self.quantum):
            q = np.asarray(self.quantum)
            y = np.where(q > 0, q * np.round(y / np.where(q > 0, q, 1.0)), y)
        return y

    def initial_state(self, first_reading) -> np.ndarray:
        """The delay line at sample 0: d copies of the first reading (d * m,)."""
        return np.tile(np.asarray(first_reading, dtype=float), self.delay)

    def delayed(self, line, y):
        """Step 4: (what the controller gets (m,), the delay line one sample later)."""
        if self.delay == 0:
            return np.asarray(y, dtype=float), np.asarray(line, dtype=float)
        m = len(y)
        line = np.asarray(line, dtype=float)
        return line[:m].copy(), np.concatenate([line[m:], y])

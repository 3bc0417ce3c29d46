"""The steady oscillation of a loop over the final window, measured, and its describing-function prediction.

Measured (per signal x of m samples of period h, here z_1 and the law's u):

* the last LAST samples of the window are analysed (32.8 s at 1 ms: many cycles of any chattering),
  their mean removed (u), or for z_1 their moving average over one cycle of u's oscillation, so a
  slow motion under the chattering (the response to a slow disturbance) is not taken for it;
* **frequency** (Hz): from the crossings of zero with hysteresis (a Schmitt trigger at +-H, H = RMS / 4
  of the detrended signal, so sampling noise around zero does not count): the number of full
  cycles between the first and the last upward crossing over the time between them;
* **amplitude** (units of x): half the peak-to-peak value per cycle (between consecutive upward
  crossings), the median over the cycles (robust to one odd cycle). For a sinusoid it is its
  amplitude; for a relay's square wave of levels +-c it is c.

None when the window holds fewer than two full cycles (no steady oscillation to speak of).

Averaged power (Perez-Ventura & Fridman, arXiv:1705.09711, 2017: chattering of discontinuous and continuous
sliding-mode laws compared): the time average over the window of |z_1 z_2| (chain units^2 / s),
which for a harmonic z_1 = A sin(W t) equals A^2 W / pi: it weighs the amplitude and the frequency
together (a small fast oscillation and a large slow one may cost the same).

Predicted: the limit cycle that harmonic balance gives for the loop's law through its actuator lag
(ftstab_mj.control.describing), for a loop with an actuator lag (tau > 0).
"""

from __future__ import annotations

import functools
import json
import math

import numpy as np

HYSTERESIS = 0.25  # Schmitt trigger threshold, in RMS of the de-meaned signal
LAST = 1 << 15  # samples analysed: the window's last ones (its temporaries then stay under 1 MB)


def _upward_crossings(y, H: float):
    """Indices where y, having been below -H, first rises above +H (only the samples outside the band
    [-H, H] can flip the trigger)."""
    idx = np.flatnonzero((y > H) | (y < -H))
    high = y[idx] > H
    return idx[1:][high[1:] & ~high[:-1]]


def oscillation(x, period: float, cycle: float | None = None) -> dict:
    """{"amplitude", "frequency"} of the steady oscillation of samples x (m,) of period h s (module
    docstring); values None when fewer than two full cycles are found or x is not finite. cycle (s):
    the oscillation's period when known (from u): the moving average of x over it is removed instead
    of the mean, so a slow motion under the chattering (a disturbance's response) is not counted."""
    none = {"amplitude": None, "frequency": None}
    x = np.asarray(x, dtype=float)[-LAST:]
    if len(x) < 8 or not np.all(np.isfinite(x)):
        return none
    n = 0 if cycle is None else int(round(cycle / period))
    if 2 <= n <= len(x) // 8:  # a centred moving average over one cycle (the edges' half cycles dropped)
        c = np.concatenate([[0.0], np.cumsum(x)])
        y = x[n // 2:n // 2 + len(x) - n + 1] - (c[n:] - c[:-n]) / n
    else:
        y = x - np.mean(x)
    with np.errstate(over="ignore"):  # finite samples beyond ~1e154 (a diverged run's u): their squares overflow
        rms = math.sqrt(float(np.dot(y, y)) / len(y))
    if rms == 0.0 or rms == math.inf:  # no oscillation, or none measurable: no band [-H, H] to cross
        return none
    up = _upward_crossings(y, HYSTERESIS * rms)
    if len(up) < 3:
        return none
    cycles = len(up) - 1
    freq = cycles / ((up[-1] - up[0]) * period)
    # each cycle's max and min, y[up[k]:up[k+1]], in one pass (reduceat: the last slice ends at up[-1])
    head = y[:up[-1]]
    half_pp = 0.5 * (np.maximum.reduceat(head, up[:-1]) - np.minimum.reduceat(head, up[:-1]))
    return {"amplitude": _median(half_pp), "frequency": float(freq)}


def _median(x) -> float:
    """np.median(x) of a 1-d float array, bit for bit (the mean of the one or two middle values, a sum
    from +0.0 divided by their count), without its generic machinery (~35 us a call, twice a run);
    np.median itself where x holds NaN."""
    n = len(x)
    if n == 0 or np.isnan(x).any():
        return float(np.median(x))
    h = n // 2
    if n % 2:
        return float((0.0 + np.partition(x, h)[h]) / 1.0)
    p = np.partition(x, (h - 1, h))
    return float((0.0 + p[h - 1] + p[h]) / 2.0)


def oscillation_metrics(z1, u, period: float, z1_z2_abs_sum: float | None) -> dict:
    """The loop's oscillation keys over the final window of m samples: z1_osc_amplitude (m or rad),
    z1_osc_frequency (Hz), u_osc_amplitude (chain units of u), u_osc_frequency (Hz), averaged_power
    (z1_z2_abs_sum / m: the window's sum of |z_1 z_2|, None for r = 1)."""
    ou = oscillation(u, period)  # u switches cleanly: its cycle separates z_1's chattering from slow motion
    oz = oscillation(z1, period, None if ou["frequency"] is None else 1.0 / ou["frequency"])
    ap = None if z1_z2_abs_sum is None or not len(z1) else float(z1_z2_abs_sum) / len(z1)
    return {"z1_osc_amplitude": oz["amplitude"], "z1_osc_frequency": oz["frequency"],
            "u_osc_amplitude": ou["amplitude"], "u_osc_frequency": ou["frequency"],
            "averaged_power": ap if ap is None or math.isfinite(ap) else None}


def predicted_limit_cycle(loop, period: float) -> dict | None:
    """The describing-function limit cycle (LimitCycle.as_dict, plus "delay" s) of a loop (LoopInfo)
    with an actuator lag, its law rebuilt from the log's parameters; the sampled law's delay h / 2 plus
    the sensor's whole periods. None without a lag, or when harmonic balance has no solution."""
    from ftstab_mj.control.law import declared

    stages = getattr(loop, "stages", None)
    act = stages and stages.get("actuator")
    if not act or not act.get("tau"):
        return None
    cls = declared(loop.law)
    if cls is None:
        return None
    values = {p.name: p.default for p in cls.all_params() if not p.required}
    values.update({k: v for k, v in (loop.hong or {}).items() if k != "r"})
    values.update(loop.law_params or {})
    delay = period * (0.5 + stages["sensor"].get("delay", 0))
    try:
        key = json.dumps(values, sort_keys=True, default=repr)
    except (TypeError, ValueError):
        return None
    lc = _predicted(cls, loop.r, key, period, float(act["tau"]), int(act.get("lag_order", 1)), delay)
    return None if lc is None else {**lc, "delay": delay}


@functools.lru_cache(maxsize=256)
def _predicted(cls, r: int, values_json: str, period: float, tau: float, lag_order: int, delay: float):
    """predicted_limit_cycle's harmonic balance (about 0.7 s CPU for Hong's law), once per law, parameters
    and actuator in a process: the rows of a sweep or a comparison that differ in anything else (seed,
    initial state, integrator, plant mass) share it."""
    from ftstab_mj.config.errors import ParameterError
    from ftstab_mj.control.describing import harmonic_balance

    try:
        law = cls.from_params(r, json.loads(values_json)).for_period(period)
    except (ParameterError, KeyError, TypeError, ValueError):  # a log whose parameters this version cannot rebuild: nothing is predicted
        return None
    lc = harmonic_balance(law, tau, lag_order, delay, w_range=(1e-2 / tau, math.pi / period))
    return None if lc is None else lc.as_dict()

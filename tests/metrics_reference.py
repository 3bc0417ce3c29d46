"""The metrics' definitions over whole arrays: the references the streaming metrics (metrics/run_metrics.py,
batch by batch, in flat memory) are checked against. Chain units; t in s."""

import numpy as np

from ftstab_mj.metrics.run_metrics import _num  # the metrics' rounding of non-finite values


def settle_time(t, V1, level):
    """Settling time (s): the first sample time from which V1 <= level until the end of the run.

    One-period resolution. t[0] when V1 is never above level; None when the last sample is above it
    (not settled) or V1 is NaN there.
    """
    above = ~(V1 <= level)  # NaN counts as above
    if not above.any():
        return float(t[0])
    last = int(np.flatnonzero(above)[-1])
    return None if last == len(t) - 1 else float(t[last + 1])


def estimation_error(z_hat, z):
    """Per component i: (max |z_hat_i - z_i|, RMS of it) over the samples given, lists of r (chain units)."""
    e = np.abs(np.asarray(z_hat) - np.asarray(z))
    return [_num(x) for x in e.max(axis=0)], [_num(x) for x in np.sqrt(np.mean(e * e, axis=0))]


def final_abs_max(z_final):
    """Final accuracy per state component: max |z_i| over the final window, list of r (chain units)."""
    return [_num(np.max(np.abs(z_final[:, i]))) for i in range(z_final.shape[1])]


def effort(u, period):
    """Control effort over the whole run with u held per period h.

    Returns (integral |u| dt = h sum |u_k|, integral u^2 dt = h sum u_k^2, max |u_k|); units: u s, u^2 s, u.
    """
    return (_num(period * np.sum(np.abs(u))), _num(period * np.sum(u * u)), _num(np.max(np.abs(u))))


def eps_ball(t, V1, eps):
    """First entry into the eps-ball {V1 <= eps} and what V1 does afterwards.

    Returns (entry time s or None, min V1 from the entry on, max V1 from the entry on);
    (None, None, None) when V1 never enters.
    """
    inside = np.flatnonzero(V1 <= eps)
    if inside.size == 0:
        return None, None, None
    after = V1[inside[0]:]
    return float(t[inside[0]]), _num(np.min(after)), _num(np.max(after))

"""Metrics of a run, computed from the logged arrays only (same code live and on replay).

A run streams them (:class:`MetricsStream`: each batch reduced as it comes, only the samples the
final window may need kept, in a temporary file once they pass 1 MiB); a replay hands the log's arrays
the same way (:func:`compute_metrics`). Both give the same bits whatever the batching (the effort sums are block sums,
_BlockSum).

:func:`compute_metrics` maps a :class:`~ftstab_mj.simulation.records.RunInfo`, the samples of every loop
({loop name: {field: array}}, fields of ``records.LOOP_FIELDS``, and ``STAGE_FIELDS`` for a loop
with a sensor, observer or actuator model) and the run status to a plain
JSON-able dict::

    {"status": str, "n_samples": int, "duration": s, "loops": {name: {metric: value}}}

Every per-loop metric is defined by one function below (docstring: definition and units).
Undefined or non-finite values are ``None`` (JSON null). Samples are read as the log stores
them: non-finite entries count as NaN, so a live run and its replay give identical dicts.

"The final window" is the last ``MetricSettings.final_fraction`` of the run's duration, and at most
its last ``MetricSettings.final_window_max`` seconds (at least one sample; :func:`final_window_start`);
"period" is the control period h: each sample's u is held for h.
"""

from __future__ import annotations

import bisect
import contextlib
import math
import threading
import warnings

import numpy as np

from ftstab_mj.control.interval import Iv
from ftstab_mj.control.law import declared
from ftstab_mj.metrics.oscillation import LAST as OSC_LAST, oscillation_metrics, predicted_limit_cycle
from ftstab_mj.simulation.records import RunInfo, format_table  # noqa: F401 - format_table is part of this API


def _num(x):
    """A JSON-able float (None when not finite)."""
    x = float(x)
    return x if math.isfinite(x) else None


def _certificate(r: int, k: float, gains: tuple, form: str, max_boxes: int, progress=None):
    """certify() of Hong's controller within max_boxes boxes per bound, computed once per parameter
    set and limit (ftstab_mj.metrics.certificate_cache)."""
    from ftstab_mj.metrics.certificate_cache import cached_certify

    return cached_certify(r, k, gains, form, max_boxes=max_boxes, progress=progress)


# Metrics that depend on the certificate. Logs recorded before the sound certificate (their loop
# metrics have no "certificate" entry) used a sampled estimate of c: replay explains, not fails, there.
CERTIFICATE_DERIVED = ("time_bound", "bound_applies", "beat_bound", "theorem3")
CERTIFICATE_METHOD = "interval branch and bound"


def certificate_summary(loop):
    """The loop's certificate as logged: {"method", "status", "c_lower", "c_upper", "c_prime_upper",
    "c_prime_lower", "boxes", "box_limit", "note"} (c' bracketed as c is; boxes: evaluated by the
    branch and bound; box_limit: the run's certificate_boxes, per bound; note: what the status
    guarantees when the limit stopped the B&B, see :func:`certificate_note`). None for a law not
    built on Hong's controller."""
    if not loop.hong:
        return None
    cert = loop_certificate(loop)
    return {"method": CERTIFICATE_METHOD, "status": cert.status, "c_lower": _num_or_none(cert.c_lower),
            "c_upper": _num_or_none(cert.c_upper), "c_prime_upper": _num_or_none(cert.c_prime_upper),
            "c_prime_lower": _num_or_none(cert.c_prime_lower), "boxes": int(cert.boxes),
            "box_limit": int(loop.certificate_boxes), "note": certificate_note(cert, loop.certificate_boxes)}


def certificate_note(cert, box_limit: int) -> str:
    """What a run's certificate guarantees, in words, where it is not plain: undecided within the
    work limit (no T(z0)), or certified with the gap still open at the limit (T(z0) guaranteed, from
    c_lower, but looser than at convergence); "" for a converged certificate; the witness's note
    for "not certified"."""
    from ftstab_mj.control.certificate import CERTIFIED, DEFAULT_RTOL, UNDECIDED

    if cert.form != "full":
        return cert.note
    if cert.status == UNDECIDED:
        return (f"undecided within {box_limit} boxes (metrics.certificate_boxes): c > 0 is not proven, so "
                "the run claims no T(z0) and no Theorem 3 bound; raise metrics.certificate_boxes")
    if cert.status == CERTIFIED and cert.gap is not None and cert.gap > DEFAULT_RTOL:
        return (f"certified within {box_limit} boxes (metrics.certificate_boxes) with the gap still "
                f"{100 * cert.gap:.3g} % (the branch and bound stops at {100 * DEFAULT_RTOL:g} %): c >= c_lower "
                "is guaranteed, so is T(z0) from it, looser than with a closed gap")
    return "" if cert.status == CERTIFIED else cert.note


def certificate_moved(recorded: dict | None, now: dict | None) -> bool:
    """Whether two logged certificate summaries (certificate_summary) of one controller differ only as
    two sound computations of it may: another version of the branch and bound stops elsewhere inside
    its gap. Both give c_lower <= c <= c_upper (and c' inside its bracket), so where both are sound
    their brackets overlap and their statuses agree; brackets that do not overlap mean one of them is
    wrong. False when either is missing or they are equal."""
    if not recorded or not now or recorded == now or recorded.get("status") != now.get("status"):
        return False

    def overlap(lo, hi):
        a, b = recorded.get(lo), recorded.get(hi)
        c, d = now.get(lo), now.get(hi)
        if None in (a, b, c, d):  # an end not computed (c' of an uncertified law): nothing to contradict
            return (a is None) == (c is None) and (b is None) == (d is None)
        return a <= d and c <= b

    return overlap("c_lower", "c_upper") and overlap("c_prime_lower", "c_prime_upper")


def _num_or_none(x):
    return None if x is None else _num(x)


def loop_certificate(loop, progress=None):
    """The Certificate of a LoopInfo's Hong controller within its work limit (cached). progress(text):
    called now and then while it is computed (a cache hit calls nothing)."""
    h = loop.hong
    return _certificate(int(h["r"]), float(h["k"]), tuple(float(g) for g in h["gains"]), h.get("form", "full"),
                        int(loop.certificate_boxes), progress)


PROGRESS_AFTER = 0.5  # s: a certificate computed faster than this shows no status line


def run_certificates(info, progress=None) -> None:
    """Compute (or find in the cache) the certificate of every loop of a run (RunInfo), before its
    logs are opened: a first r >= 5 run may spend a while here, and a signal must still stop it.
    progress(text): a status line for a terminal naming the loop, once a computation has lasted
    PROGRESS_AFTER s and then at most every 0.2 s; "" at the end (clear the line)."""
    import time

    for loop in info.loops:
        if not loop.hong:
            continue
        start, last = time.monotonic(), [0.0]

        def say(text, name=loop.name, r=loop.r, n=loop.certificate_boxes, start=start):
            now = time.monotonic()
            if now - start >= PROGRESS_AFTER and now - last[0] >= 0.2:
                last[0] = now
                progress(f"certificate of loop {name} (r = {r}, at most {n} boxes per bound): {text}")

        loop_certificate(loop, None if progress is None else say)
    if progress is not None:
        progress("")  # the status line is cleared (a no-op where nothing was said)


# -- per-loop metric definitions -------------------------------------------------------------------

def _is_finite_number(x) -> bool:
    """True for a finite number; False for inf and for None (an infinite bound after JSON, where
    it is written as null)."""
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _ultimate_bound(loop) -> dict | None:
    """Theorem 3's constants of ``loop``'s law when it declares its ultimate bounds, else None."""
    law = declared(loop.law)
    return law.ultimate_bound(loop.law_params) if law is not None else None


def bound_applies(loop) -> bool:
    """Whether Theorem 1's time bound T(z0) is a guarantee for this loop (chain units).

    Asked of the law (its ``time_bound`` and ``bound_holds``: the nominal law without disturbance and
    with gamma = 1, the robust law when the true bounds are within the assumed ones; the adaptive law
    never: Theorem 3 gives ultimate bounds, not a time). Never without a sound certificate (status
    "certified": c_lower > 0), never for a law this process does not know. :func:`bound_denied` says why not.
    """
    return bound_denied(loop) is None


def v1_label(loop, name: str = "V1") -> str:
    """The label of a loop's V1 curve in the report and the viewers: on the simplified form (Proposition 1
    as printed, homogeneous of degree k/(1+k) with weights (1+ik)/(1+k)) V1 is not a Lyapunov function,
    and a law built on it has no proof; the label says so."""
    if loop.hong and loop.hong.get("form", "full") == "simplified":
        return f"{name} (simplified form: not a Lyapunov function, no proof)"
    return name


def bound_denied(loop) -> str | None:
    """Why Theorem 1's time bound is not a guarantee for this loop (one phrase), None when it is."""
    if not _is_finite_number(loop.true_phibar):
        return "the plant's disturbance has no known bound"  # e.g. a damped cart: nothing is guaranteed
    law = declared(loop.law)
    if law is None:
        return f"law {loop.law!r} is not known to this process"
    if not law.time_bound:
        return f"law {loop.law!r} claims no time bound"
    if loop.hong and loop.hong.get("form", "full") == "simplified":
        return ("the simplified form (Proposition 1 as printed) is homogeneous of degree k/(1+k), and its V1 "
                "is not a Lyapunov function: the robust law on it has no proof")
    if loop.hong and not loop_certificate(loop).certified:
        return f"no sound certificate ({loop_certificate(loop).status})"
    if not law.bound_holds(loop.law_params, loop.true_phibar, loop.true_gamma_m, loop.true_gamma_M):
        return (f"the plant leaves the law's bounds (true |phi| <= {loop.true_phibar:.4g}, gamma in "
                f"[{loop.true_gamma_m:.4g}, {loop.true_gamma_M:.4g}])")
    return None


class AssumedBounds:
    """Where the logged true phi and gamma first left the bounds the law assumes (Theorem 2's
    hypothesis, checked at the samples): the law's own ``bound_holds`` on the running max |phi| and
    range of gamma (chain units), so a plant's computed bounds that did not hold (a passive joint
    out of its workspace, a contact) are caught by what MuJoCo computed. Fed batches in order."""

    def __init__(self, loop):
        self.loop, self.law = loop, declared(loop.law)
        self.phi, self.g_lo, self.g_hi = 0.0, math.inf, -math.inf  # over the samples so far
        self.reason = None  # the first departure, a sentence

    # The logged phi and gamma are MuJoCo's float64 recomputation of the quantities a plant's bounds were
    # computed from (e.g. gamma_m met with equality at the start pose): they may differ from them by rounding,
    # a few hundred ulps of the mass matrix's factorisation. A departure smaller than this (relative) is that.
    ROUNDING = 1e-12

    def _holds(self, phi, g_lo, g_hi) -> bool:
        r, p = self.ROUNDING, self.loop.law_params
        return bool(self.law.bound_holds(p, phi, g_lo, g_hi)  # as logged (a law may ask equality: gamma = 1)
                    or self.law.bound_holds(p, phi * (1 - r), g_lo + r * abs(g_lo), g_hi - r * abs(g_hi)))

    def update(self, t, phi, gamma) -> None:
        if self.reason is not None or len(t) == 0:
            return
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # NaN (a diverged run) is skipped by fmax/fmin
            cphi = np.fmax.accumulate(np.concatenate([[self.phi], np.abs(phi)]))
            clo = np.fmin.accumulate(np.concatenate([[self.g_lo], gamma]))
            chi = np.fmax.accumulate(np.concatenate([[self.g_hi], gamma]))
        if self._holds(cphi[-1], clo[-1], chi[-1]):
            self.phi, self.g_lo, self.g_hi = float(cphi[-1]), float(clo[-1]), float(chi[-1])
            return
        lo, hi = 1, len(cphi) - 1  # the running extremes only grow: bisect for the first failing sample
        while lo < hi:
            mid = (lo + hi) // 2
            if self._holds(cphi[mid], clo[mid], chi[mid]):
                lo = mid + 1
            else:
                hi = mid
        k, p = lo, self.loop.law_params
        assumed = ", ".join(f"{key} = {p[key]:.4g}" for key in ("phibar", "gamma_m", "gamma_M") if _is_finite_number(p.get(key)))
        if not self._holds(cphi[k], clo[k - 1], chi[k - 1]):
            what = f"|phi| reached {abs(float(phi[k - 1])):.4g}"
        else:
            what = f"gamma reached {float(gamma[k - 1]):.4g}"
        self.reason = (f"loop {self.loop.name!r}: the logged true {what} at t = {float(t[k - 1]):.6g} s, outside the "
                       f"bounds the law assumed ({assumed})")


def reference_cover(loop) -> dict:
    """Whether the law's phibar covers a tracked reference: phi of the error chain holds -ref^(r)
    (z_r' = q^(r) - ref^(r)), so phibar must bound the plant's |phi| plus max |ref^(r)| over the run.
    ``reference_r_max_abs``: max |ref^(r)| (chain units); ``phibar_covers_reference``: phibar >= the
    true bound (the plant's, which includes it) when that is finite; false when phibar < max |ref^(r)|
    alone; None when the plant's own bound is unknown (infinite) or the law assumes no phibar."""
    need = float(loop.reference["max_abs"][loop.r])
    phibar = loop.law_params.get("phibar")
    if not _is_finite_number(phibar):
        covers = None
    elif phibar < need:
        covers = False
    else:
        covers = bool(phibar >= loop.true_phibar) if _is_finite_number(loop.true_phibar) else None
    return {"reference_r_max_abs": _num(need), "phibar_covers_reference": covers}


def stage_reasons(stages: dict | None) -> list[str]:
    """Why the paper's guarantee does not cover a loop with these stages (LoopInfo.stages): the
    theorems assume the exact state and an actuator that delivers any u at once. [] when it does:
    no stage, or only a saturation above what the law needs (``u_needed``, a sampled estimate)."""
    if not stages:
        return []
    out = []
    sensor, obs, act = stages["sensor"], stages["observer"], stages["actuator"]
    if obs is not None:
        out.append(f"the law uses the {obs['kind']} observer's estimate, not the state")
    if sensor["measured"] == "state":
        parts = [w for w, on in (("noise", any(sensor["noise"])), ("quantization", any(sensor["quantum"])),
                                 (f"a delay of {sensor['delay']} periods", sensor["delay"])) if on]
        if parts:
            out.append("the law reads the state with " + ", ".join(parts))
    for key, what in (("tau", "an actuator lag"), ("rate_max", "an actuator rate limit"),
                      ("dead_zone", "an actuator dead zone")):
        if act[key]:
            out.append(f"{what} ({key} = {act[key]:g}" + (f", order {act['lag_order']})" if key == "tau" else ")"))
    u_max, need = act["u_max"], stages["u_needed"]
    if u_max is not None:
        if need is None:
            out.append(f"saturation at u_max = {u_max:g}, and {stages['u_needed_note']}")
        elif u_max < need:
            out.append(f"the guarantee needs |u| up to {need:.4g} > u_max = {u_max:g} ({stages['u_needed_note']})")
    return out


def saturated_time(u, stages: dict, period: float) -> float:
    """Time (s) during which the law asked for more than the actuator's u_max gives, |u| - dead_zone > u_max
    (0 without saturation)."""
    u_max = stages["actuator"]["u_max"]
    if u_max is None:
        return 0.0
    return float(np.count_nonzero(np.abs(u) - stages["actuator"]["dead_zone"] > u_max) * period)


# {((r, k, gains), shape, z0 bytes): V1(z0) enclosure}: a sweep's rows mostly share the law and z0, and
# the enclosure of V1(z0) in intervals costs ~2 ms a row (of ~10 on the cart); the most recent last
_V1_ENCLOSURES: dict = {}
_V1_LOCK = threading.Lock()  # the batch engine's rows run on threads: two evicting at once would delete one key twice
V1_ENCLOSURES_KEPT = 256
# {(r, k, gains): [({z0 bytes: index}, lo (n,), hi (n,))]}: the states of Monte Carlos under way
# (V1_enclosures_ahead), each state's entry taken by its run
_V1_AHEAD: dict = {}
AHEAD_CHUNK = 1 << 16  # states enclosed per call: the interval temporaries stay ~100 MB at r = 5


def _controller_args(hong: dict) -> tuple:
    return int(hong["r"]), float(hong["k"]), tuple(float(g) for g in hong["gains"])


@contextlib.contextmanager
def V1_enclosures_ahead(hong: dict, Z0):
    """Within the block, a run of Hong's controller ``hong`` (LoopInfo.hong) whose z0 is a row of Z0 (n, r)
    finds the enclosure of V1(z0) computed ahead for all of Z0 at once (a Monte Carlo on the plant: one
    vectorised call instead of ~1.4 ms per state at r = 2). certificate.V1_enclosure is elementwise (every
    interval operation acts on each element alone), so a row's enclosure is the bits its run would compute
    alone (tests/test_montecarlo.py checks it). A run whose z0 is not in Z0 computes its own."""
    from ftstab_mj.control.certificate import V1_enclosure

    args = _controller_args(hong)
    Z0 = np.asarray(Z0, dtype=float)
    rows = np.flatnonzero(np.isfinite(Z0).all(axis=1)) if Z0.ndim == 2 and Z0.shape[1] == args[0] else []
    lo, hi = np.empty(len(rows)), np.empty(len(rows))
    for a in range(0, len(rows), AHEAD_CHUNK):
        E = V1_enclosure(*args, Z0[rows[a:a + AHEAD_CHUNK]])
        lo[a:a + AHEAD_CHUNK], hi[a:a + AHEAD_CHUNK] = E.lo, E.hi
    entry = ({Z0[j:j + 1].tobytes(): i for i, j in enumerate(rows)}, lo, hi)
    _V1_AHEAD.setdefault(args, []).append(entry)
    try:
        yield
    finally:
        kept = _V1_AHEAD.get(args, [])
        kept[:] = [e for e in kept if e is not entry]
        if not kept:
            _V1_AHEAD.pop(args, None)


def _V1_ahead(args: tuple, rows):
    """The enclosure of V1 at the one state rows (1, r) computed ahead (V1_enclosures_ahead), or None."""
    if rows.shape[0] != 1:
        return None
    key = rows.tobytes()
    for index, lo, hi in list(_V1_AHEAD.get(args, ())):
        i = index.pop(key, None)  # each state's run takes its entry: the index shrinks as the rows run
        if i is not None:
            return Iv(lo[i:i + 1].copy(), hi[i:i + 1].copy())
    return None


def _V1_enclosure(hong: dict, rows):
    """certificate.V1_enclosure of the states rows (n, r) under Hong's controller ``hong`` (its r, k,
    gains); a run's own z0 (at most 64 numbers) is kept per controller, so the rows of a sweep that
    share it (about 2 ms each) pay once, and a Monte Carlo's states are enclosed ahead
    (V1_enclosures_ahead). The certificate is applied to it afresh by the caller."""
    from ftstab_mj.control.certificate import V1_enclosure

    args = _controller_args(hong)
    ahead = _V1_ahead(args, rows) if _V1_AHEAD else None
    if ahead is not None:
        return ahead
    key = (args, rows.shape, rows.tobytes()) if rows.size <= 64 else None  # not a Monte Carlo's states
    with _V1_LOCK:
        kept = _V1_ENCLOSURES.pop(key, None) if key is not None else None
    V = kept if kept is not None else V1_enclosure(*args, rows)
    if key is not None:
        with _V1_LOCK:
            _V1_ENCLOSURES[key] = V
            while len(_V1_ENCLOSURES) > V1_ENCLOSURES_KEPT:
                del _V1_ENCLOSURES[next(iter(_V1_ENCLOSURES))]
    return V


def time_bound(loop, z0):
    """Theorem 1's bound (s) on the time to reach the origin from z0 (r floats, chain units):
    V1(z0)^(1-alpha) / (c_lower (1-alpha)), a guaranteed upper bound (V1(z0) enclosed and every step
    rounded outward: Certificate.time_bound). None when the certificate does not hold (c <= 0, or
    the simplified form, which has none). z0 (n, r): an array (n,), NaN where there is no bound.
    """
    z0 = np.asarray(z0, dtype=float)
    rows = np.atleast_2d(z0)
    out = np.full(len(rows), np.nan)
    if loop.hong and loop_certificate(loop).certified:  # else Theorem 1 says nothing
        ok = np.isfinite(rows).all(axis=1)
        out[ok] = loop_certificate(loop).time_bound(_V1_enclosure(loop.hong, rows[ok]))
    out[~np.isfinite(out)] = np.nan
    return out if z0.ndim == 2 else _num_or_none(None if np.isnan(out[0]) else out[0])


ENVELOPE_POINTS = 400  # samples of the drawn envelope (a smooth curve on a log axis)


def envelope(cert, V1_0: float, duration: float, n: int = ENVELOPE_POINTS, T: float | None = None):
    """Theorem 1's envelope from V1(0) = V1_0: (t (m,), V1 bound (m,)) on [0, min(T, duration)],
    and T(z0) (s, inf when the certificate gives none). From dV1/dt <= -c V1^alpha the comparison
    lemma gives V1(t) <= (V1_0^(1-alpha) - c (1-alpha) t)^(1/(1-alpha)) until T(z0) =
    V1_0^(1-alpha) / (c (1-alpha)) (chain units); the points are guaranteed upper bounds of it,
    computed from the guaranteed T (Certificate.V1_bound). T: the run's :func:`time_bound` of z0 where
    the caller has it (the same guaranteed number as the metrics; else Certificate.time_bound of
    V1_0). What it guarantees for the sampled loop: :func:`envelope_kind`."""
    if T is None:
        T = float(cert.time_bound(V1_0)) if cert is not None and cert.certified else math.inf
    if not math.isfinite(T) or not V1_0 > 0:
        return np.empty(0), np.empty(0), T
    t = np.linspace(0.0, min(T, duration), n)
    return t, cert.V1_bound(T, t), T


def envelope_kind(m: dict) -> str:
    """What Theorem 1's envelope is for a loop whose metrics are ``m``: a continuous-time guarantee
    only where ``m["bound_applies"]`` (the sampled loop settles into an O(h) band, so its V1 may
    cross the envelope once that small); else "not a guarantee" and why."""
    if m.get("bound_applies"):
        return "continuous-time guarantee"
    cert = m.get("certificate")
    if cert and cert.get("status") != "certified":
        return f"not a guarantee: the certificate is {cert['status']}" + (
            f" within {cert['box_limit']} boxes" if cert["status"] == "undecided" and cert.get("box_limit") else "")
    reason = m.get("workspace_left") or m.get("bound_applies_reason")
    return f"not a guarantee: {reason}" if reason else "not a guarantee: the true bounds exceed the assumed ones"


def final_window_start(t0: float, n: int, h: float, ms) -> float:
    """Where the final window of n samples of period h from t0 starts (s): the window is the samples with
    t_k >= t0 + (1 - final_fraction) n h, or t_k >= t0 + n h - final_window_max when that is later (a run
    longer than final_window_max / final_fraction: the window's length, and the memory its chattering
    indices need, stop growing with the run's). ms: MetricSettings."""
    cap = ms.final_window_max
    if cap is not None and ms.final_fraction * n * h > cap:
        return t0 + (n * h - cap)
    return t0 + (1.0 - ms.final_fraction) * n * h


def chattering(u_final, period):
    """Chattering: total variation of u over the final window per second, sum |u_{k+1} - u_k| / (m h).

    Units: u units per second; m the number of samples of the window. 0 for a one-sample window.
    """
    d = np.diff(u_final)
    return _num(np.sum(np.abs(d, out=d)) / (len(u_final) * period))  # (in place: one array of the window's size)


def du_dt_variance(u_final, period):
    """Chattering: variance of the control rate du/dt = (u_{k+1} - u_k) / h over the final window.

    Units: (u units per second)^2. 0 for a window of fewer than two samples.
    """
    if len(u_final) < 2:
        return 0.0
    d = np.diff(u_final)
    d /= period
    # np.var(d) with its own steps (mean = sum / m, then the sum of squared deviations / m), in place
    d -= np.sum(d) / len(d)
    d *= d
    return _num(np.sum(d) / len(d))


def zero_crossing_rate(u_final, period):
    """Chattering: sign changes of u per second over the final window (Hz).

    A sign change is counted between consecutive non-zero samples of opposite sign (exact zeros are
    skipped, so 1, 0, -1 is one change). Over m samples of period h the rate is changes / (m h).
    """
    changes, before = 0, 0.0  # counted in blocks (the sign of the last non-zero sample carried over)
    for i in range(0, len(u_final), 1 << 16):
        s = np.sign(u_final[i:i + (1 << 16)])
        s = s[np.isfinite(s) & (s != 0)]
        if s.size:
            changes += int(np.count_nonzero(s[1:] != s[:-1])) + int(before != 0.0 and s[0] != before)
            before = s[-1]
    return _num(changes / (len(u_final) * period))


def band_rms(u_final, period, band):
    """Chattering: RMS of u in the frequency band (low, high) Hz over the final window, from its FFT.

    With U_j = FFT(u)_j of m samples, |U_j| 2 / m is the amplitude of the sinusoid at f_j = j / (m h),
    and I = sqrt(sum_{low <= f_j <= high, 0 < f_j} (2 |U_j| / m)^2 / 2): a sinusoid of amplitude A inside
    the band gives A / sqrt(2), its RMS (the Nyquist bin, without a mirror, counts once: (|U|/m)^2).
    The mean (f = 0) is never counted. Units: u units. The band is clipped to the Nyquist frequency.
    """
    m = len(u_final)
    if m < 2:
        return 0.0
    U = np.fft.rfft(u_final)
    # the bins in the band, j0..j1, with f_j = j / (m h) computed as np.fft.rfftfreq does (j * (1 / (m h))):
    # only they are squared and summed, so a long window costs its spectrum U and no more
    val, last = 1.0 / (m * period), len(U) - 1
    j0 = max(1, bisect.bisect_left(range(len(U)), band[0], key=lambda j: j * val))  # f > 0, f >= low
    j1 = bisect.bisect_right(range(len(U)), band[1], key=lambda j: j * val) - 1  # f <= high
    amp2 = (2.0 * np.abs(U[j0:j1 + 1]) / m) ** 2 / 2.0
    if m % 2 == 0 and j0 <= last == j1:
        amp2[-1] = (np.abs(U[-1]) / m) ** 2  # the Nyquist bin has no mirror image
    return _num(np.sqrt(np.sum(amp2)))


_EXTREME_R = 8  # chain lengths the workspace check reads (z_2 .. z_8; the certificate's r <= 8)


def extremes(z, u) -> np.ndarray:
    """(min z_1, max z_1, max |u|, max |z_2|, ..., max |z_8|) of samples z (n, r), u (n,), NaN ignored
    (NaN when all are NaN, and for i > r): what :func:`workspace_left` reads. Per-batch extremes
    combine exactly with np.fmin (the first) and np.fmax (the others)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an all-NaN batch (a diverged run)
        z1 = z[:, 0]
        higher = [np.nanmax(np.abs(z[:, i])) if z.shape[1] > i else np.nan for i in range(1, _EXTREME_R)]
        return np.array([np.nanmin(z1), np.nanmax(z1), np.nanmax(np.abs(u)), *higher])


def workspace_left(loop, z, u) -> str | None:
    """What left the region where the loop's true bounds hold (LoopInfo.workspace), "" when
    nothing did, None when the bounds hold everywhere. z (n, r) and u (n,) are the samples."""
    return _workspace_text(loop, extremes(z, u))


def _workspace_text(loop, ext) -> str | None:
    """:func:`workspace_left` from the samples' :func:`extremes`: every bound the workspace states
    (z1_min/z1_max, z<i>_abs_max for each i it names, u_abs_max) is checked; a bound the plant's
    guarantee needs but the workspace does not state would be a plant's bug, not a pass."""
    w = loop.workspace
    if w is None:
        return None
    out = []
    z1_min, z1_max, u_max = (float(x) for x in ext[:3])
    if z1_min < w["z1_min"] or z1_max > w["z1_max"]:
        out.append(f"z_1 spanned [{z1_min:.3g}, {z1_max:.3g}], outside [{w['z1_min']:g}, {w['z1_max']:g}]")
    for i in range(2, _EXTREME_R + 1):
        key = f"z{i}_abs_max"
        if key in w and float(ext[i + 1]) > w[key]:
            out.append(f"|z_{i}| reached {float(ext[i + 1]):.3g} > {w[key]:g}")
    if u_max > w["u_abs_max"]:
        out.append(f"|u| reached {u_max:.3g} > {w['u_abs_max']:g}")
    return "; ".join(out)


def theorem3_check(loop, v_max, ph_max, v_min):
    """Theorem 3's bounds (true phibar, gamma_m) and whether the final window respects them, from
    the window's max V1 (v_max), max phi_hat (ph_max) and min V1 (v_min).

    Delta: limsup V1 <= Delta, checked as max V1 over the final window <= Delta (their ratio:
    V1_max_over_Delta);
    phi_hat_limsup: checked as max phi_hat over the final window <= it; eps_reached: min V1 over
    the final window <= eps (liminf V1 <= eps). None for non-adaptive laws or without certificate.
    """
    from ftstab_mj.control import theorem3_bounds

    p = _ultimate_bound(loop)
    if p is None:
        return None
    cert = loop_certificate(loop)
    if not cert.certified or not _is_finite_number(loop.true_phibar):
        return None  # (an unbounded plant, e.g. a damped cart, gives Theorem 3 nothing to check)
    b = theorem3_bounds(cert, loop.true_phibar, loop.true_gamma_m, p["kappa"], p["delta"], p["rate"], p["eps"])
    v_max, ph_max, v_min = float(v_max), float(ph_max), float(v_min)
    return {
        "Phibar": _num(b.Phibar), "Delta": _num(b.Delta), "phi_hat_limsup": _num(b.phi_hat_limsup),
        "V1_max_final": _num(v_max), "Delta_held": bool(v_max <= b.Delta),
        # how tight Theorem 3 is on this run: 1 would be a bound reached; the sweep theorem3_tightness
        "V1_max_over_Delta": _num(v_max / b.Delta) if b.Delta > 0 else None,
        "phi_hat_max_final": _num(ph_max),
        # None at k = 0, where Theorem 3 gives no finite bound (see theorem3_bounds)
        "phi_hat_bound_held": bool(ph_max <= b.phi_hat_limsup) if np.isfinite(b.phi_hat_limsup) else None,
        "V1_min_final": _num(v_min), "eps_reached": bool(v_min <= p["eps"]),
    }


def _finite_or_nan(a):
    a = np.asarray(a, dtype=float)
    return np.where(np.isfinite(a), a, np.nan)


# -- streaming: the metrics of a run as its batches arrive ------------------------------------------

# Theorem 1's guarantee along one run: what a Monte Carlo keeps of each trajectory (a MetricsStream
# selection), and the recorded fields they are computed from
GUARANTEE_METRICS = ("z0", "V1_initial", "V1_final", "settle_level", "settle_time", "time_bound",
                     "workspace_left", "bound_applies", "bound_applies_reason", "u_max_abs")
_GUARANTEE_FIELDS = frozenset(("t", "z", "u", "V1", "phi", "gamma", "u_applied"))


class _SettleTracker:
    """:func:`settle_time` on a stream: the last sample above the level and the time of the one after."""

    def __init__(self, level: float):
        self.level = level
        self.last_above = -1  # index of the last sample with x above the level (NaN counts as above)
        self.t_after = None  # time of the sample after it (None until it has arrived)

    def update(self, n_before: int, t, x) -> None:
        if self.last_above == n_before - 1 and n_before:  # the previous batch ended above the level
            self.t_after = float(t[0])
        above = np.flatnonzero(~(x <= self.level))
        if above.size:
            i = int(above[-1])
            self.last_above = n_before + i
            self.t_after = float(t[i + 1]) if i + 1 < len(t) else None

    def result(self, n: int, t0: float):
        if self.last_above < 0:
            return t0
        return None if self.last_above == n - 1 else self.t_after


class _BlockSum:
    """A sum of a stream of samples that does not depend on how the stream is cut into batches: np.sum
    of each block of BLOCK consecutive samples, the block sums added in order. So a run and its replay
    (one batch) give the same bits, and a run of <= BLOCK samples the bits of np.sum of its whole array
    (as logs recorded before streaming did); longer runs differ from that by rounding only (a few ulp).
    Holds < BLOCK samples (256 kB)."""

    BLOCK = 1 << 15

    def __init__(self):
        self.total, self.carry = 0.0, np.empty(0)

    def update(self, x) -> None:
        x = np.concatenate([self.carry, x]) if self.carry.size else x
        full = len(x) - len(x) % self.BLOCK
        for i in range(0, full, self.BLOCK):
            self.total += np.sum(x[i:i + self.BLOCK])
        self.carry = x[full:].copy()

    def result(self) -> float:
        return self.total + np.sum(self.carry)


def _nan_max(acc, x):
    """Running max that propagates NaN as np.max of the whole array does (None: nothing yet)."""
    return x if acc is None else np.maximum(acc, x)


def _nan_min(acc, x):
    """Running min, NaN propagated as by np.min of the whole array (None: nothing yet)."""
    return x if acc is None else np.minimum(acc, x)


class _AxisSum:
    """np.sum(x, axis=0) of a stream of (m, r) blocks with the whole array's bits: numpy adds the rows
    of a C-ordered (m, r >= 2) array one after the other (so the running sum is continued row by row);
    an (m, 1) one it sums pairwise as a column (then _BlockSum: exact up to BLOCK rows, rounding beyond)."""

    def __init__(self, r: int):
        self.column = _BlockSum() if r == 1 else None
        self.acc = None

    def update(self, x) -> None:
        if self.column is not None:
            self.column.update(x[:, 0])
        else:
            self.acc = np.add.reduce(x if self.acc is None else np.vstack([self.acc, x]), axis=0)

    def result(self) -> np.ndarray:
        return np.array([self.column.result()]) if self.column is not None else self.acc


class _Ring:
    """The last rows (float64, ``width`` columns) of a stream, at least ``capacity`` of them: what the
    final window may need. The capacity only grows (:meth:`grow`), so a row is dropped only once more
    than ``capacity`` rows came after it. Up to RING_IN_MEMORY bytes the rows stay in memory; beyond, in
    an unlinked temporary file (the default temporary directory), so that the page cache holds them
    rather than the process and a run's memory does not grow with its length."""

    RING_IN_MEMORY = 1 << 20
    READ_ROWS = 1 << 13  # rows per chunk read back (8192 rows of up to ~12 columns: < 1 MB)

    def __init__(self, width: int, capacity: int = 1):
        self.width, self.capacity, self.n = width, 0, 0
        self.blocks: list = []  # in memory: the last blocks of rows, together >= capacity rows
        self.kept = 0  # rows held (in self.blocks, or the last ones written to the file)
        self.file = None  # in the file: row k at (k % capacity) * width * 8
        self.grow(capacity)

    def grow(self, capacity: int) -> None:
        """Hold at least ``capacity`` rows from now on. Into the file once they pass RING_IN_MEMORY
        bytes; a file is rewritten at twice the size or more (few rewrites). A temporary file that
        cannot be made or grow (no temporary directory, a full disk) leaves the rows in memory."""
        if capacity <= self.capacity:
            return
        if self.file is None and capacity * self.width * 8 <= self.RING_IN_MEMORY:
            self.capacity = capacity
            return
        import tempfile

        old, old_capacity = self.file, self.capacity
        capacity = max(capacity, 2 * old_capacity) if old is not None else capacity
        held = self._read(old, old_capacity) if old is not None else iter(self.blocks)
        kept = min(self.kept, capacity)
        try:
            new = tempfile.TemporaryFile()
        except OSError:
            self._to_memory(capacity)
            return
        self.file, self.capacity = new, capacity
        try:
            i = self.n - self.kept
            for rows in held:
                self._write(rows, i)
                i += len(rows)
        except OSError:
            self.file, self.capacity = old, old_capacity
            new.close()
            self._to_memory(capacity)
            return
        if old is not None:
            old.close()
        self.blocks, self.kept = [], kept

    def _to_memory(self, capacity: int) -> None:
        """Keep the rows in memory from now on (the file, if any, read back and closed)."""
        if self.file is not None:
            self.blocks = [np.array(c) for c in self._read(self.file, self.capacity)]
            self.kept = sum(len(b) for b in self.blocks)
            self.file.close()
            self.file = None
        self.capacity = max(self.capacity, capacity)

    def append(self, rows) -> None:
        if self.file is not None:
            try:
                self._write(rows, self.n)
                self.n += len(rows)
                self.kept = min(self.kept + len(rows), self.capacity)
                return
            except OSError:  # the file could not grow (a full disk): what it holds goes back to memory
                self._to_memory(self.capacity)
        self.blocks.append(rows)
        self.n += len(rows)
        self.kept += len(rows)
        while self.kept - len(self.blocks[0]) >= self.capacity:
            self.kept -= len(self.blocks.pop(0))

    def _write(self, rows, start: int) -> None:
        """Rows start, start + 1, ... into the file."""
        import os

        c = self.capacity
        if len(rows) > c:  # only the last `capacity` rows can matter
            start, rows = start + len(rows) - c, rows[-c:]
        rows = np.ascontiguousarray(rows, dtype=np.float64)
        while len(rows):
            p = start % c
            part = rows[:c - p]
            os.pwrite(self.file.fileno(), part.tobytes(), p * self.width * 8)
            start, rows = start + len(part), rows[len(part):]

    @property
    def held(self) -> int:
        """How many rows the ring holds."""
        return self.kept

    @property
    def dropped(self) -> bool:
        """Rows were dropped: the ring holds the last ones only."""
        return self.n > self.held

    def chunks(self):
        """The rows held, oldest first, in blocks of (k, width)."""
        return iter(self.blocks) if self.file is None else self._read(self.file, self.capacity)

    def _read(self, file, capacity: int):
        import os

        w, i = self.width, self.n - self.kept
        while i < self.n:
            p = i % capacity
            k = min(self.READ_ROWS, self.n - i, capacity - p)
            data = os.pread(file.fileno(), k * w * 8, p * w * 8)
            yield np.frombuffer(data, dtype=np.float64).reshape(k, w)
            i += k

    def close(self) -> None:
        if self.file is not None:
            self.file.close()
            self.file = None


def _oscillation(fw, h: float) -> dict:
    """The steady oscillation of z_1 and u over the final window and its averaged power
    (ftstab_mj.metrics.oscillation)."""
    n = min(fw.m, len(fw.z1))
    z1 = np.roll(fw.z1[:n], -(fw.m % len(fw.z1))) if fw.m > len(fw.z1) else fw.z1[:n]  # oldest first
    return oscillation_metrics(z1, fw.u[:fw.m], h, None if fw.z1_z2 is None else fw.z1_z2.result())


class _FinalWindow:
    """The final window's reductions, fed the window's rows in order (ring columns, see _LoopStream):
    its start, max |z_i|, max and min V1, max phi_hat, and (stages) max |z_hat - z| per component and
    its sum of squares; it keeps the window's u (and u_applied) whole, for the chattering indices
    (their FFT and np.sum's pairwise bits need the whole array): 8 bytes per window sample (16 with
    stages)."""

    def __init__(self, r: int, staged: bool, capacity: int, applied: bool = False):
        self.r, self.staged, self.m = r, staged, 0
        self.applied = staged or applied  # the rows end with u_applied
        self.start = None
        self.z_max = self.v_max = self.v_min = self.ph_max = self.e_max = None
        self.e_sq = _AxisSum(r)
        self.u = np.empty(capacity)  # filled up to m
        self.z1 = np.empty(min(capacity, OSC_LAST))  # z_1's last samples, a ring, for its oscillation
        self.z1_z2 = _BlockSum() if r > 1 else None  # sum of |z_1 z_2|: the averaged power
        self.u_applied = np.empty(capacity if self.applied else 0)

    def update(self, rows) -> None:
        r, m, k = self.r, self.m, len(rows)
        if k == 0:
            return
        if self.start is None:
            self.start = float(rows[0, 0])
        z = rows[:, 1:1 + r]
        self.z_max = _nan_max(self.z_max, np.max(np.abs(z), axis=0))
        self.u[m:m + k] = rows[:, 1 + r]
        keep = np.arange(max(k - len(self.z1), 0), k)  # the rows that stay in the ring
        self.z1[(m + keep) % len(self.z1)] = z[keep, 0]
        if self.z1_z2 is not None:
            self.z1_z2.update(np.abs(z[:, 0] * z[:, 1]))
        V1, ph = rows[:, 2 + r], rows[:, 3 + r]
        self.v_max, self.v_min = _nan_max(self.v_max, np.max(V1)), _nan_min(self.v_min, np.min(V1))
        self.ph_max = _nan_max(self.ph_max, np.max(ph))
        if self.staged:
            e = np.abs(rows[:, 4 + r:4 + 2 * r] - z)
            self.e_max = _nan_max(self.e_max, np.max(e, axis=0))
            self.e_sq.update(e * e)
        if self.applied:
            self.u_applied[m:m + k] = rows[:, -1]
        self.m = m + k


class _LipschitzTracker:
    """How often the run broke the differentiator's assumption |z_1^(n+1)| <= L (Levant 2003).

    z_1^(n+1) is the (n + 2 - r)-th finite difference of the true z_r over the control period h
    (z_r' = z_1^(r)), divided by h^(n + 2 - r): the mean over a period, so a lower estimate of the sup.
    Kept across batches: the last n + 2 - r samples of z_r."""

    def __init__(self, r: int, order: int, L: float, h: float):
        self.q, self.L, self.h = order + 2 - r, L, h
        self.carry = np.empty(0)
        self.n = self.above = 0
        self.max = 0.0

    def update(self, zr) -> None:
        x = np.concatenate([self.carry, zr])
        if len(x) > self.q:
            d = np.abs(np.diff(x, n=self.q)) / self.h ** self.q
            self.n += len(d)
            self.above += int(np.count_nonzero(d > self.L))
            self.max = max(self.max, float(np.nanmax(d)))
        self.carry = x[-self.q:].copy()

    def result(self) -> dict:
        return {"observer_L": self.L,
                "observer_derivative_max": _num(self.max),  # max sampled |z_1^(n+1)|, chain units
                "observer_L_exceeded_ratio": _num(self.max / self.L),  # > 1: the assumption broke
                "observer_L_exceeded_fraction": _num(self.above / self.n) if self.n else None}


class _LoopStream:
    """The metrics of one loop from its batches ({field: array}, as logged); see :func:`loop_metrics`.

    Whole-run metrics are reduced batch by batch; the final-window ones at the end, from a ring of the
    last samples: after n samples it holds at least window(n) = min(ceil(final_fraction n),
    ceil(final_window_max / h)) + 2 of them, the
    most the final window can hold then or later (t_k = t_0 + k h: the window of a longer run starts
    later). ``n_total``: the most samples expected (a hint sizing the ring at once; None: it grows). A
    ring row is t, z (r), u, V1, phi_hat and, with stages, z_hat (r), u_applied.
    """

    def __init__(self, info: RunInfo, loop, n_total: int | None, selection: tuple | None = None):
        self.info, self.loop = info, loop
        self.selection = selection  # None: every metric; else only these keys (GUARANTEE_METRICS)
        ms = info.metric_settings
        ultimate = _ultimate_bound(loop)
        self.eps = float(ultimate["eps"]) if ultimate else ms.settle_level
        self.settle = _SettleTracker(ms.settle_level)
        self.settle_z1 = _SettleTracker(ms.settle_z1)
        self.n = 0
        self.stages = getattr(loop, "stages", None)
        self.clamp = getattr(loop, "clamp", None) if self.stages is None else None  # u_applied without stages
        self.ring = None if selection is not None else _Ring(
            4 + loop.r + (loop.r + 1 if self.stages is not None else 1 if self.clamp else 0), self._window(n_total or 0))
        self.first = self.last = None
        self.abs_sum, self.sq_sum = _BlockSum(), _BlockSum()
        self.u_max = self.phi_hat_max = self.u_applied_max = None
        self.ext = None  # workspace extremes
        self.entry = self.v_min = self.v_max = None  # eps-ball: entry time, V1 min/max from it on
        self.n_saturated = 0.0
        self.denied = bound_denied(loop)  # the loop's and its certificate's: asked once per run
        self.assumed = AssumedBounds(loop) if self.denied is None else None  # only where a time bound is claimed
        obs = self.stages["observer"] if self.stages is not None else None
        self.lipschitz = None if obs is None else _LipschitzTracker(loop.r, obs["order"], obs["L"], info.period)

    def update(self, arrays: dict) -> None:
        # a selection reads only the fields its metrics need (the same conversion, field by field)
        a = {k: _finite_or_nan(v) for k, v in arrays.items()
             if self.selection is None or k in _GUARANTEE_FIELDS}
        t, V1, u, z = a["t"], a["V1"], a["u"], a["z"]
        m = len(t)
        if m == 0:
            return
        if self.n == 0:
            self.first = {"t": float(t[0]), "z": z[0].copy(), "V1": float(V1[0])}
        self.last = {"V1": V1[-1], "phi_hat": a["phi_hat"][-1] if "phi_hat" in a else None}
        self.settle.update(self.n, t, V1)
        self.u_max = _nan_max(self.u_max, np.max(np.abs(u)))
        if self.assumed is not None and "phi" in a:  # a stream without the true phi, gamma has nothing to check
            self.assumed.update(t, a["phi"], a["gamma"])
        ext = extremes(z, u)
        self.ext = ext if self.ext is None else np.array([np.fmin(self.ext[0], ext[0]), *np.fmax(self.ext[1:], ext[1:])])
        if self.selection is not None:  # what bound_applies needs of an actuator that clamps, nothing more
            if self.clamp:
                self.n_saturated += float(np.count_nonzero(a["u_applied"] != u))
            self.n += m
            return
        self.settle_z1.update(self.n, t, np.abs(z[:, 0]))
        self.abs_sum.update(np.abs(u))
        with np.errstate(over="ignore"):  # |u| > 1e154 (a diverging run): the effort is inf, said by its value
            self.sq_sum.update(u * u)
        self.phi_hat_max = _nan_max(self.phi_hat_max, np.max(a["phi_hat"]))
        if self.entry is None:
            inside = np.flatnonzero(V1 <= self.eps)
            if inside.size:
                self.entry = float(t[inside[0]])
                after = V1[inside[0]:]
                self.v_min, self.v_max = np.min(after), np.max(after)
        else:
            self.v_min, self.v_max = np.minimum(self.v_min, np.min(V1)), np.maximum(self.v_max, np.max(V1))
        cols = [t[:, None], z, u[:, None], V1[:, None], a["phi_hat"][:, None]]
        if self.stages is not None:
            self.n_saturated += saturated_time(u, self.stages, 1.0)  # a count: exact
            self.u_applied_max = _nan_max(self.u_applied_max, np.max(np.abs(a["u_applied"])))
            cols += [a["z_hat"], a["u_applied"][:, None]]
            if self.lipschitz is not None:
                self.lipschitz.update(z[:, -1])
        elif self.clamp:
            self.n_saturated += float(np.count_nonzero(a["u_applied"] != u))
            self.u_applied_max = _nan_max(self.u_applied_max, np.max(np.abs(a["u_applied"])))
            cols += [a["u_applied"][:, None]]
        self.n += m
        self.ring.grow(self._window(self.n))
        self.ring.append(np.hstack(cols))

    def _window(self, n: int) -> int:
        """The most samples the final window of n samples holds: those with t_k >= t_0 + (1 - ff) n h,
        at most ff n + 1 of them, or with t_k >= t_0 + n h - cap, at most cap / h + 1 (+1 for rounding)."""
        ms = self.info.metric_settings
        most = math.ceil(ms.final_fraction * n)
        if ms.final_window_max is not None:
            most = min(most, math.ceil(ms.final_window_max / self.info.period))
        return int(most) + 2

    def _final_window(self) -> _FinalWindow:
        """The reductions of the final window: the samples from :func:`final_window_start` on, or the
        last sample when there is none."""
        ms, h, n, ring = self.info.metric_settings, self.info.period, self.n, self.ring
        start = final_window_start(self.first["t"], n, h, ms)
        fw = _FinalWindow(self.loop.r, self.stages is not None, ring.held, applied=bool(self.clamp))
        last = None
        for k, rows in enumerate(ring.chunks()):
            win = rows[:, 0] >= start
            if k == 0 and ring.dropped and win[0]:  # only with times not t_0 + k h (not a run's)
                raise ValueError(f"the final window of loop {self.loop.name} starts before the last "
                                 f"{ring.held} of its {n} samples: its times t are not spaced by the period")
            fw.update(rows[win])
            last = rows[-1:]
        if fw.m == 0:
            fw.update(last)
        ring.close()
        return fw

    def _guarantee(self) -> tuple[dict, list[str]]:
        """The metrics of Theorem 1's guarantee (GUARANTEE_METRICS) and the stages' and the run's reasons
        why it does not apply."""
        loop, ms = self.loop, self.info.metric_settings
        ts = self.settle.result(self.n, self.first["t"])
        tb = time_bound(loop, self.first["z"])
        left = _workspace_text(loop, self.ext)
        reasons = stage_reasons(self.stages)
        # the true bounds only hold inside the workspace; the stages may break the theorems' assumptions
        if self.clamp and self.n_saturated:  # the plant's actuator clamped the law: its guarantee does not hold
            reasons = reasons + [f"the actuator's {self.clamp} clamped the law's u"]
        if self.assumed is not None and self.assumed.reason:  # the plant's bounds did not hold along the run
            reasons = reasons + [self.assumed.reason]
        denied = self.denied
        applies = denied is None and not left and not reasons
        why = "; ".join(([denied] if denied else []) + ([f"the plant left the workspace: {left}"] if left else [])
                        + reasons) or None
        return {
            "z0": [_num(x) for x in self.first["z"]],
            "V1_initial": _num(self.first["V1"]),
            "V1_final": _num(self.last["V1"]),
            "settle_level": ms.settle_level,
            "settle_time": ts,
            "time_bound": tb,
            "workspace_left": left,
            "bound_applies": applies,
            "bound_applies_reason": why,  # always a phrase when bound_applies is false
            "u_max_abs": _num(self.u_max),
        }, reasons

    def result(self) -> dict:
        loop, info, n = self.loop, self.info, self.n
        out = {"law": loop.law, "n_samples": n}
        if n == 0:
            return out
        guarantee, reasons = self._guarantee()
        if self.selection is not None:
            out.update({k: guarantee[k] for k in self.selection})
            return out
        ms, h = info.metric_settings, info.period
        fw = self._final_window()
        ts, tb, applies = guarantee["settle_time"], guarantee["time_bound"], guarantee["bound_applies"]
        left, stages = guarantee["workspace_left"], self.stages
        u_win = fw.u[:fw.m]
        g = guarantee
        out.update({  # in the order the metrics have always had (a sweep table's columns follow it)
            **{k: g[k] for k in ("z0", "V1_initial", "V1_final", "settle_level", "settle_time")},
            # the same definition on |z_1| (law-independent: a rival law may have no V1)
            "settle_time_z1": self.settle_z1.result(n, self.first["t"]),
            **{k: g[k] for k in ("time_bound", "workspace_left", "bound_applies", "bound_applies_reason")},
            "beat_bound": (bool(ts <= tb) if applies and ts is not None and tb is not None else None),
            "final_window_start": fw.start,
            "final_abs_z_max": [_num(x) for x in fw.z_max],  # final_abs_max, a running max
            "chattering": chattering(u_win, h),
            "chattering_du_dt_var": du_dt_variance(u_win, h),
            "chattering_zero_crossings": zero_crossing_rate(u_win, h),
            "chattering_band_rms": band_rms(u_win, h, ms.chatter_band),
            # effort(u, h), summed in blocks (_BlockSum)
            "effort_abs": _num(h * self.abs_sum.result()),
            "effort_sq": _num(h * self.sq_sum.result()),
            "u_max_abs": g["u_max_abs"],
            "eps": self.eps,
            "eps_entry_time": self.entry,  # eps_ball(t, V1, eps), batch by batch
            "V1_min_after_entry": None if self.entry is None else _num(self.v_min),
            "V1_max_after_entry": None if self.entry is None else _num(self.v_max),
            "phi_hat_max": _num(self.phi_hat_max),
            "phi_hat_final": _num(self.last["phi_hat"]),
            "theorem3": None if left else theorem3_check(loop, fw.v_max, fw.ph_max, fw.v_min),
            "certificate": certificate_summary(loop),
        })
        out.update(_oscillation(fw, h))
        if stages is not None:  # the loop's sensor, observer, actuator (records.STAGE_FIELDS)
            t_sat = self.n_saturated * h  # saturated_time(u, stages, h)
            out.update({
                "u_needed": stages["u_needed"],
                # estimation_error(z_hat, z) of the window, reduced as it is read
                "estimation_error_max": [_num(x) for x in fw.e_max],
                "estimation_error_rms": [_num(x) for x in np.sqrt(fw.e_sq.result() / fw.m)],
                "time_saturated": _num(t_sat),
                "saturated_fraction": _num(t_sat / (n * h)),
                "chattering_applied": chattering(fw.u_applied[:fw.m], h),
                "u_applied_max_abs": _num(self.u_applied_max),
            })
            if self.lipschitz is not None:
                out.update(self.lipschitz.result())
            out["limit_cycle_predicted"] = predicted_limit_cycle(loop, h)
        elif self.clamp:  # the plant's actuator clamps: u_max_abs, chattering are the law's u; these what it applied
            t_sat = self.n_saturated * h
            out.update({
                "clamp": self.clamp,
                "time_saturated": _num(t_sat),
                "saturated_fraction": _num(t_sat / (n * h)),
                "chattering_applied": chattering(fw.u_applied[:fw.m], h),
                "u_applied_max_abs": _num(self.u_applied_max),
            })
        if loop.reference is not None:  # a tracked reference: its ref^(r) is part of phi
            out.update(reference_cover(loop))
        if reasons and "bound_applies_reason" not in out:
            out["bound_applies_reason"] = "; ".join(reasons)
        return out


class MetricsStream:
    """The metrics of a run computed as its batches arrive, in memory that does not grow with the run.

        stream = MetricsStream(info, n_total)      # n_total: the most samples the run can have
        for batch in batches: stream.update(batch.loops)   # {loop name: {field: array}}
        metrics = stream.result(status)            # compute_metrics' dict

    Kept: per loop, running sums, extremes and first/last values for the whole-run metrics, and a ring
    of the last min(ceil(final_fraction n), ceil(final_window_max / h)) + 2 samples (n so far) of t, z, u,
    V1, phi_hat (z_hat, u_applied)
    for the final-window ones: in memory up to 1 MiB, beyond in a temporary file (_Ring). At the end the
    window is read back and reduced; only its u (and u_applied) is held whole, for the chattering
    indices. n_total (a hint: None when unknown, e.g. a log read as it streams) sizes the ring at once.
    ``selection`` (:data:`GUARANTEE_METRICS`, None: all): only those metrics of each loop (with ``law`` and
    ``n_samples``), the same values as in the whole set, from only what they need (no ring, no final window).
    Equal to :func:`compute_metrics` of the concatenated arrays (a replay) bit for bit, whatever the
    batches; against the definitions on whole arrays (effort's np.sum) effort_abs and effort_sq agree to
    rounding (exactly up to 32768 samples, _BlockSum), as does estimation_error_rms of an r = 1 loop;
    every other metric exactly.
    """

    def __init__(self, info: RunInfo, n_total: int | None = None, selection: tuple | None = None):
        self.info = info
        self.loops = {lp.name: _LoopStream(info, lp, n_total, selection) for lp in info.loops}

    def update(self, loops: dict) -> None:
        for name, stream in self.loops.items():
            stream.update(loops[name])

    def result(self, status: str) -> dict:
        """{"status", "n_samples", "duration" (s), "loops": {name: loop metrics}}."""
        per = {name: s.result() for name, s in self.loops.items()}
        n = max((m["n_samples"] for m in per.values()), default=0)
        return {"status": status, "n_samples": n, "duration": _num(n * self.info.period), "loops": per}


def loop_metrics(info: RunInfo, loop, arrays: dict) -> dict:
    """All metrics of one loop from its whole arrays (see the functions above for each definition)."""
    s = _LoopStream(info, loop, None)
    s.update(arrays)
    return s.result()


def compute_metrics(info: RunInfo, loops: dict, status: str) -> dict:
    """Metrics of a run: {"status", "n_samples", "duration" (s), "loops": {name: loop_metrics}}.

    loops: {loop name: {field: array}} with z (n, r) and the other fields (n,), as logged.
    """
    stream = MetricsStream(info)
    stream.update(loops)
    return stream.result(status)

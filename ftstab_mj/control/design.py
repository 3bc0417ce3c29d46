"""Gain design for Hong's controller: gains with a sound certificate (ftstab design).

The search runs on log-gains with a deterministic Nelder-Mead simplex over a cheap estimate of
the objective (the float witness search of the certificate: it can only over-estimate c); every
candidate it ends on is then certified soundly (ftstab_mj.control.certificate.certify), and the
best certified one is returned. Objectives:

* ``max-c``: maximise c_lower (for a given k, c scales with the gains: multiplying every gain by
  the same factor is not a dilation, so the search is over the whole gain vector, bounded by
  ``gain_max``);
(A ``min-time`` objective, T(z0) for given initial states under |u0| <= u_max on a region, is not
implemented yet.)
"""

from __future__ import annotations

import numpy as np


def nelder_mead(f, x0, step=0.5, iters=300, tol=1e-7):
    """Minimise f over R^n from x0 with the Nelder-Mead simplex (standard coefficients). Deterministic.

    Returns (x, f(x)). f may return inf (an infeasible point).
    """
    n = len(x0)
    pts = [np.asarray(x0, dtype=float)]
    for i in range(n):
        p = pts[0].copy()
        p[i] += step
        pts.append(p)
    vals = [f(p) for p in pts]
    for _ in range(iters):
        order = np.argsort(vals)
        pts, vals = [pts[i] for i in order], [vals[i] for i in order]
        if abs(vals[-1] - vals[0]) <= tol * (abs(vals[0]) + tol) and np.isfinite(vals[-1]):
            break
        cen = np.mean(pts[:-1], axis=0)
        xr = cen + (cen - pts[-1])
        fr = f(xr)
        if fr < vals[0]:
            xe = cen + 2.0 * (cen - pts[-1])
            fe = f(xe)
            pts[-1], vals[-1] = (xe, fe) if fe < fr else (xr, fr)
        elif fr < vals[-2]:
            pts[-1], vals[-1] = xr, fr
        else:
            xc = cen + 0.5 * (pts[-1] - cen)
            fc = f(xc)
            if fc < vals[-1]:
                pts[-1], vals[-1] = xc, fc
            else:
                for i in range(1, n + 1):
                    pts[i] = pts[0] + 0.5 * (pts[i] - pts[0])
                    vals[i] = f(pts[i])
    i = int(np.argmin(vals))
    return pts[i], vals[i]


def _estimate_c(r, k, gains, pts, rng):
    """-max over the fixed face points pts (n, r) of the float ratio, improved by a short climb:
    an estimate of c from above (cheap; the final candidate is certified soundly)."""
    from ftstab_mj.control.certificate import _climb, _Ratio
    from ftstab_mj.control.hong_terms import Terms

    obj = _Ratio(Terms(r, k, gains), "c")
    f = obj.floats(pts)
    top = pts[np.argsort(f)[-8:]]
    z = _climb(obj, top, rng, rounds=20)
    return -float(max(np.max(f), np.max(obj.floats(z))))


def design_max_c(r: int, k: float, gain_min=0.1, gain_max=100.0, starts=3, iters=150, budget=None, seed=0):
    """Gains l_1..l_r maximising the certified c_lower for (r, k), searched over [gain_min, gain_max]^r.

    Returns (gains, certificate) of the best certified candidate, or (gains, certificate) of the
    best estimate with its (not certified / undecided) certificate when none certifies. Deterministic
    for a given seed (the certification of the candidates has no time budget unless ``budget``).
    """
    from ftstab_mj.control.certificate import certify
    from ftstab_mj.control.hong import HongController, is_hurwitz

    rng = np.random.default_rng(seed)
    pts = []
    for face in range(r):
        x = rng.uniform(-1.0, 1.0, size=(2000, r - 1))
        pts.append(np.insert(x, face, 1.0, axis=1))
    pts = np.concatenate(pts)
    lo, hi = np.log(gain_min), np.log(gain_max)

    def cost(x):
        g = tuple(float(v) for v in np.exp(np.clip(x, lo, hi)))
        if not is_hurwitz(g):
            return np.inf
        with np.errstate(all="ignore"):
            c = _estimate_c(r, k, g, pts, np.random.default_rng(seed))
        return -c if np.isfinite(c) else np.inf

    found = []
    for s in range(starts):
        ratio = 2.0 + 2.0 * s  # geometric starts: each gain `ratio` times the previous one
        x0 = np.clip(np.log(ratio) * np.arange(r) - np.log(ratio) * (r - 1) / 3.0, lo, hi)
        x, fx = nelder_mead(cost, x0, step=0.7, iters=iters)
        found.append((fx, tuple(float(round(v, 4)) for v in np.exp(np.clip(x, lo, hi)))))
    found.sort()
    best, fallback = None, None
    for fx, g in found:
        if not np.isfinite(fx):
            continue
        cert = certify(HongController(r, k, g), budget=budget)
        if cert.certified and (best is None or cert.c_lower > best[1].c_lower):
            best = (g, cert)
        if best is None and cert.status != "certified":
            fallback = (g, cert)
    return best if best is not None else fallback if fallback is not None else (found[0][1], None)

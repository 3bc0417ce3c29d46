"""Gain design for Hong's controller: gains with a sound certificate (ftstab design).

The search runs on log-gains with a deterministic Nelder-Mead simplex over a cheap estimate of
the objective (the float witness search of the certificate: it can only over-estimate c); every
candidate it ends on is then certified soundly (ftstab_mj.control.certificate.certify), and the
best certified one is returned. Objectives:

* ``max-c``: maximise c_lower (for a given k, c scales with the gains: multiplying every gain by
  the same factor is not a dilation, so the search is over the whole gain vector, bounded by
  ``gain_max``);
* ``min-time``: minimise the guaranteed T(z0) = max over the given z0 of V1(z0)^(1-alpha) /
  (c (1-alpha)), subject to |u0(z)| <= u_max for every z in the box |z_i| <= region_i (checked with
  outward-rounded intervals, so the constraint is guaranteed too).
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

"""c of the linear law (k = 0) in closed form, and its limit as k -> 0 from below.

Both are floats from eigenvalues, exact up to rounding and cheap (microseconds; limit_c 6 ms at r = 6):
the designer's objective at k = 0 and the start of its search at k < 0. Neither is a certificate
at any k < 0 (ftstab_mj.control.certificate proves one).
"""

from __future__ import annotations

import itertools
from typing import NamedTuple

import numpy as np


def linear_c(gains) -> float:
    """c at k = 0 in closed form (float): the linear law's V1 = |e|^2 / 2 in the backstepping
    coordinates e_1 = z_1, e_{i+1} = z_{i+1} + l_i e_i (e = T z), whose closed loop is e' = B e with
    B = T A T^-1, so dV1/dt / V1 = 2 e^T B e / |e|^2 and c = 2 lambda_min(-(B + B^T) / 2).
    Exact up to float rounding: the search objective at k = 0 and the start of the search at k < 0."""
    g = np.asarray(gains, dtype=float)
    r = len(g)
    T = np.zeros((r, r))
    T[0, 0] = 1.0
    A = np.diag(np.ones(r - 1), 1)
    with np.errstate(all="ignore"):  # overflowing gains: B not finite, -inf below
        for i in range(1, r):
            T[i] = g[i - 1] * T[i - 1]
            T[i, i] += 1.0
        A[r - 1] = -g[-1] * T[r - 1]
        B = np.linalg.solve(T.T, (T @ A).T).T  # T A T^-1
        c = 2.0 * float(np.linalg.eigvalsh(-(B + B.T) / 2.0)[0]) if np.isfinite(B).all() else -np.inf
    return c if np.isfinite(c) else -np.inf


class LimitC(NamedTuple):
    """limit_c's answer: c, the zero set where it is attained and a state there."""
    c: float  # lim c as k -> 0- (float)
    z_zero: tuple[int, ...]  # the i (1-based) with z_i = 0 on that set
    s_zero: tuple[int, ...]  # the i with e_i = z_i - v_{i-1} = 0 there
    z: np.ndarray  # (r,) a state of the k = 0 law where dV1/dt / V1 = -c on that set, |e| = 1


def limit_forms(gains, single=False):
    """limit_c's value on each choice of zero sets (LimitC per choice, in a fixed order). A level
    on both z_i = 0 and s_i = 0 is left out: with G_i = 0 the factor B_i is not used, so that set
    only restricts the one with s_i = 0 alone. single: only the sets z_i = 0 of one i."""
    l = np.asarray(gains, dtype=float)
    r = len(l)
    # z = M e (rows z_1 .. z_r, then z_{r+1} = u0 = -l_r e_r): z_j = e_j - l_{j-1} e_{j-1}
    M = np.eye(r + 1, r)
    M[np.arange(1, r + 1), np.arange(r)] -= l
    levels = range(2, r)
    if single:
        choices = [((i,), ()) for i in levels]
    else:  # per level: factors 1, B_i = 0 (z_i = 0) or G_i = 0 (s_i = 0)
        codes = itertools.product(range(3), repeat=len(levels))
        choices = [(tuple(i for i, c in zip(levels, cs) if c == 1), tuple(i for i, c in zip(levels, cs) if c == 2))
                   for cs in codes]
    for zero_z, zero_s in choices:
        with np.errstate(all="ignore"):  # overflowing gains: Q not finite, no value below
            w = -l[0] * M[1]  # w_1 (rows: linear forms in e)
            Q = np.outer(np.eye(r)[0], M[1]) + (np.outer(np.eye(r)[1], M[2] - w) if r >= 2 else 0.0)
            for i in range(2, r):
                w = np.zeros(r) if i in zero_s else -l[i - 1] * ((0.0 if i in zero_z else 1.0) * M[i] - w)
                Q += np.outer(np.eye(r)[i], M[i + 1] - w)
            Q = (Q + Q.T) / 2.0
        if not np.isfinite(Q).all():  # gains whose products overflow floats: no value (as linear_c)
            yield LimitC(-np.inf, zero_z, zero_s, np.full(r, np.nan))
            continue
        rows = [M[i - 1] for i in zero_z] + [np.eye(r)[i - 1] for i in zero_s]
        if rows:
            _, sv, vt = np.linalg.svd(np.array(rows))
            N = vt[int(np.sum(sv > 1e-12 * sv[0])):].T  # orthonormal basis of the set
        else:
            N = np.eye(r)
        if N.shape[1] == 0:
            continue
        lam, vec = np.linalg.eigh(N.T @ Q @ N)
        z = M[:r] @ (N @ vec[:, -1])
        z[[i - 1 for i in zero_z]] = 0.0
        yield LimitC(-2.0 * float(lam[-1]), zero_z, zero_s, z)


def limit_c(gains) -> LimitC:
    """The limit of c as k -> 0 from below (float), which differs from linear_c for r >= 5.

    Write dV1/dt = sum_j s_j z_{j+1} - e_j w_{j-1} (z_{r+1} = u0), with s_j = sig(z_j, b_{j-1}) -
    sig(v_{j-1}, b_{j-1}), e_j = z_j - v_{j-1} and w_i the time derivative of sig(v_i, b_i) =
    -l_i^(b_i) sig(s_i, g_i) (b_i = beta_i, g_i = alpha_i beta_i / beta_{i-1} in the paper's
    exponents). Then w_1 = -l_1^(b_1) z_2 and, for i = 2..r-1,

        w_i = -l_i^(b_i) G_i (B_i z_{i+1} - w_{i-1}),  B_i = b_{i-1} |z_i|^(b_{i-1} - 1),
                                                       G_i = g_i |s_i|^(g_i - 1).

    For k < 0, b_{i-1} > 1 and g_i > 1, and both exponents minus one are O(|k|): as k -> 0- each
    factor tends to 1 wherever its argument is not 0, but it is 0 on z_i = 0 (B_i) or s_i = 0
    (G_i) for every k < 0, and it takes every value in [0, 1] in a layer around that set which
    thins to nothing. Everything else tends to the linear law (v_i = -l_i e_i, V1 = |e|^2 / 2,
    alpha = 1). So in the limit dV1/dt is e^T Q e with any of the 2 (r - 2) factors set to a value
    in [0, 1] on its set; it is affine in each factor, so its largest value is at a factor 0 or 1,
    and lim c = min over the choices (a factor 0 restricts e to its set; 3^(r-2) of them matter) of
    -2 lambda_max(Q restricted to that subspace). With every factor 1 that is linear_c. Measured:
    the maximum of the controller's own dV1/dt / V1^alpha on z_3 = 0 at k = -1e-6 is within 2e-4
    relative of this value, at r = 6. A limit, not a bound at any k: an estimate to search with.
    -inf (as linear_c) where the gains' products overflow floats.
    """
    return min(limit_forms(gains), key=lambda f: f.c)

"""Bounds of phi and gamma of a ChainPlant (plants/chain.py) over a stated workspace.

Workspace: q in [q_min, q_max] and |q'| <= qd_max for every dof (passive ones included), for r = 3
also |q''| <= qdd_max, and |u_j| <= u_max_j for the loops' controls (a torque for r = 2, a torque
rate for r = 3: they enter phi of the other loops). Signals: injected |tau_d_j| (r = 3: its rate)
<= D_j, gain factors g_j in [g_m, g_M]. With F = M^-1 (nv, nv) at q and d_i loop i's dof:

    gamma_m_i = g_m,i b_i min_q F_ii,   gamma_M_i = g_M,i b_i max_q F_ii
    r = 2:  phibar_i = max_q [ max_q' |(F f(q, q'))_i| + sum_j |F_i dj| D_j + sum_c |F_ic| frictionloss_c
                              + sum_{j != i} |F_i dj| b_j g_M,j u_max_j ]
    r = 3:  phibar_i = max_{q, q'} [ |(F f_q q')_i| + sum_c |(F (f_q' - M'))_ic| qdd_max_c ]
                       + the same D and u terms (dry friction: no finite bound, its rate jumps)

where f = qfrc_passive - qfrc_bias (+ actuators no loop drives), f_q, f_q' its partial
derivatives and M' = sum_k q'_k dM/dq_k. f is exactly quadratic in q' (f0 + L x + Q[x, x] with
x = q' / qd_max), identified from MuJoCo by polarization (and checked at one more point); the
derivatives in q are central differences of those coefficients and of M (step DQ).

How exact: r = 2 is exact in q' (the maximum of a quadratic over a box, by faces) and in the
signal and control ranges, r = 3 exact in q'' and in those ranges (linear), and both are maxima
over a grid of q (``grid`` points per dof, corners included) and, for r = 3, of q'
(``qd_grid`` points per dof): between grid points they are estimates, not guarantees. Runs check
them along the way (metrics: workspace_left; tests: |phi| <= phibar with the margins).
"""

from __future__ import annotations

import hashlib
import itertools
import sys
import time
from dataclasses import dataclass

import mujoco
import numpy as np

from ftstab_mj.config.errors import ParameterError
from ftstab_mj.plants.base import model_bytes, reads_files

DQ = 1e-5  # rad or m: central-difference step in q for the r = 3 derivative terms
_CACHE: dict = {}  # (model, workspace) -> tables; a sweep over parameters keeps at most 32
PROGRESS_AFTER = 1.0  # s: a bound table that takes longer says so on stderr


@dataclass(frozen=True)
class Workspace:
    """Where the bounds hold (arrays over all nv dofs, u_max over the loops), grid resolution."""

    q_min: np.ndarray
    q_max: np.ndarray
    qd_max: np.ndarray
    u_max: np.ndarray
    qdd_max: np.ndarray | None = None
    grid: int = 21
    qd_grid: int = 5

    def key(self) -> tuple:
        arrays = (self.q_min, self.q_max, self.qd_max, self.u_max, self.qdd_max)
        return tuple(None if a is None else tuple(np.asarray(a, float).tolist()) for a in arrays) + (self.grid, self.qd_grid)


def max_abs_quadratic(c: np.ndarray, b: np.ndarray, A: np.ndarray) -> np.ndarray:
    """max |c + b.x + x^T A x| over the box |x_j| <= 1, exactly, batched: c (G,), b (G, n), A (G, n, n).

    The extrema of a quadratic over a box lie at stationary points of its restriction to a face:
    for every face (each coordinate free or at -1/+1) solve the stationary equations in the free
    coordinates (all G at once) and keep the points inside the box (3^n faces).
    """
    G, n = b.shape
    best = np.zeros(G)
    for pattern in itertools.product((-1, 0, 1), repeat=n):
        x = np.broadcast_to(np.array(pattern, dtype=float), (G, n)).copy()
        free = [j for j in range(n) if pattern[j] == 0]
        ok = np.ones(G, dtype=bool)
        if free:
            fixed = [j for j in range(n) if pattern[j] != 0]
            H = 2 * A[:, free][:, :, free]
            rhs = -(b[:, free] + 2 * np.einsum("gij,gj->gi", A[:, free][:, :, fixed], x[:, fixed]))
            det_ok = np.abs(np.linalg.det(H)) > 1e-12 * np.maximum(1.0, np.abs(H).max(axis=(1, 2))) ** len(free)
            sol = np.zeros((G, len(free)))
            if det_ok.any():  # a degenerate face has its extrema on its own boundary (other faces)
                sol[det_ok] = np.linalg.solve(H[det_ok], rhs[det_ok][..., None])[..., 0]
            x[:, free] = sol
            ok = det_ok & np.all(np.abs(sol) <= 1.0, axis=1)
        val = np.abs(c + np.einsum("gi,gi->g", b, x) + np.einsum("gi,gij,gj->g", x, A, x))
        best = np.where(ok, np.maximum(best, val), best)
    return best


def _grid(lo, hi, points):
    axes = [np.linspace(a, b, points) for a, b in zip(lo, hi)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(lo))


class _Sampler:
    """M(q) and the coefficients of f(q, x) = f0 + L x + Q[x, x] (x = q' / qd_max) from a private MjData
    whose loop actuators have ctrl = act = 0 (their torques are accounted for separately)."""

    def __init__(self, plant, qd_max):
        self.m, self.d, _ = plant.compile(0.001)
        self.nv = self.m.nv
        self.S = np.asarray(qd_max, dtype=float)
        self.M = np.empty((self.nv, self.nv))
        self.calls = 0

    def at(self, q):
        """(M (nv, nv), f0 (nv,), L (nv, nv), Q (nv, nv, nv), mismatch of the quadratic at one more point)."""
        m, d, n = self.m, self.d, self.nv
        d.qpos[:] = q
        mujoco.mj_fwdPosition(m, d)
        mujoco.mj_fullM(m, d, self.M)
        eye = np.diag(self.S)

        def f(qd):
            d.qvel[:] = qd
            mujoco.mj_fwdVelocity(m, d)
            mujoco.mj_fwdActuation(m, d)
            mujoco.mj_fwdAcceleration(m, d)
            self.calls += 1
            return d.qfrc_smooth.copy()

        f0 = f(np.zeros(n))
        fp = [f(eye[j]) for j in range(n)]
        fm = [f(-eye[j]) for j in range(n)]
        L = np.stack([(fp[j] - fm[j]) / 2 for j in range(n)], axis=-1)
        Q = np.zeros((n, n, n))
        for j in range(n):
            Q[:, j, j] = (fp[j] + fm[j]) / 2 - f0
        for j in range(n):  # the cross terms need every diagonal term first
            for k in range(j + 1, n):
                cross = f(eye[j] + eye[k]) - f0 - L[:, j] - L[:, k] - Q[:, j, j] - Q[:, k, k]
                Q[:, j, k] = Q[:, k, j] = cross / 2
        x = np.linspace(-0.7, 0.9, n)  # a point off the polarization stencil
        mismatch = np.abs(f(self.S * x) - (f0 + L @ x + np.einsum("ijk,j,k->i", Q, x, x))).max()
        return self.M.copy(), f0, L, Q, mismatch / max(1.0, np.abs(f0).max(), np.abs(L).max(), np.abs(Q).max())


def tables(plant) -> dict:
    """The workspace tables of the plant's bounds (cached by model and workspace): over the q grid
    (Gq points), F = M^-1 (Gq, nv, nv) and the phi part that depends on the state, maxed over the
    velocities (Gq, n)."""
    ws = plant.workspace
    m, _, xml = plant.compile(0.001)
    model = xml.encode() + (model_bytes(m) if reads_files(xml) else b"")  # a mesh's file is not in the text
    key = (hashlib.sha256(model).hexdigest(), ws.key(), plant.r, tuple(plant.dof_ids.tolist()))
    if key in _CACHE:
        return _CACHE[key]
    t0 = time.perf_counter()
    sm = _Sampler(plant, ws.qd_max)
    nv, dofs = sm.nv, plant.dof_ids
    qs = _grid(ws.q_min, ws.q_max, ws.grid)
    G = len(qs)
    F = np.empty((G, nv, nv))
    state = np.empty((G, plant.n))
    worst = 0.0
    said = False
    if plant.r == 2:
        c = np.empty((G, plant.n))
        b = np.empty((G, plant.n, nv))
        A = np.empty((G, plant.n, nv, nv))
        for g, q in enumerate(qs):
            M, f0, L, Q, mis = sm.at(q)
            worst = max(worst, mis)
            F[g] = Fg = np.linalg.inv(M)
            rows = Fg[dofs]  # [F f]_i is again quadratic in x
            c[g], b[g], A[g] = rows @ f0, rows @ L, np.einsum("ic,cab->iab", rows, Q)
            said = _progress(plant, t0, g, G, said)
        state[:] = max_abs_quadratic(c.reshape(-1), b.reshape(-1, nv), A.reshape(-1, nv, nv)).reshape(G, plant.n)
    else:
        xs = _grid(-np.ones(nv), np.ones(nv), ws.qd_grid)  # x = q' / qd_max
        qd = xs * sm.S  # (X, nv)
        eye = np.eye(nv) * DQ
        for g, q in enumerate(qs):
            M, f0, L, Q, mis = sm.at(q)
            worst = max(worst, mis)
            dM, df0, dL, dQ = [], [], [], []
            for k in range(nv):
                Mp, f0p, Lp, Qp, _ = sm.at(q + eye[k])
                Mm, f0m, Lm, Qm, _ = sm.at(q - eye[k])
                dM.append((Mp - Mm) / (2 * DQ))
                df0.append((f0p - f0m) / (2 * DQ))
                dL.append((Lp - Lm) / (2 * DQ))
                dQ.append((Qp - Qm) / (2 * DQ))
            F[g] = Fg = np.linalg.inv(M)
            # f_q q' = sum_k q'_k (df0_k + dL_k x + dQ_k[x, x])   (X, nv)
            dfx = (np.einsum("kc->kc", np.array(df0))[None] + np.einsum("kca,xa->xkc", np.array(dL), xs)
                   + np.einsum("kcab,xa,xb->xkc", np.array(dQ), xs, xs))
            fq_qd = np.einsum("xk,xkc->xc", qd, dfx)
            # f_q' = (L + 2 Q[x, .]) / qd_max,  M' = sum_k q'_k dM_k   (X, nv, nv)
            fqd = (L[None] + 2 * np.einsum("cab,xa->xcb", Q, xs)) / sm.S[None, None, :]
            Mdot = np.einsum("xk,kab->xab", qd, np.array(dM))
            rows = Fg[dofs]  # (n, nv)
            a = np.einsum("ic,xc->xi", rows, fq_qd)
            Bm = np.einsum("ic,xcb->xib", rows, fqd - Mdot)
            state[g] = (np.abs(a) + np.abs(Bm) @ ws.qdd_max).max(axis=0)
            said = _progress(plant, t0, g, G, said)
    if worst > 1e-6:
        raise ParameterError("params.model", "forces that are quadratic in the joint velocities (bounds by "
                             "polarization)", f"a mismatch of {worst:.2g} (relative) off the stencil")
    if len(_CACHE) >= 32:
        _CACHE.clear()
    _CACHE[key] = {"diag": np.einsum("gii->gi", F[:, dofs][:, :, dofs]), "F": F, "state": state}
    if said:
        print(f"bounds of {plant.model_name!r}: done in {time.perf_counter() - t0:.1f} s ({sm.calls} model evaluations)",
              file=sys.stderr)
    return _CACHE[key]


def _progress(plant, t0, g, G, said) -> bool:
    if not said and time.perf_counter() - t0 > PROGRESS_AFTER:
        print(f"bounds of {plant.model_name!r}: computing over {G} workspace points ({g}/{G} done)...", file=sys.stderr)
        return True
    return said


def chain_bounds(plant, phi_bounds, gamma_bounds):
    """(phibar (n,), gamma_m (n,), gamma_M (n,)) in chain units: see the module docstring."""
    D = np.array([max(abs(lo), abs(hi)) for lo, hi in phi_bounds], dtype=float)
    g = np.array(gamma_bounds, dtype=float)
    if np.any(g[:, 0] <= 0):
        raise ParameterError("gamma", "gain factors > 0 for the bounds", list(g[:, 0]))
    t = tables(plant)
    ws, dofs = plant.workspace, plant.dof_ids
    rows = np.abs(t["F"][:, dofs])  # (G, n, nv): |F_i c|
    loops = rows[:, :, dofs]  # (G, n, n): |F_i dj|
    torque = g[:, 1] * plant.b * ws.u_max  # the largest torque (rate) each loop's actuator gives
    others = loops @ torque - np.einsum("gii->gi", loops) * torque
    extra = loops @ D + others
    m, _, _ = plant.compile(0.001)
    friction = np.asarray(m.dof_frictionloss, dtype=float)
    if plant.r == 2:
        extra = extra + rows @ friction
    phibar = (t["state"] + extra).max(axis=0)
    if plant.r == 3 and np.any(friction > 0):
        phibar = np.full(plant.n, np.inf)
    return phibar, g[:, 0] * plant.b * t["diag"].min(axis=0), g[:, 1] * plant.b * t["diag"].max(axis=0)

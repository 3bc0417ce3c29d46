"""The arm (models/arm.xml): a vertical stack of two actuated hinge joints, one control loop per joint.

Parameters (defaults in DEFAULTS): link_lengths (m), link_masses (kg), armature (kg m^2, the
reflected rotor inertia of geared motors, MuJoCo joint armature; default [0.2, 0.1]), friction (N m,
dry), damping (N m s/rad), and the workspace of the bounds below.
Why armature by default: without it the inertia coupling of this light two-link arm is so strong
that no decentralised robust design closes (the bound on joint 0's phi through joint 1's torque
needs more torque than joint 1 may use, and vice versa); with rotor inertia, as on any geared
arm, the computed bounds are consistent with the default u_max.

Joint dynamics: M(q) q'' = tau + tau_d + f(q, q'), with tau_j = g_j(t) u_j the motor torques
(u in N m, g_j the LoopSpec's gamma signal: a dimensionless gain factor, nominal 1), tau_d the
injected disturbance torques (the LoopSpec's phi signal, in N m), f = passive - bias (gravity,
Coriolis/centrifugal, damping). Loop i sees the perturbed double integrator
z = (q_i - ref_i, q_i'),  z_2' = phi_i + gamma_i u_i  with

    gamma_i = g_i (M^-1)_ii                      (chain units: rad/s^2 per unit u)
    phi_i   = [M^-1 (tau_d + f + tau_others)]_i  (rad/s^2), tau_others = the other motors' torques

(the same M^-1 row also mixes the loop's own tau_d). Both are recorded at every sample from MuJoCo's
M, bias and passive forces of that instant; dry friction (a constraint force solved after the
controller) is only in the bound. Joint damping is in the recorded phi, but note that MuJoCo's Euler
integrates damping implicitly (an O(h) difference).

Bounds (:func:`arm_bounds`) for the stated workspace (params): q in [q_min, q_max] (rad, per joint),
|q'| <= qd_max (rad/s), |u_j| <= u_max (N m, the commanded torque: it bounds the coupling through
the other motors), disturbance torques |tau_d_j| <= D_j and gain factors g_j in [g_m, g_M]:

    gamma_m_i = g_m,i min_q (M^-1)_ii,   gamma_M_i = g_M,i max_q (M^-1)_ii
    phibar_i  = max_{q, q'} ( |[M^-1 f(q, q')]_i| + sum_j |M^-1_ij| (D_j + friction_j)
                              + sum_{j != i} |M^-1_ij| g_M,j u_max_j )

f is exactly quadratic in q' (f = f0 + L q' + q'^T Q q', identified from MuJoCo by polarization),
so the max over q' is evaluated on a dense grid including the box corners; q is gridded with
``grid`` points per joint (corners included). The bounds hold for runs that stay in the workspace:
a run can check that from its records (q, q', u).
"""

from __future__ import annotations

import itertools
import json

import mujoco
import numpy as np

from ftstab_mj.errors import ParameterError
from ftstab_mj.plants.base import Plant, check_keys, load_spec, register_plant
from ftstab_mj.validate import number_problem

N_LINKS = 2
MAX_GRID = 161  # q grid points per joint of the bound tables (measured: 41 -> 0.5 s, 121 -> 4.3 s)
DEFAULTS = {"link_lengths": [0.5, 0.4], "link_masses": [1.0, 0.5], "armature": [0.2, 0.1], "friction": 0.0, "damping": 0.0,
            "q_min": [-0.3, -0.8], "q_max": [0.9, 0.6], "qd_max": [2.0, 3.0], "u_max": [15.0, 5.0], "grid": 41}


# Workspace tables of the bounds, by the plant's normalized params (JSON): they take ~0.7 s and
# depend on nothing else, and a scenario run builds the plant twice (the loader validates and
# computes "computed" bounds, the runner simulates).
_WORKSPACE_TABLES: dict[str, tuple] = {}


def _vector(params, key, positive=False, nonneg=False) -> np.ndarray:
    v = params.get(key, DEFAULTS[key])
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        v = [v] * N_LINKS
    ok = isinstance(v, (list, tuple, np.ndarray)) and len(v) == N_LINKS
    ok = ok and all(number_problem(x) is None and (x > 0 if positive else x >= 0 if nonneg else True) for x in v)
    if not ok:
        what = f"{N_LINKS} finite numbers" + (" > 0" if positive else " >= 0" if nonneg else "")
        raise ParameterError(f"params.{key}", what, v)
    return np.array(v, dtype=float)


class ArmPlant(Plant):
    """The two-joint arm; loops "joint0" (base) and "joint1"."""

    def __init__(self, model_name: str, params: dict):
        check_keys(model_name, params, DEFAULTS)
        lengths = _vector(params, "link_lengths", positive=True)
        masses = _vector(params, "link_masses", positive=True)
        armature = _vector(params, "armature", nonneg=True)
        friction = _vector(params, "friction", nonneg=True)
        damping = _vector(params, "damping", nonneg=True)
        q_min, q_max = _vector(params, "q_min"), _vector(params, "q_max")
        if np.any(q_min >= q_max):
            raise ParameterError("params.q_max", "numbers above q_min", list(q_max))
        qd_max = _vector(params, "qd_max", nonneg=True)
        u_max = _vector(params, "u_max", nonneg=True)
        grid = params.get("grid", DEFAULTS["grid"])
        if isinstance(grid, bool) or not isinstance(grid, (int, np.integer)) or not 2 <= grid <= MAX_GRID:
            raise ParameterError("params.grid", f"an integer in [2, {MAX_GRID}] (the bounds evaluate grid^2 "
                                 "configurations at ~0.3 ms each: 161 takes ~8 s)", grid)
        spec = load_spec("arm.xml")
        for i in range(N_LINKS):
            g = spec.geom(f"link{i}")
            g.fromto = [0, 0, 0, 0, 0, lengths[i]]
            g.mass = masses[i]
            j = spec.joint(f"joint{i}")
            j.frictionloss = friction[i]
            j.armature = armature[i]
            j.damping = [damping[i], 0.0, 0.0]
        spec.body("link1").pos = [0, 0, lengths[0]]
        spec.site("tip").pos = [0, 0, lengths[1]]
        super().__init__(spec)
        self.model_name = model_name
        self.params = {"link_lengths": lengths.tolist(), "link_masses": masses.tolist(), "armature": armature.tolist(),
                       "friction": friction.tolist(), "damping": damping.tolist(), "q_min": q_min.tolist(),
                       "q_max": q_max.tolist(), "qd_max": qd_max.tolist(), "u_max": u_max.tolist(), "grid": int(grid)}
        self.friction, self.q_min, self.q_max, self.qd_max, self.u_max = friction, q_min, q_max, qd_max, u_max
        self.grid = int(grid)
        self.loop_names = tuple(f"joint{i}" for i in range(N_LINKS))
        self.r = 2
        self.dist_scale = np.ones(N_LINKS)
        self.body_names = ("link0", "link1")
        self.phi_units = "N m (injected joint torque)"
        self.gamma_units = "motor gain factor (dimensionless, nominal 1; chain gamma = factor x (M^-1)_ii)"
        self._M = np.empty((N_LINKS, N_LINKS))

    def bind(self, m):
        self._pos = np.array([self.sensor_block(m, f"q{i}").start for i in range(N_LINKS)])
        self._vel = np.array([self.sensor_block(m, f"qd{i}").start for i in range(N_LINKS)])

    def set_initial(self, m, d, q0, z0):
        d.qpos[:N_LINKS] = q0
        d.qvel[:N_LINKS] = z0[:, 1]

    def sense(self, d, z):
        s = d.sensordata
        z[:, 0] = s[self._pos]
        z[:, 1] = s[self._vel]

    def true_chain(self, m, d, u, gain, phi_inj):
        """M, bias and passive forces are fresh inside the callback (position/velocity stages)."""
        mujoco.mj_fullM(m, d, self._M)
        Minv = np.linalg.inv(self._M)
        tau = gain * u
        acc = Minv @ (phi_inj + tau + d.qfrc_passive[:N_LINKS] - d.qfrc_bias[:N_LINKS])
        gamma = gain * np.diag(Minv)
        return acc - gamma * u, gamma

    def loop_workspace(self, i: int, ref: float) -> dict:
        """The workspace the bounds were computed for, seen from loop i (see Plant.loop_workspace)."""
        return {"z1_min": float(self.q_min[i] - ref), "z1_max": float(self.q_max[i] - ref),
                "z2_abs_max": float(self.qd_max[i]), "u_abs_max": float(self.u_max[i])}

    def true_bounds(self, phi_bounds, gamma_bounds):
        D = np.array([max(abs(lo), abs(hi)) for lo, hi in phi_bounds])
        g = np.array(gamma_bounds, dtype=float)
        if np.any(g[:, 0] <= 0):
            raise ParameterError("gamma", "gain factors > 0 for the arm's bounds", list(g[:, 0]))
        minv_lo, minv_hi, f_part, coupling = self._workspace_tables()
        # per grid point q: |[M^-1 f]_i| max over q' + sum_j |M^-1_ij| (D_j + fric_j) + others' torques
        extra = coupling @ (D + self.friction)  # (Gq, n)
        others = np.einsum("gij,j->gi", coupling, g[:, 1] * self.u_max) - np.einsum(
            "gii,i->gi", coupling, g[:, 1] * self.u_max)
        phibar = (f_part + extra + others).max(axis=0)
        return phibar, g[:, 0] * minv_lo, g[:, 1] * minv_hi

    def _workspace_tables(self):
        """Over the q grid (Gq points): min/max over q of diag(M^-1) (n,) each, max over q' of
        |[M^-1 f(q, q')]_i| (Gq, n) and |M^-1(q)| (Gq, n, n). Cached by parameters (see
        _WORKSPACE_TABLES)."""
        key = json.dumps(self.params, sort_keys=True)
        if key in _WORKSPACE_TABLES:
            return _WORKSPACE_TABLES[key]
        n, G = N_LINKS, self.grid
        m, d, _ = self.compile(0.001)  # a private MjData: fwdPosition/fwdVelocity never call the control callback
        axes = [np.linspace(self.q_min[i], self.q_max[i], G) for i in range(n)]
        qs = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, n)
        diag = np.empty((len(qs), n))
        f_part = np.empty((len(qs), n))
        coupling = np.empty((len(qs), n, n))
        M = np.empty((n, n))

        def f_at(qd):
            d.qvel[:n] = qd
            mujoco.mj_fwdVelocity(m, d)
            return d.qfrc_passive[:n] - d.qfrc_bias[:n]

        eye = np.eye(n)
        for k, q in enumerate(qs):
            d.qpos[:n] = q
            mujoco.mj_fwdPosition(m, d)
            mujoco.mj_fullM(m, d, M)
            Minv = np.linalg.inv(M)
            # f(q') = f0 + L q' + sum_jl Q[:, j, l] q'_j q'_l, identified by polarization (exact: f is quadratic)
            f0 = f_at(np.zeros(n))
            fp = [f_at(eye[j]) for j in range(n)]
            fm = [f_at(-eye[j]) for j in range(n)]
            L = np.stack([(fp[j] - fm[j]) / 2 for j in range(n)], axis=-1)
            Q = np.zeros((n, n, n))
            for j in range(n):
                Q[:, j, j] = (fp[j] + fm[j]) / 2 - f0
                for l in range(j + 1, n):
                    cross = f_at(eye[j] + eye[l]) - f0 - L[:, j] - L[:, l] - Q[:, j, j] - Q[:, l, l]
                    Q[:, j, l] = Q[:, l, j] = cross / 2
            for i in range(n):  # [M^-1 f]_i is again quadratic in q'
                f_part[k, i] = _max_abs_quadratic(Minv[i] @ f0, Minv[i] @ L, np.einsum("j,jab->ab", Minv[i], Q),
                                                  self.qd_max)
            diag[k] = np.diag(Minv)
            coupling[k] = np.abs(Minv)
        if len(_WORKSPACE_TABLES) >= 32:  # a sweep over arm parameters: keep the cache small
            _WORKSPACE_TABLES.clear()
        _WORKSPACE_TABLES[key] = (diag.min(axis=0), diag.max(axis=0), f_part, coupling)
        return _WORKSPACE_TABLES[key]


def _max_abs_quadratic(c: float, b: np.ndarray, A: np.ndarray, half_widths: np.ndarray) -> float:
    """max |c + b.x + x^T A x| over the box |x_j| <= half_widths_j, exactly.

    The extrema of a quadratic over a box lie at stationary points of its restriction to a face:
    for every face (each coordinate either free or at -w/+w) solve the stationary equations in the
    free coordinates and keep the points inside the box (3^n faces; n = 2 here).
    """
    n = len(b)
    best = 0.0
    for pattern in itertools.product((-1, 0, 1), repeat=n):
        x = np.array(pattern, dtype=float) * half_widths
        free = [j for j in range(n) if pattern[j] == 0]
        if free:
            fixed = [j for j in range(n) if pattern[j] != 0]
            H = 2 * A[np.ix_(free, free)]
            rhs = -(b[free] + 2 * A[np.ix_(free, fixed)] @ x[fixed])
            try:
                x[free] = np.linalg.solve(H, rhs)
            except np.linalg.LinAlgError:  # degenerate face: its extrema are on its own boundary
                continue
            if np.any(np.abs(x[free]) > half_widths[free]):
                continue
        best = max(best, abs(c + b @ x + x @ A @ x))
    return best


register_plant("arm", ArmPlant, "r = 2, loops 'joint0', 'joint1': two stacked hinge joints in a vertical plane "
               "(params: link_lengths, link_masses, armature, friction, damping; bounds' workspace: "
               "q_min, q_max, qd_max, u_max, grid)")

"""The arm: its chain mapping (true phi, gamma), its bounds computed from the model, and set-point control."""

import mujoco
import numpy as np
import pytest

from ftstab_mj.control import HongController, RobustLaw, certify
from ftstab_mj.plants.disturbances import Signal
from ftstab_mj.config.errors import ParameterError
from ftstab_mj.metrics.run_metrics import compute_metrics, workspace_left
from ftstab_mj.plants import make_plant
from ftstab_mj.plants.chain_bounds import max_abs_quadratic
from ftstab_mj.scenario import LoopSpec

from ftstab_mj.simulation.run_loop import simulate

HONG = HongController(2, -0.2, (1.0, 2.0))
PHIS = [Signal("sine", amplitude=0.3, freq=0.5), Signal("random", amplitude=0.1, freq=2.0, seed=1)]  # N m
GAINS = [Signal("sine", offset=1.0, amplitude=0.1, freq=0.3), Signal("random", offset=1.0, amplitude=0.1, freq=1.0, seed=2)]
REF = (0.5, -0.4)


@pytest.fixture(scope="module")
def arm():
    """The default arm and its bounds for PHIS / GAINS (computed once: ~1 s)."""
    plant = make_plant("arm")
    return plant, plant.true_bounds([s.bounds() for s in PHIS], [s.bounds() for s in GAINS])


def test_max_abs_quadratic_is_exact_on_a_box():
    rng = np.random.default_rng(0)
    w = np.array([2.0, 3.0])
    g = np.stack(np.meshgrid(*(np.linspace(-wi, wi, 801) for wi in w), indexing="ij"), axis=-1).reshape(-1, 2)
    for _ in range(5):
        c, b, A = rng.normal(), rng.normal(size=2), rng.normal(size=(2, 2))
        A = A + A.T
        brute = np.abs(c + g @ b + np.einsum("vi,ij,vj->v", g, A, g)).max()
        # x = w y with |y| <= 1: c + (w b).y + y^T (w A w) y
        exact = max_abs_quadratic(np.array([c]), (w * b)[None], (np.outer(w, w) * A)[None])[0]
        assert brute <= exact * (1 + 1e-12) and exact <= brute * (1 + 1e-4)  # a grid approaches the max from below


def _random_states(plant, n, seed):
    rng = np.random.default_rng(seed)
    q = rng.uniform(plant.q_min, plant.q_max, size=(n, 2))
    qd = rng.uniform(-1, 1, size=(n, 2)) * plant.qd_max
    return q, qd


def test_bounds_hold_at_random_workspace_states_and_are_nearly_reached(arm):
    """Independent check of the bounds: at random states of the workspace, with random disturbance
    torques, gain factors and other-motor torques within their ranges, the chain gamma_i and phi_i
    computed directly from MuJoCo (mj_forward: M, bias, passive) stay within the bounds. The q grid
    is not a proof between grid points: allow 0.1 %. The bounds are not loose by construction:
    the sampled extremes come within 25 % of them."""
    plant, (phibar, gm, gM) = arm
    m, d, _ = plant.compile(0.001)
    rng = np.random.default_rng(1)
    M = np.empty((2, 2))
    q, qd = _random_states(plant, 3000, seed=2)
    D = np.array([0.3, 0.1])
    g_lo, g_hi = np.array([0.9, 0.9]), np.array([1.1, 1.1])
    seen_phi, seen_g = np.zeros(2), []
    for k in range(len(q)):
        d.qpos[:2], d.qvel[:2] = q[k], qd[k]
        mujoco.mj_forward(m, d)
        mujoco.mj_fullM(m, d, M)
        Minv = np.linalg.inv(M)
        g = rng.uniform(g_lo, g_hi)
        tau_d = rng.choice([-1, 1], size=2) * D
        u = rng.choice([-1, 1], size=2) * plant.u_max
        gamma = g * np.diag(Minv)
        for i in range(2):
            tau = g * u
            tau[i] = 0.0  # the loop's own motor is gamma_i u_i, not phi
            phi_i = Minv[i] @ (tau_d + tau + d.qfrc_passive[:2] - d.qfrc_bias[:2])
            seen_phi[i] = max(seen_phi[i], abs(phi_i))
        seen_g.append(gamma)
    seen_g = np.array(seen_g)
    assert np.all(seen_phi <= phibar * 1.001)
    assert np.all(seen_g.min(axis=0) >= gm * 0.999) and np.all(seen_g.max(axis=0) <= gM * 1.001)
    assert np.all(seen_phi >= 0.75 * phibar)


def test_recorded_phi_and_gamma_are_the_joint_accelerations():
    """With Euler and one physics step per period, qvel advances by exactly h qacc, and the chain
    says qacc_i = phi_i + gamma_i u_i: the recorded (true) phi and gamma must reproduce the
    measured joint-velocity increments to round-off (gravity, coupling and inertia included).
    No damping here: MuJoCo's Euler integrates joint damping implicitly, so with damping the
    velocity increment is h (M + h B)^-1 (...) and differs from h qacc by O(h)."""
    h = 0.002
    plant = make_plant("arm")
    loops = [LoopSpec(f"joint{i}", controller=RobustLaw(HONG, phibar=20.0, gamma_m=2.0), disturbance=PHIS[i], gain=GAINS[i], z0=(-REF[i], 0.5), ref=REF[i]) for i in range(2)]
    res = simulate(plant, loops, duration=1.0, period=h, physics_step=h)
    for i in range(2):
        s = res.loops[f"joint{i}"]
        np.testing.assert_allclose(np.diff(s["z"][:, 1]), h * (s["phi"] + s["gamma"] * s["u"])[:-1], rtol=0, atol=1e-12)
        assert np.abs(s["phi"]).max() > 1.0  # gravity and coupling are really there


def test_arm_joints_reach_their_set_points_with_the_robust_law_and_the_computed_bounds(arm):
    plant, (phibar, gm, gM) = arm
    loops = [LoopSpec(f"joint{i}", controller=RobustLaw(HONG, phibar=phibar[i], gamma_m=gm[i]), disturbance=PHIS[i], gain=GAINS[i], z0=(0.0 - REF[i], 0.0), ref=REF[i]) for i in range(2)]
    res = simulate(plant, loops, duration=5.0, period=0.002, physics_step=0.001)
    assert res.status == "completed"
    cert = certify(HONG)
    for i, info in enumerate(res.info.loops):
        assert (info.true_phibar, info.true_gamma_m, info.true_gamma_M) == (phibar[i], gm[i], gM[i])
        s = res.loops[f"joint{i}"]
        # the run stayed in the workspace the bounds were computed for (checked below), so the true phi and gamma stayed within the bounds (the robust law's assumption)
        assert np.abs(s["phi"]).max() <= phibar[i] and gm[i] <= s["gamma"].min() and s["gamma"].max() <= gM[i]
        # and the joint reached its set point before Theorem 1's time, then stayed in a band
        V1 = s["V1"]
        T = V1[0] ** (1 - cert.alpha) / (cert.c * (1 - cert.alpha))
        assert s["t"][np.argmax(V1 < 1e-3)] <= T and V1[0] > 1e-3
        assert np.abs(s["z"][-500:, 0]).max() < 0.01  # rad, last second
    assert all(workspace_left(info, res.loops[info.name]["z"], res.loops[info.name]["u"]) == ""
               for info in res.info.loops)


def test_leaving_the_workspace_is_reported(arm):
    """The same set point with a too small torque budget (u_max) and a set point beyond q_max."""
    plant = make_plant("arm", {"u_max": [5.0, 1.0], "q_max": [0.4, 0.6]})
    loops = [LoopSpec(f"joint{i}", controller=RobustLaw(HONG, phibar=10.0, gamma_m=1.0), z0=(0.0 - REF[i], 0.0), ref=REF[i])
             for i in range(2)]
    res = simulate(plant, loops, duration=3.0, period=0.01, physics_step=0.001)
    m = compute_metrics(res.info, res.loops, res.status)["loops"]
    j0, j1 = m["joint0"]["workspace_left"], m["joint1"]["workspace_left"]
    assert f"outside [{-0.3 - REF[0]:g}, {0.4 - REF[0]:g}]" in j0  # q range, in z_1 = q - ref
    assert "|u| reached" in j0 and "> 5" in j0 and "|u| reached" in j1 and "> 1" in j1
    assert m["joint0"]["bound_applies"] is False and m["joint1"]["bound_applies"] is False


@pytest.mark.parametrize("params, match", [
    ({"link_lengths": [0.5]}, "params.link_lengths: expected 2 finite numbers > 0"),
    ({"q_min": [0.0, 0.0], "q_max": [1.0, -1.0]}, "params.q_max: expected numbers above q_min"),
    ({"grid": 1}, r"params.grid: expected an integer in \[2, 161\]"),
    ({"grid": 100000}, r"params.grid: expected an integer in \[2, 161\] \(the bounds evaluate the model at grid\^joints"),
    ({"elbow": 1}, "params.elbow: expected a parameter of model 'arm'"),
])
def test_bad_arm_parameters_are_named(params, match):
    with pytest.raises(ParameterError, match=match):
        make_plant("arm", params)

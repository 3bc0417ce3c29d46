"""The flexible joint: its relative degree and gamma measured on MuJoCo's own dynamics, z read exactly,
phi's bound guaranteed over the workspace, and the chain identity z_r' = phi + gamma u in a run."""

import json

import mujoco
import numpy as np
import pytest

from ftstab_mj.config.errors import ParameterError
from ftstab_mj.plants import make_plant
from ftstab_mj.plants.flexible_joint import Interval, cos, phi_of_z, sin

H = 1e-4  # s: the step of the RK4 trajectories the derivatives are measured on
PARAMS = {"motor_inertia": 0.05, "link_inertia": 0.045, "stiffness": 2.0, "gear": 1.0}


def _link_accelerations(plant, m, d0, u, steps=6):
    """MuJoCo's own link acceleration q'' (mj_forward's qacc) along the RK4 trajectory from d0's state
    with ctrl = u held: q''(0), q''(H), ..."""
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:], d.act[:] = d0.qpos, d0.qvel, d0.act
    d.ctrl[0] = u
    out = []
    for _ in range(steps):
        mujoco.mj_forward(m, d)
        out.append(d.qacc[plant._link_dof])
        mujoco.mj_step(m, d)
    return np.array(out)


def _fd(a):
    """q'', q''', q'''', q^(5) at t = 0 from samples of q'' at 0, H, 2H, ... (one-sided stencils, O(H^2))."""
    return (a[0], (-3 * a[0] + 4 * a[1] - a[2]) / (2 * H), (2 * a[0] - 5 * a[1] + 4 * a[2] - a[3]) / H ** 2,
            (-5 * a[0] + 18 * a[1] - 24 * a[2] + 14 * a[3] - 3 * a[4]) / (2 * H ** 3))


def _state(plant, m, seed):
    d = mujoco.MjData(m)
    rng = np.random.default_rng(seed)
    d.qpos[:] = rng.uniform(-0.8, 0.8, size=2)
    d.qvel[:] = rng.uniform(-1.5, 1.5, size=2)
    d.act[:] = rng.uniform(-0.5, 0.5, size=m.na)
    return d


@pytest.mark.parametrize("damped", [False, True])
def test_relative_degree_4_and_gamma_from_mujoco(damped):
    """From MuJoCo's dynamics alone (RK4 trajectories with two motor torques): q'' and q''' do not depend
    on the torque, and d q''''/du = K gear / (J_m M_l) of the parameters (888.89 here); the plant's
    gamma and its z (q'', q''', q'''') agree with those measurements."""
    params = dict(PARAMS, **({"motor_damping": 0.01, "link_damping": 0.02} if damped else {}))
    plant = make_plant("flexible_joint", params)
    m, _, _ = plant.compile(H, "rk4")
    expected = PARAMS["stiffness"] * PARAMS["gear"] / (PARAMS["motor_inertia"] * PARAMS["link_inertia"])
    for seed in range(3):
        d = _state(plant, m, seed)
        lo, hi = _fd(_link_accelerations(plant, m, d, -0.5)), _fd(_link_accelerations(plant, m, d, 1.5))
        assert lo[0] == hi[0]  # q'': the torque does not enter (bit for bit)
        assert abs(hi[1] - lo[1]) / 2.0 < 1e-6 * abs(hi[2] - lo[2]) / 2.0  # q''': not either (O(H^2) leaks)
        gain = (hi[2] - lo[2]) / 2.0
        assert gain == pytest.approx(expected, rel=1e-5)
        assert plant.gamma_nominal == pytest.approx(expected, rel=1e-12)
        d.ctrl[0] = 1.5
        z = plant.derivatives(m, d, n=5)
        assert z[2] == pytest.approx(hi[0], rel=1e-12, abs=1e-12)
        assert z[3] == pytest.approx(hi[1], rel=1e-5)
        assert z[4] == pytest.approx(hi[2], rel=1e-5)


def test_relative_degree_5_with_an_integrating_motor():
    """The motor integrates its input (act' = ctrl): d q^(5)/du = K gear / (J_m M_l) and q'''' does not
    depend on u; the plant's z_5 = q'''' and its z_5' (derivatives at ctrl) agree with MuJoCo's."""
    plant = make_plant("flexible_joint", dict(PARAMS, integrating=True))
    assert plant.r == 5 and plant.integrating
    m, _, _ = plant.compile(H, "rk4")
    expected = PARAMS["stiffness"] * PARAMS["gear"] / (PARAMS["motor_inertia"] * PARAMS["link_inertia"])
    for seed in range(3):
        d = _state(plant, m, seed)
        lo, hi = _fd(_link_accelerations(plant, m, d, -20.0)), _fd(_link_accelerations(plant, m, d, 20.0))
        assert abs(hi[2] - lo[2]) < 1e-5 * abs(hi[3] - lo[3])
        assert (hi[3] - lo[3]) / 40.0 == pytest.approx(expected, rel=2e-3)  # a third derivative: O(H^2) of q^(7)
        z = plant.derivatives(m, d, control=20.0, n=6)
        assert z[4] == pytest.approx(hi[2], rel=1e-5)
        assert z[5] == pytest.approx(hi[3], rel=2e-3)


@pytest.mark.parametrize("integrating", [False, True])
def test_phi_of_z_is_the_recorded_phi(integrating):
    """The phi the bounds are computed from (a function of z) is the phi recorded at run time (a function
    of the rotor's state), with damping and an injected torque."""
    plant = make_plant("flexible_joint", {"integrating": integrating, "motor_damping": 0.01, "link_damping": 0.02})
    m, _, _ = plant.compile(0.001)
    for seed in range(5):
        d = _state(plant, m, seed)
        d.qfrc_applied[plant._motor_dof] = 0.03
        mujoco.mj_forward(m, d)
        z = plant.derivatives(m, d, n=plant.r)
        inj = 0.7
        phi, gamma = plant.true_chain(m, d, np.array([0.4]), np.array([1.1]), np.array([inj]))
        injected = 0.0 if integrating else 0.03 / plant.dist_scale[0]  # r = 4: the torque on the rotor now
        rate = inj if integrating else 0.0  # r = 5: its rate
        assert phi[0] == pytest.approx(phi_of_z(plant.k, plant.r, list(z)) + injected + rate, rel=1e-11, abs=1e-9)
        assert gamma[0] == pytest.approx(1.1 * plant.gamma_nominal)


def test_sense_and_set_initial_are_inverse():
    for integrating in (False, True):
        plant = make_plant("flexible_joint", {"integrating": integrating, "link_damping": 0.02})
        m, d, _ = plant.compile(0.001)
        z0 = np.array([[0.0, 0.3, -0.7, 1.1, -2.0][:plant.r]])
        plant.set_initial(m, d, np.array([0.25]), z0)
        z = np.empty((1, plant.r))
        plant.sense(d, z)
        assert z[0, 0] == 0.25 and np.allclose(z[0, 1:], z0[0, 1:], rtol=1e-12, atol=1e-12)


def test_interval_sin_cos_enclose():
    rng = np.random.default_rng(0)
    lo = rng.uniform(-10, 10, 2000)
    hi = lo + rng.uniform(0, 4, 2000)
    x = lo + (hi - lo) * np.linspace(0, 1, 2001)[:, None]  # endpoints included, spacing <= 2e-3
    for f, ref in ((sin, np.sin), (cos, np.cos)):
        iv = f(Interval(lo, hi))
        vals = ref(x)
        assert np.all(iv.lo <= vals.min(axis=0)) and np.all(vals.max(axis=0) <= iv.hi)
        # and exact: the sampled range misses at most (spacing)^2 / 8 < 1e-6 at each end
        assert np.all(iv.hi - iv.lo <= (vals.max(axis=0) - vals.min(axis=0)) + 2e-6)


@pytest.mark.parametrize("integrating,damped", [(False, False), (False, True), (True, False)])
def test_phibar_is_guaranteed_and_tight(integrating, damped):
    """phibar holds at 200,000 random states of the workspace box (and its corners), and the sampled
    maximum comes within 2 % of it (cells = 200)."""
    params = {"integrating": integrating, **({"motor_damping": 0.01, "link_damping": 0.02} if damped else {})}
    plant = make_plant("flexible_joint", params)
    phibar, gm, gM = plant.true_bounds([(-0.5, 0.3)], [(0.9, 1.1)])
    box = np.array(plant.workspace_box())
    rng = np.random.default_rng(3)
    z = rng.uniform(box[:, 0], box[:, 1], size=(200_000, plant.r))
    corners = np.array(np.meshgrid(*box, indexing="ij")).reshape(plant.r, -1).T
    z = np.vstack([z, corners])
    vals = np.abs(phi_of_z(plant.k, plant.r, list(z.T))) + 0.5
    assert vals.max() <= phibar[0]
    assert vals.max() >= 0.98 * phibar[0]
    assert gm[0] == pytest.approx(0.9 * plant.gamma_nominal) and gM[0] == pytest.approx(1.1 * plant.gamma_nominal)
    ws = plant.loop_workspace(0, 0.3)
    assert ws["z1_min"] == pytest.approx(box[0, 0] - 0.3) and ws["z3_abs_max"] == box[2, 1]
    assert ("z4_abs_max" in ws) == (integrating or damped)


def test_bad_parameters_are_refused_by_name():
    with pytest.raises(ParameterError, match="params.link_inertia"):
        make_plant("flexible_joint", {"link_inertia": 0.002})  # below m l_c^2 = 0.3 x 0.1^2 = 0.003
    with pytest.raises(ParameterError, match="params.integrating"):
        make_plant("flexible_joint", {"integrating": 1})
    with pytest.raises(ParameterError, match="params.stiffnes"):
        make_plant("flexible_joint", {"stiffnes": 2.0})
    with pytest.raises(ParameterError, match="params.q_max"):
        make_plant("flexible_joint", {"q_min": 0.5, "q_max": 0.1})


@pytest.mark.parametrize("name,tol", [("flexible_joint_r4_robust", 1e-5), ("flexible_joint_r5_robust", 1e-3)])
def test_chain_identity_in_a_logged_run(name, tol, tmp_path):
    """From the run's MCAP log (2 s of the shipped scenario): the increment of z_r per period equals
    h (phi + gamma u) of the sample, relative to |phi + gamma u| (measured 95th percentiles: 1.7e-7 at
    r = 4, 4.5e-5 at r = 5; the issue asks < 5 %). For r = 5 the bound also needs |q'''| <= qddd_max,
    which the metrics do not check: checked here on the log (max 0.44 against 4). The recorded phi
    stays within the computed phibar and gamma above gamma_m."""
    import ftstab_mj

    res = ftstab_mj.run(name, out=tmp_path, overrides=["sim.duration=2.0"])
    s = ftstab_mj.replay(res.logs["mcap"]).samples["link"]
    h = float(res.scenario["sim"]["period"])
    r = s["z"].shape[1]
    assert r == (5 if "r5" in name else 4)
    inc = np.diff(s["z"][:, r - 1]) / h
    pred = (s["phi"] + s["gamma"] * s["u"])[:-1]
    rel = np.abs(inc - pred) / np.abs(pred)
    assert np.percentile(rel, 95) < tol
    plant = make_plant("flexible_joint", {k: v for k, v in res.scenario["plant"].items() if k != "model"})
    ws = plant.loop_workspace(0, 0.0)
    if "z4_abs_max" in ws:
        assert np.abs(s["z"][:, 3]).max() <= ws["z4_abs_max"]
    phibar, gm, _ = plant.true_bounds([(-5.0, 5.0)], [(0.9, 1.1)])  # the scenario's signals
    assert np.abs(s["phi"]).max() <= phibar[0] and s["gamma"].min() >= gm[0] * (1 - 1e-12)


# A series-elastic joint written here (not the shipped model): a drive rotor on a damped hinge reaches a
# capsule arm (its inertia from the geom) through a fixed tendon of stiffness 3 N m/rad, motor gear 2.
SEA = """<mujoco model="sea">
  <option gravity="0 0 -9.81"/>
  <worldbody>
    <body name="drive" pos="0 -0.1 0">
      <joint name="drive_hinge" type="hinge" axis="0 1 0" damping="0.02"/>
      <inertial pos="0 0 0" mass="2" diaginertia="0.05 0.05 0.05"/>
    </body>
    <body name="arm" pos="0 0.1 0">
      <joint name="elbow" type="hinge" axis="0 1 0" damping="0.01"/>
      <geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.02" mass="0.5" contype="0" conaffinity="0"/>
    </body>
  </worldbody>
  <tendon>
    <fixed name="sea_spring" stiffness="3"><joint joint="elbow" coef="1"/><joint joint="drive_hinge" coef="-1"/></fixed>
  </tendon>
  <actuator><motor name="drive_motor" joint="drive_hinge" gear="2"/></actuator>
</mujoco>"""
SEA_LOOP = {"loops": {"elbow": {"joint": "elbow", "actuator": "drive_motor", "u_max": 5.0}},
            "workspace": {"elbow": {"q": [-0.3, 0.6], "qd_max": 1.0, "qdd_max": 1.0, "qddd_max": 3.0}}}


def test_a_user_model_driving_its_joint_through_a_spring_is_a_chain_of_four(tmp_path):
    """The user's series-elastic joint is recognised as r = 4 (r = 5 with an integrating actuator), and
    MuJoCo's own dynamics agree (RK4 trajectories with two torques): q'' and q''' do not depend on u,
    d q''''/du = K gear / (J_m M_l) with K = 3, gear = 2 from the XML and J_m, M_l from MuJoCo's mass
    matrix; the plant's z is MuJoCo's q'' and the measured q''', q''''."""
    (tmp_path / "sea.xml").write_text(SEA)
    plant = make_plant(str(tmp_path / "sea.xml"), SEA_LOOP)
    assert plant.r == 4 and plant.loop_names == ("elbow",)
    m, _, _ = plant.compile(H, "rk4")
    d = _state(plant, m, 0)
    mujoco.mj_forward(m, d)
    M = np.empty((2, 2))
    mujoco.mj_fullM(m, d, M)
    expected = 3.0 * 2.0 / (M[plant._motor_dof, plant._motor_dof] * M[plant._link_dof, plant._link_dof])
    lo, hi = _fd(_link_accelerations(plant, m, d, -0.5)), _fd(_link_accelerations(plant, m, d, 1.5))
    assert lo[0] == hi[0] and abs(hi[1] - lo[1]) / 2.0 < 1e-6 * abs(hi[2] - lo[2]) / 2.0
    assert (hi[2] - lo[2]) / 2.0 == pytest.approx(expected, rel=1e-5)
    assert plant.gamma_nominal == pytest.approx(expected, rel=1e-12)
    d.ctrl[0] = 1.5
    z = plant.derivatives(m, d, n=6)
    assert z[2] == pytest.approx(hi[0], rel=1e-12)
    # the one-sided stencil of q''' errs by H^2/3 q^(5) (this stiffer joint's is larger than the shipped one's)
    assert abs(z[3] - hi[1]) <= H ** 2 / 3 * abs(z[5]) * 1.5
    assert z[4] == pytest.approx(hi[2], rel=1e-4)
    phibar, gm, _ = plant.true_bounds([(0.0, 0.0)], [(1.0, 1.0)])
    assert np.isfinite(phibar[0]) and gm[0] == plant.gamma_nominal
    (tmp_path / "sea5.xml").write_text(SEA.replace('<motor name="drive_motor" joint="drive_hinge" gear="2"/>',
                                                   '<general name="drive_motor" joint="drive_hinge" gear="2" '
                                                   'dyntype="integrator" gainprm="1"/>'))
    loops5 = {"loops": {"elbow": {"joint": "elbow", "actuator": "drive_motor", "integrating": True}}}
    assert make_plant(str(tmp_path / "sea5.xml"), loops5).r == 5


def test_a_user_series_elastic_joint_runs_the_r4_law_with_its_chain_identity(tmp_path):
    """0.3 s of the robust law (designed r = 4 gains, phibar computed over the workspace) on the user's
    model: z of 4 components logged, the increment of z_4 per period equals h (phi + gamma u) (95th
    percentile relative residual < 1e-3; measured 2.1e-4: phi drifts within the Euler step by about
    h/2 |phi'| = 0.4 against |z_4'| ~ 2000 on this stiff joint; the issue asks < 5 %), and the log
    re-runs to the same samples without the model's file (replay --verify)."""
    import ftstab_mj

    (tmp_path / "sea.xml").write_text(SEA)
    raw = {"name": "sea", "description": "a user's series-elastic joint", "plant": {"model": "sea.xml", **SEA_LOOP},
           "sim": {"duration": 0.3, "physics_step": 0.0002, "period": 0.0002},
           "loops": {"elbow": {"z0": [-0.1, 0.0, 0.0, 0.0], "ref": 0.2, "controller": {
               "law": "robust", "k": -0.05, "gains": [0.82723, 1.5168, 3.1113, 100.0],
               "phibar": "computed", "gamma_m": "computed"}}}}
    res = ftstab_mj.run(ftstab_mj.scenario_from_dict(raw, base_dir=tmp_path), out=tmp_path / "o")
    s, h = res.samples["elbow"], 0.0002
    assert s["z"].shape[1] == 4 and res.status == "completed"
    inc = np.diff(s["z"][:, 3]) / h
    pred = (s["phi"] + s["gamma"] * s["u"])[:-1]
    assert np.percentile(np.abs(inc - pred) / np.abs(pred), 95) < 1e-3
    (tmp_path / "sea.xml").unlink()  # the log holds the model: replay --verify re-runs it without the file
    from conftest import run_cli

    out = run_cli("replay", "--verify", res.logs["mcap"])
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr


@pytest.mark.parametrize("edit, says", [
    # the arm hangs from the rotor: the inertias couple
    (lambda x: x.replace('    </body>\n    <body name="arm" pos="0 0.1 0">', '      <body name="arm" pos="0 0.2 0">')
     .replace("</body>\n  </worldbody>", "</body>\n    </body>\n  </worldbody>"), "coupled"),
    # a third hinge on the arm: not the two-hinge chain
    (lambda x: x.replace('contype="0" conaffinity="0"/>\n    </body>',
                         'contype="0" conaffinity="0"/>\n      <body name="tip" pos="0 0 -0.3"><joint name="wrist"/>'
                         '<inertial pos="0 0 -0.05" mass="0.1" diaginertia="0.001 0.001 0.001"/></body>\n    </body>'),
     "3 degrees of freedom"),
    (lambda x: x.replace('damping="0.01"', 'damping="0.01" range="-1 1" limited="true"'), "joint limits"),
])
def test_a_spring_loop_that_is_not_a_chain_is_refused_in_one_line(tmp_path, edit, says):
    from conftest import run_cli

    xml = edit(SEA)
    assert xml != SEA
    (tmp_path / "sea.xml").write_text(xml)
    with pytest.raises(ParameterError) as err:
        make_plant(str(tmp_path / "sea.xml"), SEA_LOOP)
    assert "\n" not in str(err.value) and says in str(err.value), str(err.value)
    if says != "coupled":
        return  # the command line's refusal: once
    (tmp_path / "sea.toml").write_text(
        'name = "sea"\ndescription = "d"\n[sim]\nduration = 0.1\n[plant]\nmodel = "sea.xml"\n[plant.loops.elbow]\njoint = "elbow"\n'
        'actuator = "drive_motor"\n[loops.elbow]\nz0 = [0.1, 0.0, 0.0, 0.0]\n[loops.elbow.controller]\n'
        'law = "robust"\nk = -0.05\ngains = [0.82723, 1.5168, 3.1113, 100.0]\nphibar = 1.0\ngamma_m = 1.0\n')
    res = run_cli("run", tmp_path / "sea.toml", "--out", tmp_path / "o")
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and says in res.stderr, res.stderr


MC_FILE = "scenarios/montecarlo/flexible_joint_r4.toml"
MC_ROWS = "tests/data/flexible_joint_montecarlo.parquet"  # benchmarks/flexible_joint_montecarlo.py --save


def test_theorem1_monte_carlo_on_the_flexible_joint_small_version(tmp_path):
    """The shipped Monte Carlo file on 6 states of its box (the long study: benchmarks/): every run
    stays where the computed bounds hold, settles, and before its T(z0) (measured ratios <= 0.035)."""
    from conftest import ROOT, run_cli

    res = run_cli("montecarlo", ROOT / MC_FILE, "--on", "plant", "--states", "6", "--box", "0.2,0.3,0.3,0.3",
                  "--workers", "2", "--json", "--out", tmp_path / "mc")
    assert res.returncode == 0, res.stderr
    s = json.loads(res.stdout)
    assert s["states"] == s["settled"] == s["with_bound"] == 6 and s["bound_applies"] is True
    assert s["violations"] == 0 and s["ratio"]["max"] <= 1.0


def mc_results_text(rows) -> str:
    """The sentence of docs/flexible-joint.md that states the committed Monte Carlo's results: the
    distribution over the states whose run stayed where the bounds hold (bound_applies), and the rest."""
    from ftstab_mj.studies import montecarlo as mc

    inside = [r for r in rows if r["bound_applies"]]
    out = [r for r in rows if not r["bound_applies"]]
    s = mc.summarize(inside, True)
    q = s["ratio"]
    return (f"{len(rows)} initial states, all settled: {len(inside)} stayed in the workspace of the bounds, "
            f"{s['violations']} of them beyond their T(z0); settle time / T(z0) min {q['min']:.3g}, median "
            f"{q['median']:.3g}, p99 {q['p99']:.3g}, max {q['max']:.3g} (T(z0) {min(r['time_bound'] for r in rows):.3g} "
            f"to {max(r['time_bound'] for r in rows):.3g} s, settle times up to "
            f"{max(r['settle_time'] for r in rows):.3g} s); {len(out)} left the workspace (max ratio "
            f"{max((r['ratio'] for r in out), default=float('nan')):.3g}), where the bound is not claimed")


def test_the_flexible_joint_page_states_the_committed_monte_carlo_and_draws_its_figure(tmp_path):
    """docs/flexible-joint.md's numbers are the summary of the committed rows, and its figure is
    what `ftstab montecarlo` draws from them (re-drawn here, pixel by pixel within 1 % of the pixels)."""
    import matplotlib.image as mpimg
    import pyarrow.parquet as pq
    from conftest import ROOT

    from ftstab_mj.studies import montecarlo as mc

    rows = pq.read_table(ROOT / MC_ROWS).to_pylist()
    page = (ROOT / "docs" / "flexible-joint.md").read_text()
    assert all(np.isfinite(r["settle_time"]) for r in rows)  # "all settled"
    assert mc_results_text(rows) in " ".join(page.split())
    applies = all(r["bound_applies"] for r in rows)
    mc.figure(rows, mc.summarize(rows, applies), "flexible_joint_r4_montecarlo: settle time / T(z0)",
              tmp_path / "f.png")
    a, b = mpimg.imread(tmp_path / "f.png"), mpimg.imread(ROOT / "docs" / "assets" / "flexible_joint_montecarlo.png")
    assert a.shape == b.shape and np.mean(np.any(np.abs(a - b) > 0.1, axis=-1)) < 0.01

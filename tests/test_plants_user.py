"""A model the user brings (plants/user.py): models the project did not write, from installed packages
(gymnasium's MuJoCo assets; MuJoCo's own test model), their chain map against an independent
computation, the native callback against the Python one, the refusals through the real CLI, and a
replay that needs no model file."""

import os
import shutil
import time
from pathlib import Path

import gymnasium
import mujoco
import numpy as np
import pytest
from conftest import run_cli
from test_plants_chain import native_and_python_agree

from ftstab_mj.control import HongController, RobustLaw
from ftstab_mj.plants import make_plant
from ftstab_mj.scenario import LoopSpec

ASSETS = Path(gymnasium.__file__).parent / "envs" / "mujoco" / "assets"
MUJOCO_TEST_MODEL = Path(mujoco.__file__).parent / "testdata" / "model.xml"
# gymnasium's inverted pendulum: an actuated slider (gear 100, ctrlrange -3..3) carrying a passive
# hinge (the pole), both damped, both with limits; the pole's motion enters the slider's phi through M^-1.
PENDULUM = {"loops": {"cart": {"joint": "slider", "actuator": "slide", "saturation": True, "u_max": 1.0}},
            "workspace": {"slider": {"q": [-0.5, 0.5], "qd_max": 1.0}, "hinge": {"q": [-0.5, 0.5], "qd_max": 2.0}},
            "grid": 7}
# gymnasium's reacher: two actuated hinges (unnamed motors, gear 200, ctrlrange -1..1) in a horizontal
# plane, joint1 limited to +-3 rad, and the target's two passive slides (limited, uncoupled).
REACHER = {"loops": {"shoulder": {"joint": "joint0", "saturation": True, "u_max": 0.5},
                     "elbow": {"joint": "joint1", "saturation": True, "u_max": 0.5}},
           "workspace": {"joint0": {"q": [-0.5, 1.0], "qd_max": 3.0}, "joint1": {"q": [-1.0, 1.0], "qd_max": 3.0},
                         "target_x": {"q": [0.05, 0.15], "qd_max": 0.1}, "target_y": {"q": [-0.15, -0.05], "qd_max": 0.1}},
           "grid": 5}


@pytest.mark.parametrize("xml,params", [("inverted_pendulum.xml", PENDULUM), ("reacher.xml", REACHER)])
def test_chain_map_agrees_with_mj_fullM_and_qfrc_bias_at_random_states(xml, params):
    """At random states (all joints, passive ones included), controls, gain factors and injected torques,
    the recorded gamma_i = g_i gear_i (M^-1)_ii and phi_i = q_i'' - gamma_i u_i equal an independent
    computation: M from mj_fullM inverted by NumPy, q'' = M^-1 (qfrc_passive - qfrc_bias + tau_d +
    the motors' gear x ctrl). Different factorizations: equal to 1e-9 relative."""
    plant = make_plant(str(ASSETS / xml), params)
    m, d, _ = plant.compile(0.001)
    rng = np.random.default_rng(0)
    ws = plant.workspace
    M = np.empty((m.nv, m.nv))
    gear = m.actuator_gear[plant.actuator_ids, 0]
    seen = 0.0
    for _ in range(200):
        d.qpos[:] = rng.uniform(ws.q_min, ws.q_max)
        d.qvel[:] = rng.uniform(-1, 1, m.nv) * ws.qd_max
        u = rng.uniform(-1, 1, plant.n) * ws.u_max
        gain = rng.uniform(0.8, 1.2, plant.n)
        inj = rng.uniform(-1, 1, plant.n)
        d.ctrl[plant.actuator_ids] = gain * u  # within the ctrlrange: no saturation here
        d.qfrc_applied[:] = 0.0
        d.qfrc_applied[plant.dof_ids] = inj
        mujoco.mj_fwdPosition(m, d)
        mujoco.mj_fwdVelocity(m, d)
        phi, gamma = plant.true_chain(m, d, u, gain, inj)
        mujoco.mj_fullM(m, d, M)
        Minv = np.linalg.inv(M)
        tau = d.qfrc_passive - d.qfrc_bias + d.qfrc_applied
        tau[plant.dof_ids] += gear * gain * u
        qacc = Minv @ tau
        g_ref = gain * gear * Minv[plant.dof_ids, plant.dof_ids]
        phi_ref = qacc[plant.dof_ids] - g_ref * u
        np.testing.assert_allclose(gamma, g_ref, rtol=1e-9)
        np.testing.assert_allclose(phi, phi_ref, rtol=1e-9, atol=1e-9 * np.abs(qacc).max())
        seen = max(seen, np.abs(phi).max())
    assert seen > 1.0  # the coupling is there (the pole's reaction, the damping, the other motor)


@pytest.mark.parametrize("xml,params", [("inverted_pendulum.xml", PENDULUM), ("reacher.xml", REACHER)])
def test_native_and_python_callbacks_agree_on_a_user_model(xml, params):
    plant = make_plant(str(ASSETS / xml), params)
    hong = HongController(2, -0.2, (1.0, 2.0))
    loops = [LoopSpec(name, z0=(-0.2, 0.0), controller=RobustLaw(hong, 5.0, 50.0), ref=0.1) for name in plant.loop_names]
    native_and_python_agree(plant, loops)


SCENARIO = """name = "user"
description = "a user's model"
[plant]
model = "{model}"
{plant}
[sim]
duration = {duration}
[loops.{loop}]
z0 = [-0.2, 0.0]
ref = 0.1
[loops.{loop}.controller]
law = "robust"
k = -0.2
gains = [1.0, 2.0]
phibar = {phibar}
gamma_m = {gamma_m}
"""


def _plant_toml(params) -> str:
    """The [plant] keys of PENDULUM-like params as TOML lines (tables after the plain keys)."""
    lines = [f"grid = {params['grid']}"] if "grid" in params else []
    for loop, body in params.get("loops", {}).items():
        lines.append(f"[plant.loops.{loop}]")
        lines += [f"{k} = {str(v).lower() if isinstance(v, bool) else repr(v).replace(chr(39), chr(34))}"
                  for k, v in body.items()]
    for joint, body in params.get("workspace", {}).items():
        lines.append(f"[plant.workspace.{joint}]")
        lines += [f"{k} = {v!r}" for k, v in body.items()]
    return "\n".join(lines)


def _scenario(tmp_path, model, params, loop="cart", phibar='"computed"', gamma_m='"computed"', duration=0.2):
    path = tmp_path / "user.toml"
    path.write_text(SCENARIO.format(model=model, plant=_plant_toml(params), loop=loop, phibar=phibar,
                                    gamma_m=gamma_m, duration=duration))
    return path


def _without(params, loop_key=None, **workspace):
    p = {"loops": {k: dict(v) for k, v in params["loops"].items()}, "workspace": dict(params["workspace"]),
         "grid": params["grid"]}
    for k, v in workspace.items():
        p["workspace"][k] = v
    if loop_key:
        for body in p["loops"].values():
            body.pop(loop_key, None)
    return p


CONTACT_XML = """<mujoco><worldbody><geom name="floor" type="plane" size="1 1 .1"/>
<body name="b" pos="0 0 .2"><joint name="x" type="slide" axis="1 0 0"/><geom name="box" type="box" size=".1 .1 .1"/></body>
</worldbody><actuator><motor name="m" joint="x"/></actuator></mujoco>"""
MOTOR_XML = """<mujoco><worldbody><body name="b"><joint name="x" type="slide" axis="1 0 0"/>
<geom type="box" size=".1 .1 .1" contype="0" conaffinity="0"/></body></worldbody>
<actuator><motor name="m" joint="x"/></actuator></mujoco>"""

# (what is refused, model, plant params, loop name, key path in the message, a word of the finding)
REFUSALS = [
    ("a ball joint", str(MUJOCO_TEST_MODEL), {"loops": {"cart": {"joint": "wheel_0"}}}, "cart",
     "plant.loops.cart.joint", "ball joint"),
    ("an actuator that drives another joint", "inverted_pendulum.xml",
     {"loops": {"cart": {"joint": "hinge", "actuator": "slide"}}}, "cart", "plant.loops.cart.actuator", "slider"),
    ("an unactuated loop", "inverted_pendulum.xml", {"loops": {"cart": {"joint": "hinge"}}}, "cart",
     "plant.loops.cart.actuator", "unactuated"),
    ("a ctrlrange that would clamp the law", "inverted_pendulum.xml", _without(PENDULUM, "saturation"), "cart",
     "plant.loops.cart.saturation", "ctrlrange"),
    # the model runs (a note says what the guarantee leaves out); only the computed bound is refused
    ('phibar = "computed" with a joint limit the workspace reaches', "inverted_pendulum.xml",
     _without(PENDULUM, hinge={"q": [-2.0, 0.5], "qd_max": 2.0}), "cart", "loops.cart.controller.phibar",
     "joint limits the workspace reaches or that have no workspace: 'hinge' [-1.571, 1.571]"),
    ('phibar = "computed" with a contact that can happen', "contact.xml",
     {"loops": {"cart": {"joint": "x", "actuator": "m"}}}, "cart", "loops.cart.controller.phibar",
     "contacts can happen (a contact force depends on the ground"),
    ("integrating = true on a motor", "motor.xml", {"loops": {"cart": {"joint": "x", "actuator": "m",
                                                                       "integrating": True}}},
     "cart", "plant.loops.cart.integrating", "dyntype none"),
    ('phibar = "computed" without a workspace', "motor.xml", {"loops": {"cart": {"joint": "x", "actuator": "m"}}},
     "cart", "loops.cart.controller.phibar", "computed"),
    ("a model file that does not exist", "missing.xml", {"loops": {"cart": {"joint": "x"}}}, "cart",
     "plant.model", "missing.xml"),
]


@pytest.mark.parametrize("what,model,params,loop,key,finding", REFUSALS, ids=[r[0] for r in REFUSALS])
def test_what_cannot_be_a_chain_is_refused_in_one_line_through_the_cli(tmp_path, what, model, params, loop, key,
                                                                       finding):
    if model == "inverted_pendulum.xml":
        shutil.copy(ASSETS / model, tmp_path / model)  # relative to the scenario file
    (tmp_path / "contact.xml").write_text(CONTACT_XML)
    (tmp_path / "motor.xml").write_text(MOTOR_XML)
    path = _scenario(tmp_path, model, params, loop=loop)
    proc = run_cli("run", path, "--out", tmp_path / "out")
    assert proc.returncode == 2, proc.stdout + proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert str(path) in lines[0] and f"{key}:" in lines[0] and finding in lines[0], lines[0]
    assert not (tmp_path / "out").exists()


def test_user_model_runs_from_a_path_relative_to_the_scenario_and_replays_without_the_file(tmp_path):
    """The reacher, copied beside the scenario and named relatively; the run is started from another
    directory; the log's /scenario names the resolved file; after the file is deleted, replay
    --verify re-runs from the model XML the log holds, bit for bit. The saturation kept is said."""
    shutil.copy(ASSETS / "reacher.xml", tmp_path / "reacher.xml")
    path = _scenario(tmp_path, "reacher.xml", REACHER, loop="shoulder", duration=0.3)
    text = path.read_text() + '[loops.elbow]\nz0 = [0.1, 0.0]\n[loops.elbow.controller]\nlaw = "robust"\nk = -0.2\n' \
                              'gains = [1.0, 2.0]\nphibar = "computed"\ngamma_m = "computed"\n'
    path.write_text(text)
    proc = run_cli("run", path, "--out", tmp_path / "out", "--json", cwd=Path("/"))
    assert proc.returncode == 0, proc.stderr
    assert "note: loop 'shoulder': ctrlrange [-1.0, 1.0]" in proc.stderr and "kept as its saturation" in proc.stderr
    log = tmp_path / "out" / "user.mcap"
    (tmp_path / "reacher.xml").unlink()
    proc = run_cli("replay", log, "--verify")
    assert proc.returncode == 0, proc.stderr
    assert "bit-identical" in proc.stdout
    from ftstab_mj.logs.reader import read_log

    assert read_log(log).info.scenario["plant"]["model"] == str((tmp_path / "reacher.xml").resolve())


MESH_SLIDER_XML = """<mujoco>
  <asset><mesh name="block" file="block.obj"/></asset>
  <worldbody>
    <body name="block">
      <joint name="slide" type="slide" axis="1 0 0"/>
      <geom type="mesh" mesh="block" density="1000"/>
    </body>
  </worldbody>
  <actuator><motor name="push" joint="slide"/></actuator>
</mujoco>
"""


def _block_obj(side: float) -> str:
    """A closed box side x side x side/10 (m) as Wavefront OBJ: mass 100 side^3 kg at density 1000."""
    h = side / 2
    v = [(x, y, z) for x in (-h, h) for y in (-h, h) for z in (-h / 10, h / 10)]
    faces = [(1, 3, 4, 2), (5, 6, 8, 7), (1, 2, 6, 5), (3, 7, 8, 4), (1, 5, 7, 3), (2, 4, 8, 6)]
    return "".join(f"v {x} {y} {z}\n" for x, y, z in v) + "".join("f %d %d %d %d\n" % f for f in faces)


def test_models_of_equal_text_but_other_meshes_are_never_confused(tmp_path):
    """A compiled model is reused by its MJCF text only when the text determines it: the same text in
    two folders whose meshes differ, or after its mesh file was edited, is another model, and so are its
    bounds (cached too). A slider carrying a mesh box: M = its mass (100 side^3 kg, density 1000), so
    gamma_m = gamma_M = b / M exactly (b = 1: a motor of gear 1). References: MuJoCo compiling each file
    afresh, and the closed form."""
    params = {"loops": {"x": {"joint": "slide", "actuator": "push", "u_max": 1.0}},
              "workspace": {"slide": {"q": [-0.5, 0.5], "qd_max": 1.0}}, "grid": 3}
    paths = []
    for name, side in (("small", 0.1), ("large", 0.3)):
        (tmp_path / name).mkdir()
        (tmp_path / name / "robot.xml").write_text(MESH_SLIDER_XML)
        (tmp_path / name / "block.obj").write_text(_block_obj(side))
        paths.append((tmp_path / name / "robot.xml", side))
    paths.append((paths[0][0], 0.2))  # the small one's mesh edited in place
    for path, side in paths:
        if side == 0.2:  # a later edit (MuJoCo's own asset cache reads a file again when its mtime's second changed)
            (path.parent / "block.obj").write_text(_block_obj(side))
            os.utime(path.parent / "block.obj", (time.time() + 5, time.time() + 5))
        plant = make_plant(str(path), params)
        mass = plant.compile(0.001)[0].body_mass[1]
        fresh = mujoco.MjModel.from_xml_path(str(path)).body_mass[1]
        assert mass == fresh and mass == pytest.approx(100 * side ** 3, rel=1e-6), (path, side)
        _, gamma_m, gamma_M = plant.true_bounds([(0.0, 0.0)], [(1.0, 1.0)])
        np.testing.assert_allclose([gamma_m[0], gamma_M[0]], 1.0 / fresh, rtol=1e-12)


def test_unnamed_actuators_and_geoms_are_named_by_number_and_body(tmp_path):
    """Most models name few actuators and geoms (gymnasium's reacher and pusher name none of their motors):
    a refusal or a note says "actuator #1 (unnamed, counted from 0)" and "geom #2 of body b", not '#1'."""
    from ftstab_mj.config.errors import ParameterError

    path = tmp_path / "unnamed.xml"
    path.write_text("""<mujoco><worldbody><geom name="floor" type="plane" size="1 1 .1"/>
<body name="b" pos="0 0 .2"><joint name="x" type="slide" axis="1 0 0"/><joint name="y" type="slide" axis="0 1 0"/>
<geom type="box" size=".1 .1 .1"/></body></worldbody>
<actuator><motor joint="x"/><motor joint="y" ctrlrange="-1 1"/></actuator></mujoco>""")
    with pytest.raises(ParameterError, match=r"actuator #1 \(unnamed, counted from 0\) with ctrlrange"):
        make_plant(str(path), {"loops": {"a": {"joint": "y"}}})
    notes = make_plant(str(path), {"loops": {"a": {"joint": "y", "saturation": True}}}).notes
    assert any("of actuator #1 (unnamed, counted from 0) kept as its saturation" in n for n in notes), notes
    assert any("contacts that can happen ('floor - geom #1 of body b')" in n for n in notes), notes


def test_a_missing_include_names_the_folder_it_is_read_from(tmp_path):
    """dm_control's suite models include ./common/*.xml: copied alone, the refusal says which include and
    the folder MuJoCo reads it from (the model's), in one line."""
    from ftstab_mj.config.errors import ParameterError
    from ftstab_mj.plants.user import check_model_files

    (tmp_path / "m.xml").write_text('<mujoco><include file="./common/materials.xml"/><worldbody/></mujoco>')
    with pytest.raises(ParameterError) as err:
        check_model_files(tmp_path / "m.xml")
    assert str(err.value) == (f"model: expected an MJCF include (MuJoCo reads m.xml's includes from {tmp_path}/) that "
                              "is a regular file, got './common/materials.xml: no such file'")

"""Runs made on the ideal chain (no MuJoCo plant) in the shape the sinks and metrics consume.

A one-body MJCF stands in for the plant's 3D model: its slide joint's position is z_1.
"""

from __future__ import annotations

import numpy as np

from ftstab_mj.control import AdaptiveLaw, HongController, NominalLaw, RobustLaw
from ftstab_mj.plants.disturbances import Signal
from ftstab_mj.simulation.ideal_chain import simulate_chain
from ftstab_mj.simulation.records import LOOP_FIELDS, LoopInfo, MetricSettings, RunInfo, SampleBatch

CART_XML = """<mujoco>
  <worldbody>
    <geom name="floor" type="plane" size="0 0 0.1"/>
    <body name="cart" pos="0 0 0.1">
      <joint name="x" type="slide" axis="1 0 0"/>
      <geom name="chassis" type="box" size="0.2 0.1 0.05" rgba="0.2 0.4 0.8 1"/>
      <geom name="mast" type="capsule" fromto="0 0 0 0 0 0.3" size="0.02"/>
      <geom name="knob" type="sphere" pos="0 0 0.35" size="0.04"/>
    </body>
  </worldbody>
</mujoco>"""

HONG2 = {"r": 2, "k": -0.2, "gains": (1.0, 2.0), "form": "full"}  # c ~ 1.33 (the reference table of the certificate)
ADAPTIVE = {"kappa": 1.0, "delta": 0.1, "rate": 1.0, "eta": 0.5, "eps": 0.01}


def make_law(law: str, hong=HONG2, params=None):
    h = HongController(**hong)
    if law == "nominal":
        return NominalLaw(h)
    if law == "robust":
        return RobustLaw(h, **params)
    return AdaptiveLaw(h, **(params or ADAPTIVE))


def synthetic_run(law="adaptive", params=None, z0=(1.0, 0.0), period=1e-3, duration=10.0,
                  phi=None, gamma=None, hong=HONG2, name="cart", with_model=True,
                  settings=MetricSettings()):
    """(RunInfo, {name: {field: array}}, body_pos (n,1,3), body_quat (n,1,4)) of a chain run."""
    phi = phi or Signal("constant", 0.0)
    gamma = gamma or Signal("constant", 1.0)
    if law == "adaptive" and params is None:
        params = dict(ADAPTIVE)
    run = simulate_chain(make_law(law, hong, params), list(z0), period, duration, phi=phi, gamma=gamma)
    g_lo, g_hi = gamma.bounds()
    p_lo, p_hi = phi.bounds()
    loop = LoopInfo(name=name, r=hong["r"], law=law, hong=dict(hong), law_params=dict(params or {}),
                    true_phibar=max(abs(p_lo), abs(p_hi)), true_gamma_m=g_lo, true_gamma_M=g_hi)
    info = RunInfo(scenario={"name": "synthetic", "law": law}, loops=(loop,), period=period, physics_step=period,
                   metric_settings=settings, model_xml=CART_XML if with_model else None,
                   body_names=("cart",) if with_model else ())
    arrays = {f: getattr(run, f) for f in LOOP_FIELDS}
    n = len(run.t)
    pos = np.zeros((n, 1 if with_model else 0, 3))
    quat = np.zeros((n, 1 if with_model else 0, 4))
    if with_model:
        pos[:, 0, 0] = run.z[:, 0]
        pos[:, 0, 2] = 0.1
        quat[:, 0, 0] = 1.0
    return info, {name: arrays}, pos, quat


def batches(loops, pos, quat, size):
    """The run cut into SampleBatch of ``size`` samples (the last one shorter)."""
    n = len(next(iter(loops.values()))["t"])
    for i in range(0, n, size):
        yield SampleBatch({k: {f: v[i:i + size] for f, v in a.items()} for k, a in loops.items()},
                          pos[i:i + size], quat[i:i + size])


def write_run(sink, info, loops, pos, quat, status, metrics, batch=1000):
    sink.open(info)
    for b in batches(loops, pos, quat, batch):
        sink.write(b)
    sink.close(status, metrics)

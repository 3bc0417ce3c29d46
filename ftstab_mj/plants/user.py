"""A model the user brings: ``plant.model = "path/to/robot.xml"``, one loop per actuated joint.

Scenario keys (the loader resolves the path relative to the scenario file)::

    [plant]
    model = "robot.xml"
    grid = 15                       # q points per dof of the bounds' grid (qd_grid: q' points, r = 3)
    [plant.loops.<name>]            # one table per control loop (and a [loops.<name>] of the scenario)
    joint = "elbow"                 # a hinge or slide joint
    actuator = "elbow_motor"        # the actuator driving it (joint transmission, fixed gain)
    integrating = false             # true: its dyntype is "integrator", the control sets the torque rate (r = 3)
    saturation = false              # true: keep its ctrlrange/forcerange as the actuator's saturation
    u_max = 5.0                     # |u| of this loop within the workspace (N m or N; r = 3: per s)
    [plant.workspace.<joint>]       # every joint of the model (passive ones too) for computed bounds
    q = [-0.5, 0.5]                 # rad or m
    qd_max = 2.0                    # rad/s or m/s
    qdd_max = 5.0                   # rad/s^2 or m/s^2 (r = 3)

A loop whose actuator drives another hinge coupled to the loop's joint by a fixed tendon with
stiffness is a flexible joint (r = 4, 5 integrating: :func:`flexible_plant`, plants/flexible_joint.py;
its workspace adds qddd_max, and qdddd_max at r = 5, and ``grid`` is the cells per axis of its bound).
The chain map and the refusals are plants/chain.py's. Contacts, joint limits, equality constraints,
tendon limits and free or ball joints are simulated (their forces are part of the recorded phi and
gamma) and said in a note (plant.notes), never refused; they make the computed bounds infinite.
Without a workspace for every hinge and slide joint the bounds are infinite too: only
``phibar = "computed"`` (or ``gamma_m``) needs one, and its refusal names every joint and loop that
lacks it at once.

The run log records the model's XML (RunInfo.model_xml); ``ftstab replay --verify`` re-runs from
it (:func:`recorded_model`) when the file is gone or changed. Mesh and texture files the model
references are still read from disk.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

import mujoco
import numpy as np

from ftstab_mj.plants.callback import control_callback
from ftstab_mj.config.errors import ParameterError
from ftstab_mj.plants.chain import ChainLoop, ChainPlant
from ftstab_mj.plants.chain_bounds import Workspace

LOOP_KEYS = ("joint", "actuator", "integrating", "saturation", "u_max")
WORKSPACE_KEYS = ("q", "qd_max", "qdd_max")
PLANT_KEYS = ("loops", "workspace", "grid", "qd_grid")
_RECORDED: dict[str, str] = {}  # model path -> XML text to use instead of the file (replay --verify)


@contextlib.contextmanager
def recorded_model(path: str, xml: str):
    """Within the block, the model ``path`` is built from ``xml`` (a log's RunInfo.model_xml)."""
    key = str(Path(path))
    before = _RECORDED.get(key)
    _RECORDED[key] = xml
    try:
        yield
    finally:
        if before is None:
            _RECORDED.pop(key, None)
        else:
            _RECORDED[key] = before


def _table(v, key):
    if not isinstance(v, dict):
        raise ParameterError(key, "a table", v)
    return v


def _known(table, allowed, key):
    for k in table:
        if k not in allowed:
            raise ParameterError(f"{key}.{k}", "one of " + ", ".join(allowed), k)


def _num(v, key, positive=False):
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or (positive and v <= 0) or v < 0:
        raise ParameterError(key, "a finite number > 0" if positive else "a finite number >= 0", v)
    return float(v)


def _flag(v, key):
    if not isinstance(v, bool):
        raise ParameterError(key, "true or false", v)
    return v


def check_model_files(path) -> None:
    """ParameterError("model", ...) unless the MJCF file ``path`` and every file it <include>s (nested ones too,
    relative to the model's folder as MuJoCo resolves them) are regular files within the limits
    (config/limits.py: MAX_MJCF_BYTES, MAX_INCLUDE_BYTES, MAX_INCLUDES): MuJoCo would wait for ever on a FIFO,
    never finish /dev/zero, and spend a minute and gigabytes on a huge file before a refusal could come."""
    import os
    import re

    from ftstab_mj.config.limits import MAX_INCLUDE_BYTES, MAX_INCLUDES, MAX_MJCF_BYTES
    from ftstab_mj.config.validate import not_regular

    top = Path(path)
    todo, seen = [(top, MAX_MJCF_BYTES, "model file", top.name)], set()
    while todo:
        p, limit, what, label = todo.pop()  # label: the file's name as the including file writes it
        found = not_regular(p)
        if found:
            missing = what == "include" and found == "no such file"  # say where it was looked for
            raise ParameterError("model", f"an MJCF {what}" + (f" (MuJoCo reads {top.name}'s includes from {top.parent}/)"
                                                               if missing else "") + " that is a regular file",
                                 f"{label}: {found}")
        size = os.stat(p).st_size
        if size > limit:
            raise ParameterError("model", f"an MJCF {what} of at most {limit} bytes (a limit)", f"{p.name}: {size} bytes")
        key = os.path.realpath(p)
        if key in seen:
            continue
        seen.add(key)
        try:
            text = p.read_bytes().decode("utf-8", "replace")
        except OSError as exc:
            raise ParameterError("model", f"a readable MJCF {what}", f"{p.name}: {exc.strerror}") from None
        for name in re.findall(r"<include\b[^>]*?\bfile\s*=\s*[\"']([^\"']*)[\"']", text):
            if len(seen) + len(todo) >= MAX_INCLUDES:
                raise ParameterError("model", f"at most {MAX_INCLUDES} included files (a limit)", f"{top.name}: more")
            todo.append((top.parent / name, MAX_INCLUDE_BYTES, "include", name))


def load_model_spec(path: str) -> mujoco.MjSpec:
    """The MjSpec of the MJCF file (or its recorded XML); ParameterError("model", ...) when unusable."""
    key = str(Path(path))
    try:
        if key in _RECORDED:
            spec = mujoco.MjSpec.from_string(_RECORDED[key])
        elif not os.path.lexists(path):
            raise ParameterError("model", "an MJCF file that exists", f"no file {Path(path).name} in {Path(path).parent}")
        else:
            check_model_files(path)  # regular files of bounded size, the includes too, before MuJoCo reads any
            spec = mujoco.MjSpec.from_file(str(path))
        # One trip through MuJoCo's XML writer: its text is a fixed point of read + write (the first
        # trip rounds derived values such as inertias from geoms), so the run's model and the one a
        # replay rebuilds from the logged XML are the same to the bit.
        with control_callback(None):  # writing the XML compiles the model (callback.py)
            spec = mujoco.MjSpec.from_string(spec.to_xml())
        spec.modelfiledir = str(Path(path).resolve().parent)  # meshes, textures: relative to the file
        return spec
    except ParameterError:
        raise
    except Exception as exc:  # MuJoCo's parser: keep the first line of its message
        raise ParameterError("model", "a valid MJCF model", f"{Path(path).name}: {str(exc).strip().splitlines()[0]}") from None


class UserPlant(ChainPlant):
    """A user's MJCF model; loops and workspace from params (see the module docstring)."""

    def __init__(self, path: str, params: dict):
        _known(_table(params, "params"), PLANT_KEYS, "params")
        spec = load_model_spec(path)
        loops_raw = _table(params.get("loops", {}), "params.loops")
        if not loops_raw:
            raise ParameterError("params.loops", "at least one table [plant.loops.<name>] with joint and actuator", "none")
        loops, u_max = [], []
        for name, body in loops_raw.items():
            key = f"params.loops.{name}"
            _known(_table(body, key), LOOP_KEYS, key)
            joint = body.get("joint")
            if not isinstance(joint, str) or not joint:
                raise ParameterError(f"{key}.joint", "the name of a joint of the model", joint)
            actuator = body.get("actuator", "")
            if not isinstance(actuator, str):
                raise ParameterError(f"{key}.actuator", "the name of an actuator of the model", actuator)
            loops.append(ChainLoop(name, joint, actuator, _flag(body.get("integrating", False), f"{key}.integrating"),
                                   _flag(body.get("saturation", False), f"{key}.saturation")))
            u_max.append(_num(body["u_max"], f"{key}.u_max") if "u_max" in body else None)
        ws_raw = _table(params.get("workspace", {}), "params.workspace")
        ranges = {}
        for joint, body in ws_raw.items():
            key = f"params.workspace.{joint}"
            _known(_table(body, key), WORKSPACE_KEYS, key)
            q = body.get("q")
            if not (isinstance(q, list) and len(q) == 2 and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                                and np.isfinite(x) for x in q) and q[0] < q[1]):
                raise ParameterError(f"{key}.q", "[low, high] with low < high (rad or m)", q)
            ranges[joint] = (float(q[0]), float(q[1]))
        super().__init__(path, spec, loops, joint_ranges=ranges)
        m = self.compile(0.001)[0]
        grid = params.get("grid", 15)
        qd_grid = params.get("qd_grid", 5)
        for k, v in (("grid", grid), ("qd_grid", qd_grid)):
            if isinstance(v, bool) or not isinstance(v, int) or v < 2:
                raise ParameterError(f"params.{k}", "an integer >= 2", v)
        self.params = {"loops": {L.name: {"joint": L.joint, "actuator": L.actuator, "integrating": L.integrating,
                                          "saturation": L.saturation, **({"u_max": u} if u is not None else {})}
                                 for L, u in zip(loops, u_max)}, "grid": grid}
        if self.integrating:
            self.params["qd_grid"] = qd_grid
        if ws_raw:
            self.params["workspace"] = ws_raw
        self.workspace = self._workspace(m, ws_raw, ranges, u_max, grid, qd_grid)

    def _workspace(self, m, ws_raw, ranges, u_max, grid, qd_grid):
        """The Workspace when every joint has one and every loop a u_max, else None (no bounds)."""
        nv = m.nv
        q_min, q_max, qd_max, qdd_max = (np.full(nv, np.nan) for _ in range(4))
        for joint, body in ws_raw.items():
            key = f"params.workspace.{joint}"
            j = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, joint)
            if j < 0:
                raise ParameterError(key, "a joint of the model", joint)
            if int(m.jnt_type[j]) not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
                raise ParameterError(key, "a hinge or slide joint (a free or ball joint has no interval of q)", joint)
            dof = m.jnt_dofadr[j]
            q_min[dof], q_max[dof] = ranges[joint]
            qd_max[dof] = _num(body.get("qd_max"), f"{key}.qd_max", positive=True)
            if self.integrating:
                qdd_max[dof] = _num(body.get("qdd_max"), f"{key}.qdd_max")
        self._missing = ([_name_of(m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in range(m.njnt)
                          if int(m.jnt_type[j]) in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
                          and np.isnan(q_min[m.jnt_dofadr[j]])],
                         [L for L, u in zip(self.loop_names, u_max) if u is None])
        if np.any(np.isnan(q_min)) or any(u is None for u in u_max):
            return None
        return Workspace(q_min=q_min, q_max=q_max, qd_max=qd_max, u_max=np.array(u_max),
                         qdd_max=qdd_max if self.integrating else None, grid=grid, qd_grid=qd_grid)

    def missing_workspace(self) -> str:
        joints, loops = getattr(self, "_missing", ([], []))
        parts = []
        if joints:
            parts.append("[plant.workspace.<joint>] q = [low, high], qd_max" + (", qdd_max" if self.integrating else "")
                         + " for " + ", ".join(repr(j) for j in joints))
        if loops:
            parts.append("u_max in [plant.loops.<name>] for " + ", ".join(repr(L) for L in loops))
        return "no workspace for the bounds: add " + " and ".join(parts) if parts else super().missing_workspace()


def _name_of(m, objtype, i) -> str:
    return mujoco.mj_id2name(m, objtype, i) or f"#{i}"


# -- a loop through a spring: the flexible joint (r = 4, 5) ----------------------------------------
FLEX_WORKSPACE_KEYS = ("q", "qd_max", "qdd_max", "qddd_max", "qdddd_max")  # the link's, rad/s^(i-1)
FLEX_CELLS = 200  # default cells per axis of the flexible joint's guaranteed bound (plant.grid)


def make_user_plant(path: str, params: dict):
    """The plant of the user's model ``path``: a FlexibleJointPlant (r = 4, 5 integrating) when a loop's
    actuator reaches its joint through a spring (:func:`flexible_plant`), else a UserPlant (r = 2, 3)."""
    return flexible_plant(path, params) or UserPlant(path, params)


def flexible_plant(path: str, params: dict):
    """A FlexibleJointPlant when a loop's actuator drives another hinge coupled to the loop's joint by
    a fixed tendon with stiffness (plants/flexible_joint.py: its equations are checked against the
    model's dynamics, d q''/du = d q'''/du = 0, d q''''/du > 0), None when no loop is of that form.
    Refused (ParameterError naming the key) when such a model is not that chain: more loops, contacts,
    limits, constraints or a ctrlrange, an ``integrating`` flag against the actuator's dynamics."""
    from ftstab_mj.plants.chain import beyond_chain, spring_between
    from ftstab_mj.plants.flexible_joint import FlexibleJointPlant

    loops_raw = params.get("loops") if isinstance(params, dict) else None
    if not isinstance(loops_raw, dict) or not all(isinstance(b, dict) for b in loops_raw.values()):
        return None  # UserPlant refuses the shape
    spec = load_model_spec(path)
    with control_callback(None):  # compiling runs a forward pass (callback.py)
        m = spec.copy().compile()
    found = None
    for name, body in loops_raw.items():
        j = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, str(body.get("joint", "")))
        actuator = body.get("actuator") or (_name_of(m, mujoco.mjtObj.mjOBJ_ACTUATOR, 0) if m.nu == 1 else "")
        a = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, str(actuator))
        if j < 0 or a < 0 or m.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_JOINT or m.actuator_trnid[a, 0] == j:
            continue
        motor = int(m.actuator_trnid[a, 0])
        spring = spring_between(m, j, motor)
        if spring:
            found = (name, body, j, motor, a, spring)
            break
    if found is None:
        return None
    name, body, j, motor, a, spring = found
    key = f"params.loops.{name}"
    _known(params, PLANT_KEYS, "params")
    _known(body, LOOP_KEYS, key)
    if len(loops_raw) != 1:
        raise ParameterError("params.loops", f"one loop for a model whose loop {name!r} is a flexible joint (r = 4)",
                             f"{len(loops_raw)} loops")
    beyond, _ = beyond_chain(m)
    if beyond or m.actuator_ctrllimited[a] or m.actuator_forcelimited[a]:
        raise ParameterError("model", f"a flexible joint that is a chain (loop {name!r}: r = 4): two hinges and a "
                             "spring, no contacts, limits, constraints or ctrlrange",
                             "; ".join(beyond + (["a ctrlrange or forcerange"] if m.actuator_ctrllimited[a]
                                                 or m.actuator_forcelimited[a] else [])))
    integrating = _flag(body.get("integrating", False), f"{key}.integrating")
    dyn = int(m.actuator_dyntype[a])
    if dyn not in (int(mujoco.mjtDyn.mjDYN_NONE), int(mujoco.mjtDyn.mjDYN_INTEGRATOR)) \
            or integrating != (dyn == int(mujoco.mjtDyn.mjDYN_INTEGRATOR)):
        raise ParameterError(f"{key}.integrating", "true exactly when the actuator's dyntype is integrator",
                             f"{integrating} with dyntype {mujoco.mjtDyn(dyn).name[6:].lower()}")
    grid = params.get("grid", FLEX_CELLS)
    if isinstance(grid, bool) or not isinstance(grid, int) or not 1 <= grid <= 2000:
        raise ParameterError("params.grid", "an integer in [1, 2000] (cells per axis of the bounds)", grid)
    joint = _name_of(m, mujoco.mjtObj.mjOBJ_JOINT, j)
    ws = {"integrating": integrating, "cells": grid, **{k: None for k in ("q_min", "q_max", "qd_max", "qdd_max",
                                                                           "qddd_max", "qdddd_max", "u_max")}}
    ws_raw = _table(params.get("workspace", {}), "params.workspace")
    if joint in ws_raw and "u_max" in body:
        wkey = f"params.workspace.{joint}"
        w = _table(ws_raw[joint], wkey)
        _known(w, FLEX_WORKSPACE_KEYS, wkey)
        q = w.get("q")
        if not (isinstance(q, list) and len(q) == 2 and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                            and np.isfinite(x) for x in q) and q[0] < q[1]):
            raise ParameterError(f"{wkey}.q", "[low, high] with low < high (rad)", q)
        ws.update(q_min=float(q[0]), q_max=float(q[1]), u_max=_num(body["u_max"], f"{key}.u_max"))
        for k in FLEX_WORKSPACE_KEYS[1:4 if not integrating else 5]:
            ws[k] = _num(w.get(k), f"{wkey}.{k}")
        ws["qdddd_max"] = ws["qdddd_max"] or 0.0  # r = 4: phi does not read q''''
    names = {"link": joint, "motor": _name_of(m, mujoco.mjtObj.mjOBJ_JOINT, motor),
             "actuator": _name_of(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a), "spring": spring}
    return FlexibleJointPlant.from_model(spec, path, params, name, names, ws, key="model")

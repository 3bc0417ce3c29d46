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
    todo, seen = [(top, MAX_MJCF_BYTES, "model file")], set()
    while todo:
        p, limit, what = todo.pop()
        found = not_regular(p)
        if found:
            raise ParameterError("model", f"an MJCF {what} that is a regular file", f"{p.name}: {found}")
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
            todo.append((top.parent / name, MAX_INCLUDE_BYTES, "include"))


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

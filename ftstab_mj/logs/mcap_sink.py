"""MCAP log of a run, readable by Foxglove and by the plain ``mcap`` reader (JSON + jsonschema).

Topics (DESIGN.md "User-facing contracts"); every message is one JSON object:

- ``/loop/<name>``: one message per control sample, fields t (s), z (array of r), u, u0, V1,
  dV1_dzr, phi_hat, gamma_hat, phi, gamma (chain units). Log time = t in ns.
- ``/scenario``: the resolved scenario (one message at t = 0).
- ``/run_info``: the rest of :class:`~ftstab_mj.records.RunInfo` (loops, period, metric settings,
  MJCF, body names), so that replay rebuilds metrics and 3D without the scenario code.
- ``/tf`` (``foxglove.FrameTransforms``) every ``pose_every`` samples and ``/scene``
  (``foxglove.SceneUpdate``, once): the bodies' poses and shapes, for Foxglove's 3D panel.
- ``/metrics``: {"status", "message", "metrics"} at the end.
- File metadata ``versions``: package, MuJoCo, NumPy and Python versions.

Non-finite floats (a diverging run) are written as ``null`` (JSON has no NaN) and read back as NaN.
Each :meth:`McapSink.write` ends the current chunk and flushes the file, so a killed run leaves
every batch written before its last flush readable (see logs/reader.py).
"""

from __future__ import annotations

import platform

import numpy as np
import orjson

from ftstab_mj.errors import LogError
from ftstab_mj.logs.mcap_file import McapFile
from ftstab_mj.logs.scene import model_shapes
from ftstab_mj.records import LOOP_FIELDS, RunInfo, SampleBatch

LOOP_SCHEMA_NAME = "ftstab.LoopSample"
_NUM = {"type": ["number", "null"]}
_UNITS = {
    "t": "time (s)", "z": "state (z_1..z_r), chain units", "u": "control applied, chain units",
    "u0": "Hong's nominal control", "V1": "Lyapunov function V1(z)", "dV1_dzr": "dV1/dz_r",
    "phi_hat": "adaptive (or fixed) disturbance estimate", "gamma_hat": "gain estimate",
    "phi": "true disturbance, chain units", "gamma": "true actuator gain, chain units",
}
LOOP_SCHEMA = {
    "title": LOOP_SCHEMA_NAME, "type": "object",
    "properties": {f: ({"type": "array", "items": _NUM} if f == "z" else dict(_NUM)) | {"description": _UNITS[f]}
                   for f in LOOP_FIELDS},
    "required": list(LOOP_FIELDS),
}
_VEC3 = {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}}
_QUAT = {"type": "object", "properties": {k: {"type": "number"} for k in "xyzw"}}
_TIME = {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}}
_POSE = {"type": "object", "properties": {"position": _VEC3, "orientation": _QUAT}}
_COLOR = {"type": "object", "properties": {k: {"type": "number"} for k in "rgba"}}
FRAME_TRANSFORMS_SCHEMA = {
    "title": "foxglove.FrameTransforms", "type": "object",
    "properties": {"transforms": {"type": "array", "items": {"type": "object", "properties": {
        "timestamp": _TIME, "parent_frame_id": {"type": "string"}, "child_frame_id": {"type": "string"},
        "translation": _VEC3, "rotation": _QUAT}}}},
}
_PRIM = {"type": "array", "items": {"type": "object", "properties": {"pose": _POSE, "size": _VEC3, "color": _COLOR}}}
SCENE_UPDATE_SCHEMA = {
    "title": "foxglove.SceneUpdate", "type": "object",
    "properties": {"deletions": {"type": "array"}, "entities": {"type": "array", "items": {"type": "object", "properties": {
        "timestamp": _TIME, "frame_id": {"type": "string"}, "id": {"type": "string"},
        "lifetime": _TIME, "frame_locked": {"type": "boolean"}, "cubes": _PRIM, "spheres": _PRIM,
        "cylinders": _PRIM}}}},
}
ANY_OBJECT_SCHEMA = {"type": "object"}
WORLD_FRAME = "world"


def versions() -> dict[str, str]:
    """Versions recorded in every log's metadata."""
    import mujoco

    import ftstab_mj

    return {"ftstab_mj": ftstab_mj.__version__, "mujoco": mujoco.__version__, "numpy": np.__version__,
            "python": platform.python_version()}


def _json(obj) -> bytes:
    """Strict JSON bytes (orjson writes NaN and infinities as null)."""
    return orjson.dumps(obj, option=orjson.OPT_SERIALIZE_NUMPY)


def loop_messages(arrays: dict) -> list[bytes]:
    """JSON bytes of each sample of one loop: arrays {field: (n,) or z (n, r)} -> n messages.

    The whole batch goes through one orjson call as a 2-D array (shortest exact float repr, null
    for non-finite), then each row's numbers are put into the message template: ~1 us a sample,
    against ~12 us for a json.dumps of a dict.
    """
    z = np.asarray(arrays["z"], dtype=float)
    n, r = z.shape
    if n == 0:
        return []
    others = [f for f in LOOP_FIELDS if f not in ("t", "z")]
    table = np.column_stack([arrays["t"], z] + [arrays[f] for f in others]).astype(float)
    tmpl = (b'{"t":%s,"z":[' + b",".join([b"%s"] * r) + b"],"
            + b",".join(b'"%s":%%s' % f.encode() for f in others) + b"}")
    numbers = orjson.dumps(table, option=orjson.OPT_SERIALIZE_NUMPY)[2:-2].replace(b"],[", b",").split(b",")
    # one %-formatting over the whole batch (messages separated by newlines, which compact JSON lacks)
    return ((tmpl + b"\n") * n % tuple(numbers)).split(b"\n")[:n]


def _stamp(t_ns: int) -> dict:
    return {"sec": t_ns // 1_000_000_000, "nsec": t_ns % 1_000_000_000}


def scene_update(info: RunInfo) -> dict:
    """foxglove.SceneUpdate with one frame-locked entity per body (and 'world') holding its geoms."""
    from ftstab_mj.logs.scene import quat_rotate

    entities: dict[str, dict] = {}
    for s in model_shapes(info.model_xml, info.body_names):
        e = entities.setdefault(s.body, {
            "timestamp": _stamp(0), "frame_id": s.body, "id": s.body, "lifetime": _stamp(0),
            "frame_locked": True, "metadata": [], "arrows": [], "cubes": [], "spheres": [], "cylinders": [],
            "lines": [], "triangles": [], "texts": [], "models": []})
        w, x, y, z = s.quat
        color = dict(zip("rgba", s.rgba))
        pose = {"position": dict(zip("xyz", s.pos)), "orientation": {"x": x, "y": y, "z": z, "w": w}}
        full = [2.0 * v for v in s.half_sizes]
        if s.kind == "box":
            e["cubes"].append({"pose": pose, "size": dict(zip("xyz", full)), "color": color})
        elif s.kind == "ellipsoid":
            e["spheres"].append({"pose": pose, "size": dict(zip("xyz", full)), "color": color})
        else:  # cylinder; a capsule is a cylinder with a sphere at each end (Foxglove has no capsule)
            e["cylinders"].append({"pose": pose, "size": dict(zip("xyz", full)), "color": color,
                                   "bottom_scale": 1.0, "top_scale": 1.0})
            if s.kind == "capsule":
                d = 2.0 * s.half_sizes[0]
                for sign in (-1.0, 1.0):
                    c = np.asarray(s.pos) + quat_rotate(s.quat, (0.0, 0.0, sign * s.half_sizes[2]))
                    e["spheres"].append({"pose": {"position": dict(zip("xyz", c.tolist())),
                                                  "orientation": pose["orientation"]},
                                         "size": {"x": d, "y": d, "z": d}, "color": color})
    return {"deletions": [], "entities": list(entities.values())}


class McapSink:
    """Writes a run to an MCAP file at ``path`` (created or overwritten at :meth:`open`).

    pose_rate: Hz of simulated time at which body poses go to ``/tf`` (a display rate: the loop
    samples are all logged); compression: "zstd" | "lz4" | "none", applied per chunk (= per batch).
    Written with :class:`~ftstab_mj.logs.mcap_file.McapFile` (bulk message records).
    """

    def __init__(self, path, pose_rate: float = 60.0, compression: str = "zstd"):
        self.path = str(path)
        self.pose_rate = float(pose_rate)
        self.compression = compression
        self._writer = None
        self._file = None

    def open(self, info: RunInfo) -> None:
        try:
            self._file = open(self.path, "wb")
        except OSError as exc:
            raise LogError(f"{self.path}: cannot write the MCAP log ({exc.strerror})") from None
        w = self._writer = McapFile(self._file, compression={"none": ""}.get(self.compression, self.compression))
        w.start(profile="", library=f"ftstab_mj {versions()['ftstab_mj']}")
        w.add_metadata("versions", versions())
        self._info = info
        self._n = 0
        self._pose_every = max(1, int(round(1.0 / (self.pose_rate * info.period))))
        obj = w.register_schema("ftstab.Object", "jsonschema", _json(ANY_OBJECT_SCHEMA))
        self._ch_scenario = w.register_channel("/scenario", "json", obj)
        self._ch_run = w.register_channel("/run_info", "json", obj)
        self._ch_metrics = w.register_channel("/metrics", "json", obj)
        loop_schema = w.register_schema(LOOP_SCHEMA_NAME, "jsonschema", _json(LOOP_SCHEMA))
        self._ch_loop = {lp.name: w.register_channel(f"/loop/{lp.name}", "json", loop_schema) for lp in info.loops}
        self._ch_tf = None
        if info.model_xml is not None and info.body_names:
            tf = w.register_schema("foxglove.FrameTransforms", "jsonschema", _json(FRAME_TRANSFORMS_SCHEMA))
            self._ch_tf = w.register_channel("/tf", "json", tf)
            sc = w.register_schema("foxglove.SceneUpdate", "jsonschema", _json(SCENE_UPDATE_SCHEMA))
            w.add_message(w.register_channel("/scene", "json", sc), 0, _json(scene_update(info)))
        w.add_message(self._ch_scenario, 0, _json(info.scenario))
        run = info.to_dict()
        del run["scenario"]
        w.add_message(self._ch_run, 0, _json(run))
        w.flush()

    def write(self, batch: SampleBatch) -> None:
        for name, arrays in batch.loops.items():
            times = np.rint(np.asarray(arrays["t"], dtype=float) * 1e9).astype(np.int64)
            self._writer.add_messages(self._ch_loop[name], times, loop_messages(arrays))
        if self._ch_tf is not None and batch.body_pos.shape[1]:  # a batch may come without poses
            self._write_poses(batch)
        self._n += len(batch)
        self._writer.flush()

    def _write_poses(self, batch):
        t = np.asarray(next(iter(batch.loops.values()))["t"], dtype=float)
        finite = np.isfinite(batch.body_pos).all(axis=(1, 2)) & np.isfinite(batch.body_quat).all(axis=(1, 2))
        idx = np.flatnonzero(((self._n + np.arange(len(t))) % self._pose_every == 0) & finite)
        names = self._info.body_names
        times = np.rint(t[idx] * 1e9).astype(np.int64)
        datas = []
        for i, tn in zip(idx.tolist(), times.tolist()):
            stamp = _stamp(tn)
            tfs = []
            for b, name in enumerate(names):
                p = batch.body_pos[i, b].tolist()
                q = batch.body_quat[i, b].tolist()
                tfs.append({"timestamp": stamp, "parent_frame_id": WORLD_FRAME, "child_frame_id": name,
                            "translation": {"x": p[0], "y": p[1], "z": p[2]},
                            "rotation": {"x": q[1], "y": q[2], "z": q[3], "w": q[0]}})
            datas.append(_json({"transforms": tfs}))
        self._writer.add_messages(self._ch_tf, times, datas)

    def close(self, status: str, metrics: dict, message: str = "") -> None:
        if self._writer is None:
            return
        t_end = int(round(self._n * self._info.period * 1e9))
        self._writer.add_message(self._ch_metrics, t_end, _json({"status": status, "message": message, "metrics": metrics}))
        self._writer.finish()
        self._file.close()
        self._writer = None

"""MCAP log of a run, readable by Foxglove, by Rerun's MCAP loader and by the plain ``mcap`` reader.

Topics (a user-facing contract, listed in the README's "Logs" section):

- ``/loop/<name>``: one protobuf message ``ftstab.LoopSample`` per control sample, with the fields
  the run hands over (records.LOOP_FIELDS: t (s), z (r values), u, u0, V1, dV1_dzr, phi_hat,
  gamma_hat, phi, gamma, in chain units; and any field a loop adds), schema in the file
  (logs/encoding.py). Log time = t in ns. NaN and infinities are stored as they are.
- ``/scenario``: the resolved scenario (JSON, one message at t = 0).
- ``/run_info``: the rest of :class:`~ftstab_mj.simulation.records.RunInfo` (loops, period, metric settings,
  MJCF, body names; JSON), so that replay rebuilds metrics and 3D without the scenario code.
- ``/tf`` (``foxglove.FrameTransforms``) every ``pose_every`` samples and ``/scene``
  (``foxglove.SceneUpdate``, once): the bodies' poses and shapes for Foxglove's 3D panel, in the
  official Foxglove protobuf schemas (from foxglove-sdk), which Rerun's MCAP loader also maps.
- ``/metrics``: {"status", "message", "metrics"} at the end (JSON).
- File metadata ``versions``: package, MuJoCo, NumPy and Python versions.

Each :meth:`McapSink.write` ends the current chunk (CRC-32 checked on reading) and flushes the
file, so a killed run leaves every batch written before its last flush readable (logs/reader.py).
"""

from __future__ import annotations

import platform

import numpy as np
import orjson

from ftstab_mj.config.errors import LogWriteError
from ftstab_mj.logs.files import Reserve, create_log, discard, write_errors
from ftstab_mj.logs.encoding import SCHEMA_NAME, LoopLayout, varint
from ftstab_mj.logs.mcap_file import McapFile
from ftstab_mj.logs.scene import model_shapes
from ftstab_mj.simulation.records import RunInfo, SampleBatch

ANY_OBJECT_SCHEMA = {"type": "object"}
WHAT = "MCAP log"
WORLD_FRAME = "world"


def versions() -> dict[str, str]:
    """Versions recorded in every log's metadata."""
    import mujoco

    import ftstab_mj

    return {"ftstab_mj": ftstab_mj.__version__, "log_format": str(ftstab_mj.LOG_FORMAT), "mujoco": mujoco.__version__, "numpy": np.__version__,
            "python": platform.python_version()}


def _json(obj) -> bytes:
    """Strict JSON bytes (orjson writes NaN and infinities as null)."""
    return orjson.dumps(obj, option=orjson.OPT_SERIALIZE_NUMPY)


def _stamp(t_ns: int):
    from foxglove.messages import Timestamp

    return Timestamp(sec=t_ns // 1_000_000_000, nsec=t_ns % 1_000_000_000)


def scene_update(info: RunInfo):
    """foxglove.messages.SceneUpdate with one frame-locked entity per body (and 'world') holding its geoms."""
    from foxglove.messages import (Color, CubePrimitive, CylinderPrimitive, Duration, Pose, Quaternion,
                                   SceneEntity, SceneUpdate, SpherePrimitive, Vector3)

    from ftstab_mj.logs.scene import quat_rotate

    prims: dict[str, dict] = {}
    for s in model_shapes(info.model_xml, info.body_names):
        e = prims.setdefault(s.body, {"cubes": [], "spheres": [], "cylinders": []})
        w, x, y, z = s.quat
        color = Color(**dict(zip("rgba", s.rgba)))
        orientation = Quaternion(x=x, y=y, z=z, w=w)
        pose = Pose(position=Vector3(**dict(zip("xyz", s.pos))), orientation=orientation)
        full = Vector3(**dict(zip("xyz", (2.0 * v for v in s.half_sizes))))
        if s.kind == "box":
            e["cubes"].append(CubePrimitive(pose=pose, size=full, color=color))
        elif s.kind == "ellipsoid":
            e["spheres"].append(SpherePrimitive(pose=pose, size=full, color=color))
        else:  # cylinder; a capsule is a cylinder with a sphere at each end (Foxglove has no capsule)
            e["cylinders"].append(CylinderPrimitive(pose=pose, size=full, color=color, bottom_scale=1.0, top_scale=1.0))
            if s.kind == "capsule":
                d = 2.0 * s.half_sizes[0]
                for sign in (-1.0, 1.0):
                    c = np.asarray(s.pos) + quat_rotate(s.quat, (0.0, 0.0, sign * s.half_sizes[2]))
                    e["spheres"].append(SpherePrimitive(pose=Pose(position=Vector3(**dict(zip("xyz", c.tolist()))),
                                                                  orientation=orientation),
                                                        size=Vector3(x=d, y=d, z=d), color=color))
    return SceneUpdate(entities=[SceneEntity(timestamp=_stamp(0), frame_id=body, id=body, lifetime=Duration(sec=0, nsec=0),
                                             frame_locked=True, **p) for body, p in prims.items()])


def frame_transforms(t_ns: int, names, pos, quat):
    """foxglove.messages.FrameTransforms of the bodies ``names`` at one instant: pos (nbody, 3) m,
    quat (nbody, 4) (w, x, y, z), each body's frame as a child of the world frame. The reference
    whose ``encode()`` :func:`frame_transforms_bytes` reproduces byte for byte."""
    from foxglove.messages import FrameTransform, FrameTransforms, Quaternion, Vector3

    stamp = _stamp(t_ns)
    return FrameTransforms(transforms=[
        FrameTransform(timestamp=stamp, parent_frame_id=WORLD_FRAME, child_frame_id=name,
                       translation=Vector3(x=p[0], y=p[1], z=p[2]), rotation=Quaternion(x=q[1], y=q[2], z=q[3], w=q[0]))
        for name, p, q in zip(names, pos.tolist(), quat.tolist())])


def _varint_bytes(v: np.ndarray, width: int):
    """(bytes (k, width) uint8, used (k, width) bool): the protobuf varint of each v (k,) uint64, its
    bytes in the first used columns."""
    shifts = np.arange(width, dtype=np.uint64) * np.uint64(7)
    rest = v[:, None] >> shifts  # v without its first j 7-bit groups
    more = np.zeros_like(rest, dtype=bool)
    more[:, :-1] = rest[:, 1:] != 0
    data = ((rest & np.uint64(0x7F)) | np.where(more, np.uint64(0x80), np.uint64(0))).astype(np.uint8)
    used = rest != 0
    used[:, 0] = True
    return data, used


def frame_transforms_bytes(times_ns, names, pos, quat) -> list[bytes]:
    """The protobuf encoding of :func:`frame_transforms` at each time of times_ns (k,) int ns, built
    for all k at once by NumPy (the Foxglove objects cost ~4 us a message, 40 % of the MCAP log):
    pos (k, nbody, 3) m, quat (k, nbody, 4) (w, x, y, z). Each message is laid out with every field
    present, as a byte matrix, and the bytes proto3 leaves out (a zero or -0.0 double, a zero
    varint with its tag) are masked away; the lengths follow from the mask. The same bytes as
    ``frame_transforms(t, names, pos[i], quat[i]).encode()`` (tests/test_log_sinks.py checks it with
    zeros, -0.0, NaN and infinities); a message with a sub-message of 128 bytes or more (a long
    body name) is encoded by that reference instead."""
    t = np.asarray(times_ns, dtype=np.int64)
    k = len(t)
    if k == 0:
        return []
    vals = np.concatenate([np.asarray(pos, float), np.asarray(quat, float)[..., [1, 2, 3, 0]]], axis=2)  # x y z qx qy qz qw
    parts, keeps = [], []
    sec, nsec = (a.astype(np.uint64) for a in np.divmod(t, 1_000_000_000))
    stamp, stamp_keep = [], []
    for tag, v, width in ((8, sec, 10), (16, nsec, 5)):  # Timestamp: seconds (1), nanos (2), varints
        data, used = _varint_bytes(v, width)
        stamp += [np.full((k, 1), tag, np.uint8), data]
        stamp_keep += [(v != 0)[:, None], used & (v != 0)[:, None]]
    stamp, stamp_keep = np.hstack(stamp), np.hstack(stamp_keep)
    doubles = np.ascontiguousarray(vals.astype("<f8")).view(np.uint8).reshape(k, len(names), 7, 8)
    tags = np.array([9, 17, 25, 9, 17, 25, 33], np.uint8)  # Vector3 x y z, Quaternion x y z w: fields 1.., 8 bytes
    for b, name in enumerate(names):
        tail = np.frombuffer(_bytes_field(0x12, WORLD_FRAME) + _bytes_field(0x1A, name), np.uint8)
        nz = vals[:, b] != 0.0  # NaN included
        fields = np.concatenate([np.broadcast_to(tags, (k, 7))[:, :, None], doubles[:, b]], axis=2)  # (k, 7, 9)
        field_keep = np.repeat(nz[:, :, None], 9, axis=2)
        n_stamp, n_p, n_q = stamp_keep.sum(axis=1), 9 * nz[:, :3].sum(axis=1), 9 * nz[:, 3:].sum(axis=1)
        n_body = 2 + n_stamp + len(tail) + 2 + n_p + 2 + n_q
        if n_body.max(initial=0) >= 128:  # a varint length of two bytes: not in this layout
            return [frame_transforms(int(ti), names, pos[i], quat[i]).encode() for i, ti in enumerate(t.tolist())]

        def col(v):
            return np.asarray(v, np.uint8).reshape(k, -1) if np.ndim(v) else np.full((k, 1), v, np.uint8)

        row = [col(0x0A), col(n_body), col(0x0A), col(n_stamp), stamp, np.broadcast_to(tail, (k, len(tail))),
               col(0x22), col(n_p), fields[:, :3].reshape(k, 27), col(0x2A), col(n_q), fields[:, 3:].reshape(k, 36)]
        ones = np.ones((k, 1), bool)
        keep = [ones, ones, ones, ones, stamp_keep, np.ones((k, len(tail)), bool), ones, ones,
                field_keep[:, :3].reshape(k, 27), ones, ones, field_keep[:, 3:].reshape(k, 36)]
        parts.append(np.hstack(row))
        keeps.append(np.hstack(keep))
    full, keep = np.hstack(parts), np.hstack(keeps)
    blob = full[keep].tobytes()
    ends = np.cumsum(keep.sum(axis=1)).tolist()
    return [blob[a:b] for a, b in zip([0] + ends[:-1], ends)]


def _bytes_field(tag: int, text: str) -> bytes:
    """A protobuf string field (left out when empty, as proto3 does)."""
    data = text.encode()
    return bytes([tag]) + varint(len(data)) + data if data else b""


class McapSink:
    """Writes a run to an MCAP file at ``path``, created at :meth:`open` without following a symlink
    and replacing only one of our logs unless ``force`` (logs/files.py). A write error (disk full)
    raises LogWriteError naming the file; the file is then cut back to its last complete batch and
    kept open, so that :meth:`close` can still record the status ("failed" and the cause) in the
    room of the 64 KiB reserve the log took at its opening (logs/files.Reserve).

    pose_rate: Hz of simulated time at which body poses go to ``/tf`` (a display rate: the loop
    samples are all logged); compression: "lz4" | "zstd" | "none", applied per chunk (= per batch);
    lz4 by default: 0.5 us a sample against 0.8-1.4 for zstd level 1, files ~20 % larger.
    Written with :class:`~ftstab_mj.logs.mcap_file.McapFile` (bulk message records). live: a
    :class:`~ftstab_mj.logs.live.FoxgloveServer` that publishes everything the file gets, as it is written.
    """

    def __init__(self, path, pose_rate: float = 60.0, compression: str = "lz4", force: bool = False, live=None):
        self.path = str(path)
        self.pose_rate = float(pose_rate)
        self.compression = compression
        self.force = force  # replace a file at path that is not one of our logs (logs/files.py)
        self.live = live
        self.closed_status = None  # the status the log was closed with (None: not closed whole)
        self._writer = None
        self._file = None

    @write_errors(WHAT)
    def open(self, info: RunInfo) -> None:
        self._file = create_log(self.path, self.force, WHAT)  # LogError (bad input) when refused
        self._failed = None  # the write error that stopped the batches (the log then only closes)
        self._reserve = None
        try:
            self._reserve = Reserve(self.path)
            self._start(info)
        except BaseException:  # no half-opened log: the file this call created goes
            self._file.close()
            self._writer = None
            if self._reserve is not None:
                self._reserve.release()
            discard(self.path)
            raise

    def _start(self, info: RunInfo) -> None:
        w = self._writer = McapFile(self._file, compression={"none": ""}.get(self.compression, self.compression))
        if self.live is not None:
            w = self._writer = self.live.mirror(w)
        w.start(profile="", library=f"ftstab_mj {versions()['ftstab_mj']}")
        w.add_metadata("versions", versions())
        self._info = info
        self._n = 0
        self._pose_every = max(1, int(round(1.0 / (self.pose_rate * info.period))))
        obj = w.register_schema("ftstab.Object", "jsonschema", _json(ANY_OBJECT_SCHEMA))
        self._ch_scenario = w.register_channel("/scenario", "json", obj)
        self._ch_run = w.register_channel("/run_info", "json", obj)
        self._ch_metrics = w.register_channel("/metrics", "json", obj)
        self._loops = {}  # loop name -> (channel, LoopLayout), registered at its first batch (its fields)
        self._loop_schemas = {}  # FileDescriptorSet bytes -> schema id
        self._ch_tf = None
        if info.model_xml is not None and info.body_names:
            from foxglove.messages import FrameTransforms, SceneUpdate

            self._ch_tf = self._foxglove_channel("/tf", FrameTransforms)
            w.add_message(self._foxglove_channel("/scene", SceneUpdate), 0, scene_update(info).encode())
        w.add_message(self._ch_scenario, 0, _json(info.scenario))
        run = info.to_dict()
        del run["scenario"]
        w.add_message(self._ch_run, 0, _json(run))
        self._flush()

    def _foxglove_channel(self, topic: str, message_class) -> int:
        schema = message_class.get_schema()
        return self._writer.register_channel(
            topic, "protobuf", self._writer.register_schema(schema.name, schema.encoding, schema.data))

    def _loop_channel(self, name: str, arrays: dict):
        if name not in self._loops:
            layout = LoopLayout.of_batch(arrays)
            data = layout.file_descriptor_set()
            if data not in self._loop_schemas:  # loops with the same fields share one schema
                self._loop_schemas[data] = self._writer.register_schema(SCHEMA_NAME, "protobuf", data)
            channel = self._writer.register_channel(f"/loop/{name}", "protobuf", self._loop_schemas[data])
            self._loops[name] = (channel, layout)
        return self._loops[name]

    def _flush(self) -> None:
        """End the chunk; on a write error cut the file back to its last complete flush (no torn
        record left, every earlier batch readable; the loops registered since are forgotten too),
        and close it when even that fails."""
        try:
            self._writer.flush()
        except OSError as exc:
            self._failed = exc
            try:
                self._writer.rollback()
            except OSError:
                self._abandon()  # the file stays as far as it got; the reader stops at its torn record
                raise exc from None
            schemas, channels = self._writer.ids
            self._loops = {n: cl for n, cl in self._loops.items() if cl[0] <= channels}
            self._loop_schemas = {d: i for d, i in self._loop_schemas.items() if i <= schemas}
            raise

    def _abandon(self) -> None:
        self._reserve.release()
        self._file.close()
        self._writer = None

    @write_errors(WHAT)
    def write(self, batch: SampleBatch) -> None:
        if self._writer is None or self._failed is not None:
            raise LogWriteError(self.path, f"cannot write the {WHAT}: it was abandoned after a write error")
        for name, arrays in batch.loops.items():
            if len(arrays["t"]) == 0:
                continue
            channel, layout = self._loop_channel(name, arrays)
            times = np.rint(np.asarray(arrays["t"], dtype=float) * 1e9).astype(np.int64)
            self._writer.add_fixed_messages(channel, times, layout.encode(arrays))
        if self._ch_tf is not None and batch.body_pos.shape[1]:  # a batch may come without poses
            self._write_poses(batch)
        self._flush()
        self._n += len(batch)  # the samples in the file (the /metrics time)

    def _write_poses(self, batch):
        t = np.asarray(next(iter(batch.loops.values()))["t"], dtype=float)
        finite = np.isfinite(batch.body_pos).all(axis=(1, 2)) & np.isfinite(batch.body_quat).all(axis=(1, 2))
        idx = np.flatnonzero(((self._n + np.arange(len(t))) % self._pose_every == 0) & finite)
        names = self._info.body_names
        times = np.rint(t[idx] * 1e9).astype(np.int64)
        self._writer.add_messages(self._ch_tf, times, frame_transforms_bytes(times, names, batch.body_pos[idx],
                                                                              batch.body_quat[idx]))

    @write_errors(WHAT)
    def close(self, status: str, metrics: dict, message: str = "") -> None:
        """Write /metrics (status, message, metrics) and the summary, also after a batch that could
        not be written (the log ends at its last complete batch, then says how the run ended). When
        even /metrics cannot be written, the log ends at its last complete batch, without a status."""
        if self._writer is None:
            return
        self._reserve.release()  # its room is for what follows, on a disk that may have filled up
        t_end = int(round(self._n * self._info.period * 1e9))
        self._writer.add_message(self._ch_metrics, t_end, _json({"status": status, "message": message, "metrics": metrics}))
        try:
            self._flush()  # /metrics is on disk before the summary, which a full disk may still refuse
        except OSError:
            self._abandon()
            raise
        try:
            self._writer.finish()
            self._file.close()
        except OSError:
            try:
                self._writer.rollback()  # the log ends with its /metrics record, without the summary (index)
            except OSError:
                pass  # ... and a torn summary the reader stops at
            self._abandon()
            self.closed_status = status  # ... so it does record the status
            raise
        self._writer = None
        self.closed_status = status

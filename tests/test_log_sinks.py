"""The MCAP and Rerun sinks: self-describing files holding exactly the samples they were given."""

import json
import struct
from collections import Counter

import mujoco
import numpy as np
import pytest
from mcap.reader import make_reader

from ftstab_mj.errors import LogError
from ftstab_mj.logs import McapSink, RerunSink
from ftstab_mj.metrics import compute_metrics
from ftstab_mj.records import COMPLETED, DIVERGED, LOOP_FIELDS, RunInfo, SampleBatch
from synthetic_runs import batches, synthetic_run, write_run


def _strict_json(data: bytes):
    def no_constant(name):
        raise AssertionError(f"not strict JSON: {name}")

    return json.loads(data, parse_constant=no_constant)


@pytest.fixture(scope="module")
def run():
    info, loops, pos, quat = synthetic_run("adaptive", duration=2.0, period=1e-3)
    return info, loops, pos, quat, compute_metrics(info, loops, COMPLETED)


def _decoded(path, **query):
    """{topic: [(schema name, message, decoded)]} through the plain mcap reader: protobuf channels
    with mcap-protobuf-support's decoder (the schema stored in the file), JSON ones with json."""
    from mcap.decoder import DecoderFactory as Base
    from mcap_protobuf.decoder import DecoderFactory

    class JsonFactory(Base):
        def decoder_for(self, message_encoding, schema):
            return _strict_json if message_encoding == "json" else None

    got = {}
    with open(path, "rb") as f:
        for schema, channel, message, decoded in make_reader(
                f, decoder_factories=[DecoderFactory(), JsonFactory()]).iter_decoded_messages(**query):
            got.setdefault(channel.topic, []).append((schema.name, message, decoded))
    return got


def test_mcap_is_readable_by_the_plain_mcap_reader(tmp_path, run):
    info, loops, pos, quat, metrics = run
    path = tmp_path / "run.mcap"
    write_run(McapSink(path), info, loops, pos, quat, COMPLETED, metrics, batch=700)
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        encodings = {c.topic: (c.message_encoding, summary.schemas[c.schema_id].encoding)
                     for c in summary.channels.values()}
    assert encodings["/loop/cart"] == encodings["/tf"] == encodings["/scene"] == ("protobuf", "protobuf")
    assert encodings["/scenario"] == encodings["/metrics"] == ("json", "jsonschema")
    got = {}
    for topic, msgs in _decoded(path).items():  # every message decodes (a failure raises)
        got[topic] = [(m, d) for _, m, d in msgs]
    assert meta["versions"]["mujoco"] == mujoco.__version__
    assert summary.statistics.message_count == sum(len(v) for v in got.values())
    samples = got["/loop/cart"]
    arrays = loops["cart"]
    assert len(samples) == len(arrays["t"])
    for f in LOOP_FIELDS:  # bit-identical: protobuf doubles are the float64 values themselves
        logged = np.array([getattr(d, f) for _, d in samples], dtype=float)
        assert np.array_equal(logged, arrays[f]), f
    assert [m.log_time for m, _ in samples] == [round(t * 1e9) for t in arrays["t"]]
    assert [m.sequence for m, _ in samples] == list(range(len(samples)))
    assert got["/scenario"][0][1] == info.scenario
    rebuilt = RunInfo.from_dict({"scenario": info.scenario, **got["/run_info"][0][1]})
    assert json.loads(json.dumps(rebuilt.to_dict())) == json.loads(json.dumps(info.to_dict()))  # tuples: lists
    final = got["/metrics"][0][1]
    assert final["status"] == COMPLETED and final["metrics"] == metrics


def test_mcap_3d_scene_and_poses(tmp_path, run):
    info, loops, pos, quat, metrics = run
    path = tmp_path / "run.mcap"
    sink = McapSink(path, pose_rate=100.0)  # every 10th sample at h = 1 ms
    write_run(sink, info, loops, pos, quat, COMPLETED, metrics, batch=333)
    msgs = _decoded(path, topics=["/scene", "/tf"])
    (name, _, scene), = msgs["/scene"]
    assert name == "foxglove.SceneUpdate"  # the official schema, as foxglove-sdk ships it
    ents = {e.id: e for e in scene.entities}
    cart = ents["cart"]
    assert cart.frame_id == "cart" and cart.frame_locked
    assert len(cart.cubes) == 1 and (cart.cubes[0].size.x, cart.cubes[0].size.y, cart.cubes[0].size.z) == (0.4, 0.2, 0.1)
    assert len(cart.cylinders) == 1  # the capsule's body ...
    centres = sorted(s.pose.position.z for s in cart.spheres)
    assert centres == pytest.approx([0.0, 0.3, 0.35])  # ... its two end caps, and the knob
    assert len(ents["world"].cubes) == 1  # the floor plane
    tf = msgs["/tf"]
    assert all(n == "foxglove.FrameTransforms" for n, _, _ in tf)
    every = np.arange(0, len(loops["cart"]["t"]), 10)
    assert [m.log_time for _, m, _ in tf] == [round(t * 1e9) for t in loops["cart"]["t"][every]]
    assert [d.transforms[0].timestamp.ToNanoseconds() for _, _, d in tf] == [m.log_time for _, m, _ in tf]
    xs = [d.transforms[0].translation.x for _, _, d in tf]
    assert np.array_equal(xs, pos[every, 0, 0])


def test_mcap_keeps_nonfinite_values(tmp_path, run):
    info, loops, pos, quat, _ = run
    arrays = {f: v[:5].copy() for f, v in loops["cart"].items()}
    arrays["u"][2], arrays["z"][3, 1] = np.nan, -np.inf
    path = tmp_path / "nan.mcap"
    sink = McapSink(path)
    sink.open(info)
    sink.write(SampleBatch({"cart": arrays}, pos[:5], quat[:5]))
    sink.close(DIVERGED, compute_metrics(info, {"cart": arrays}, DIVERGED), "NaN in u")
    got = _decoded(path, topics=["/loop/cart", "/metrics"])
    data = [d for _, _, d in got["/loop/cart"]]
    assert np.isnan(data[2].u) and data[3].z[1] == -np.inf  # binary doubles: stored as they are
    assert data[2].V1 == arrays["V1"][2]
    final = got["/metrics"][0][2]  # JSON documents (strict: no NaN constant)
    assert final["status"] == DIVERGED and final["message"] == "NaN in u"


def _rrd_entities(path):
    from rerun.chunk import RrdReader

    rows, values = Counter(), {}
    for chunk in RrdReader(str(path)).stream():
        rows[chunk.entity_path] += chunk.num_rows
        if chunk.entity_path == "/loop/cart/u":
            col = chunk.to_record_batch().column("Scalars:scalars").to_pylist()
            values.setdefault("u", []).extend(v[0] for v in col)
    return rows, values


def test_rerun_recording_holds_signals_bodies_and_blueprint(tmp_path, run):
    from rerun.chunk import RrdReader

    info, loops, pos, quat, metrics = run
    path = tmp_path / "run.rrd"
    write_run(RerunSink(path), info, loops, pos, quat, COMPLETED, metrics, batch=600)
    rows, values = _rrd_entities(path)
    n = len(loops["cart"]["t"])
    for f in LOOP_FIELDS[2:]:
        assert rows[f"/loop/cart/{f}"] == n, f
    assert rows["/loop/cart/z/z1"] == rows["/loop/cart/z/z2"] == n
    assert np.array_equal(values["u"], loops["cart"]["u"])
    assert rows["/world/cart"] == n  # body pose per sample
    for geom in ("/world/cart/chassis", "/world/cart/mast", "/world/cart/knob", "/world/world/floor"):
        assert rows[geom] == 1, geom
    assert rows["/run/status"] == 1 and rows["/run/scenario"] == 1
    assert len(RrdReader(str(path)).blueprints()) == 1


def test_unwritable_log_path_is_one_line_log_error(tmp_path, run):
    info = run[0]
    for sink in (McapSink(tmp_path / "missing" / "x.mcap"), RerunSink(tmp_path / "missing" / "x.rrd")):
        with pytest.raises(LogError) as exc:
            sink.open(info)
        assert "missing" in str(exc.value) and "\n" not in str(exc.value)


def test_sinks_accept_a_run_without_3d_model(tmp_path):
    info, loops, pos, quat = synthetic_run("nominal", duration=0.2, with_model=False)
    m = compute_metrics(info, loops, COMPLETED)
    write_run(McapSink(tmp_path / "a.mcap"), info, loops, pos, quat, COMPLETED, m, batch=50)
    write_run(RerunSink(tmp_path / "a.rrd"), info, loops, pos, quat, COMPLETED, m, batch=50)
    with open(tmp_path / "a.mcap", "rb") as f:
        topics = {c.topic for c in make_reader(f).get_summary().channels.values()}
    assert topics == {"/scenario", "/run_info", "/metrics", "/loop/cart"}
    rows, _ = _rrd_entities(tmp_path / "a.rrd")
    assert rows["/loop/cart/V1"] == 200 and not any(k.startswith("/world") for k in rows)


def test_batches_helper_covers_every_sample(run):
    info, loops, pos, quat, _ = run
    assert sum(len(b) for b in batches(loops, pos, quat, 333)) == len(loops["cart"]["t"])


def test_mcap_indexes_point_at_the_messages(tmp_path, run):
    # Foxglove seeks with the chunk indexes (summary) and the message indexes after each chunk:
    # every (log_time, offset) of a message index must land on that message in its chunk.
    from mcap.records import Chunk, ChunkIndex, MessageIndex
    from mcap.stream_reader import StreamReader, breakup_chunk

    info, loops, pos, quat, metrics = run
    path = tmp_path / "run.mcap"
    write_run(McapSink(path), info, loops, pos, quat, COMPLETED, metrics, batch=400)
    chunks, indexes, chunk_index = {}, [], []
    with open(path, "rb") as f:
        reader = StreamReader(f, emit_chunks=True)
        for rec in reader.records:
            if isinstance(rec, Chunk):
                breakup_chunk(rec, validate_crc=True)  # the mcap library's decompression (lz4 here)
                import lz4.frame

                chunks[len(chunks)] = lz4.frame.decompress(rec.data)
            elif isinstance(rec, MessageIndex):
                indexes.append((len(chunks) - 1, rec))
            elif isinstance(rec, ChunkIndex):
                chunk_index.append(rec)
    n_checked = 0
    for k, idx in indexes:
        for log_time, off in idx.records:
            raw = chunks[k]
            assert raw[off] == 0x05  # a Message record starts there
            length = int.from_bytes(raw[off + 1:off + 9], "little")
            channel, _seq, t_log = struct.unpack_from("<HIQ", raw, off + 9)
            assert channel == idx.channel_id and t_log == log_time and off + 9 + length <= len(raw)
            n_checked += 1
    n = len(loops["cart"]["t"])
    assert n_checked >= n + 2  # every loop sample, the /scenario and /run_info messages, the poses
    assert len(chunk_index) == len(chunks)
    got = [d.t for _, _, d in _decoded(path, topics=["/loop/cart"], starting_at=500_000_000,
                                       ending_before=700_000_000)["/loop/cart"]]  # through the chunk indexes
    assert got == [t for t in loops["cart"]["t"].tolist() if 0.5 <= t < 0.7]

"""The MCAP and Rerun sinks: self-describing files holding exactly the samples they were given."""

import json
import struct
from collections import Counter

import mujoco
import numpy as np
import pytest
from mcap.reader import make_reader

import ftstab_mj

from ftstab_mj.plants.disturbances import Signal
from ftstab_mj.config.errors import LogError
from ftstab_mj.logs import McapSink, RerunSink
from ftstab_mj.metrics.run_metrics import compute_metrics
from ftstab_mj.simulation.records import COMPLETED, DIVERGED, LOOP_FIELDS, RunInfo, SampleBatch
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
    assert meta["versions"]["log_format"] == str(ftstab_mj.LOG_FORMAT)  # readers branch on it
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


def test_mcap_pose_messages_are_the_foxglove_encoding_byte_for_byte():
    """The /tf messages built by NumPy (frame_transforms_bytes) are the bytes foxglove-sdk's own
    FrameTransforms.encode() gives (the reference, frame_transforms), for values where proto3 leaves
    a field out (0.0, -0.0) or keeps it (NaN, infinities, denormals), timestamps whose varints take
    1 to 5 bytes, 1 to 3 bodies, an empty name, and a name long enough to need the reference path."""
    from ftstab_mj.logs.mcap_sink import frame_transforms, frame_transforms_bytes

    rng = np.random.default_rng(0)
    special = np.array([0.0, -0.0, np.nan, np.inf, -np.inf, 1e-300, 5e-324, 1.0])
    for names in (["cart"], ["link0", "link1", ""], ["x" * 100]):
        k = 400
        pos, quat = rng.normal(size=(k, len(names), 3)), rng.normal(size=(k, len(names), 4))
        for a in (pos, quat):
            mask = rng.random(a.shape) < 0.3
            a[mask] = rng.choice(special, mask.sum())
        times = np.concatenate([[0, 1, 127, 128, 999_999_999, 10**9, 2**40, (2**32 - 1) * 10**9 + 999_999_999],
                                rng.integers(0, 10**13, k - 8)]).astype(np.int64)
        ref = [frame_transforms(int(t), names, pos[i], quat[i]).encode() for i, t in enumerate(times.tolist())]
        assert frame_transforms_bytes(times, names, pos, quat) == ref, names
    assert frame_transforms_bytes(np.zeros(0, np.int64), ["cart"], np.zeros((0, 1, 3)), np.zeros((0, 1, 4))) == []


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


def _rrd(path):
    """({entity: rows}, {entity: {column: list}}) of a recording's data (time columns as float s)."""
    from rerun.chunk import RrdReader

    rows, cols = Counter(), {}
    for chunk in RrdReader(str(path)).stream():
        rows[chunk.entity_path] += chunk.num_rows
        rb = chunk.to_record_batch()
        for name in rb.schema.names:
            if name.startswith("rerun.controls"):
                continue
            col = rb.column(name)
            values = (col.cast("int64").to_numpy() * 1e-9).tolist() if name == "sim_time" else col.to_pylist()
            cols.setdefault(chunk.entity_path, {}).setdefault(name, []).extend(values)
    return rows, cols


def _blueprint(path):
    """{view name: (class, origin)} and the 3D view's eye controls, read from the recording's blueprint."""
    from rerun.chunk import RrdReader

    reader = RrdReader(str(path))
    (store,) = reader.blueprints()
    views, eye = {}, {}
    for chunk in reader.stream(store=store):
        rb = chunk.to_record_batch()
        names = rb.schema.names
        if "ViewBlueprint:display_name" in names:
            views[rb.column("ViewBlueprint:display_name").to_pylist()[0][0]] = (
                rb.column("ViewBlueprint:class_identifier").to_pylist()[0][0],
                rb.column("ViewBlueprint:space_origin").to_pylist()[0][0])
        if "EyeControls3D:position" in names:
            eye = {k: rb.column(f"EyeControls3D:{k}").to_pylist()[0][0] for k in ("position", "look_target")}
    return views, eye


@pytest.fixture(scope="module")
def robust_rrd(tmp_path_factory):
    """A robust run whose true bounds are within the assumed ones (Theorem 1's bound applies)."""
    info, loops, pos, quat = synthetic_run("robust", params={"phibar": 0.2, "gamma_m": 0.8}, duration=6.0)
    metrics = compute_metrics(info, loops, COMPLETED)
    path = tmp_path_factory.mktemp("rrd") / "robust.rrd"
    write_run(RerunSink(path), info, loops, pos, quat, COMPLETED, metrics, batch=600)
    return path, info, loops, pos, metrics


def test_rerun_blueprint_shows_plots_documents_and_frames_the_plant(robust_rrd):
    path, info, loops, pos, metrics = robust_rrd
    views, eye = _blueprint(path)
    assert views["plant"] == ("3D", "/world")
    assert views["status and metrics"] == ("TextDocument", "/run/status")
    assert views["scenario"] == ("TextDocument", "/run/scenario")
    origins = {origin for cls, origin in views.values() if cls == "TimeSeries"}
    assert origins == {f"/loop/cart/{p}" for p in ("z", "control", "V1", "adaptation", "other")}
    # the camera looks at the middle of where the cart went (x from 1 to ~0) and sees all of it
    target, position = np.array(eye["look_target"]), np.array(eye["position"])
    xs = pos[:600, 0, 0]
    assert xs.min() - 0.2 <= target[0] <= xs.max() + 0.2
    span = xs.max() - xs.min() + 0.4  # the cart's travel plus its chassis
    assert np.linalg.norm(position - target) >= span  # far enough to frame it (>= 53 deg field of view)


def test_rerun_series_are_grouped_by_plot_with_min_max_for_the_control(robust_rrd):
    from rerun.components import AggregationPolicy

    path, info, loops, pos, metrics = robust_rrd
    rows, cols = _rrd(path)
    a, n = loops["cart"], len(loops["cart"]["t"])
    control = cols["/loop/cart/control"]
    assert control["SeriesLines:names"][0] == ["u", "u0"]
    assert control["SeriesLines:aggregation_policy"][0] == [AggregationPolicy.MinMax.value]
    assert np.array_equal(np.array(control["Scalars:scalars"]), np.column_stack([a["u"], a["u0"]]))
    assert np.array_equal(np.array(cols["/loop/cart/z"]["Scalars:scalars"]), a["z"])
    assert np.array_equal(np.array(cols["/loop/cart/adaptation"]["Scalars:scalars"]),
                          np.column_stack([a[f] for f in ("phi_hat", "gamma_hat", "phi", "gamma")]))
    assert cols["/loop/cart/other"]["SeriesLines:names"][0] == ["dV1_dzr"]
    for entity in ("/loop/cart/z", "/loop/cart/control", "/loop/cart/adaptation"):
        colours = cols[entity]["SeriesLines:colors"][0]
        assert len(set(colours)) == len(colours), entity  # no two series of a plot share a colour
    assert rows["/world/cart"] == n  # body pose per sample
    for geom in ("/world/cart/chassis", "/world/cart/mast", "/world/cart/knob", "/world/world/floor"):
        assert rows[geom] == 1, geom
    assert "V1_final" in cols["/run/status"]["TextDocument:text"][-1][0]


def test_rerun_V1_plot_is_log10_with_theorem_1_envelope_above_the_samples(robust_rrd):
    from ftstab_mj.metrics.run_metrics import loop_certificate

    path, info, loops, pos, metrics = robust_rrd
    rows, cols = _rrd(path)
    a = loops["cart"]
    logged = np.array(cols["/loop/cart/V1/log10_V1"]["Scalars:scalars"])[:, 0]
    assert np.array_equal(logged, np.log10(a["V1"]))
    settle = np.array(cols["/loop/cart/V1/settle_level"]["Scalars:scalars"])[:, 0]
    assert np.all(settle == np.log10(info.metric_settings.settle_level))
    cert = loop_certificate(info.loops[0])
    alpha, c = cert.alpha, cert.c
    t_env = np.array(cols["/loop/cart/V1/envelope"]["sim_time"])
    env = 10.0 ** np.array(cols["/loop/cart/V1/envelope"]["Scalars:scalars"])[:, 0]
    # the comparison lemma's identity: V^(1-alpha) + c (1-alpha) t = V1(0)^(1-alpha) on the envelope
    V0 = a["V1"][0]
    inside = t_env < 0.999 * t_env[-1]
    assert np.allclose(env[inside] ** (1 - alpha) + c * (1 - alpha) * t_env[inside], V0 ** (1 - alpha), rtol=1e-9)
    T = metrics["loops"]["cart"]["time_bound"]
    assert cols["/loop/cart/V1/T_z0"]["sim_time"] == [pytest.approx(T, abs=1e-9)] and t_env[-1] == pytest.approx(T, abs=1e-9)  # ns
    # Theorem 1 holds on the run until it settles: every logged V1 is under the envelope
    assert metrics["loops"]["cart"]["bound_applies"]
    settled = metrics["loops"]["cart"]["settle_time"]
    before = a["t"] < settled
    bound = np.interp(a["t"][before], t_env, env)
    assert np.all(a["V1"][before] <= bound * (1 + 1e-12)) and before.sum() > 1000


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
    rows, _ = _rrd(tmp_path / "a.rrd")
    assert rows["/loop/cart/V1/log10_V1"] == 200 + 1 and not any(k.startswith("/world") for k in rows)


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


def test_rerun_plots_stage_fields_beside_the_true_ones(tmp_path):
    # A loop with a sensor/observer/actuator carries z_hat, z_measured and u_applied: the state plot
    # shows them against z, the control plot u_applied against u.
    info, loops, pos, quat = synthetic_run("nominal", duration=0.2)
    a = dict(loops["cart"])
    a["z_measured"] = a["z"] + 1e-3
    a["z_hat"] = a["z"] - 1e-3
    a["u_applied"] = np.clip(a["u"], -0.5, 0.5)
    path = tmp_path / "staged.rrd"
    write_run(RerunSink(path), info, {"cart": a}, pos, quat, COMPLETED, compute_metrics(info, loops, COMPLETED))
    _, cols = _rrd(path)
    z = cols["/loop/cart/z"]
    assert z["SeriesLines:names"][0] == ["z1", "z2", "z_hat1", "z_hat2", "z_measured1", "z_measured2"]
    assert np.array_equal(np.array(z["Scalars:scalars"]), np.hstack([a["z"], a["z_hat"], a["z_measured"]]))
    control = cols["/loop/cart/control"]
    assert control["SeriesLines:names"][0] == ["u", "u0", "u_applied"]
    assert np.array_equal(np.array(control["Scalars:scalars"]), np.column_stack([a["u"], a["u0"], a["u_applied"]]))
    assert len(set(z["SeriesLines:colors"][0])) == 6


def _envelope_names(path):
    """The last name given to the cart's envelope series and the T(z0) note (static: the viewer shows the last)."""
    rows, cols = _rrd(path)
    return cols["/loop/cart/V1/envelope"]["SeriesLines:names"][-1][0], cols["/loop/cart/V1/T_z0/note"]["TextDocument:text"][-1][0]


def test_rerun_names_the_envelope_what_the_report_calls_it(robust_rrd, tmp_path):
    """The envelope's series name and the T(z0) note say "continuous-time guarantee" only where the
    metrics say bound_applies (the report's words, metrics.envelope_kind); a robust law whose
    assumed phibar (0.2) is below the true disturbance (0.5) gets "not a guarantee" and why."""
    from ftstab_mj.metrics.run_metrics import envelope_kind

    path, info, loops, pos, metrics = robust_rrd
    series, note = _envelope_names(path)
    assert metrics["loops"]["cart"]["bound_applies"]
    assert series == "log10 Theorem 1 envelope (continuous-time guarantee)" and note.endswith(" s (continuous-time guarantee)")
    info, loops, pos, quat = synthetic_run("robust", params={"phibar": 0.2, "gamma_m": 0.8}, duration=2.0,
                                           phi=Signal("constant", 0.5))
    metrics = compute_metrics(info, loops, COMPLETED)
    assert not metrics["loops"]["cart"]["bound_applies"]
    write_run(RerunSink(tmp_path / "exceeded.rrd"), info, loops, pos, quat, COMPLETED, metrics, batch=600)
    series, note = _envelope_names(tmp_path / "exceeded.rrd")
    kind = envelope_kind(metrics["loops"]["cart"])
    assert kind == "not a guarantee: the plant leaves the law's bounds (true |phi| <= 0.5, gamma in [1, 1])"
    assert series == f"log10 Theorem 1 envelope ({kind})" and note.endswith(f" s ({kind})")

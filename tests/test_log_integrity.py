"""A log is checked and untrusted input: CRCs catch altered bytes, old JSON logs still read, crafted
logs neither read local files nor allocate what they declare, new per-sample fields pass through."""

import json
import struct
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from conftest import run_cli
from ftstab_mj.config.errors import LogError
from ftstab_mj.logs import McapSink
from ftstab_mj.logs.reader import DamagedLog, read_log
from ftstab_mj.metrics.run_metrics import compute_metrics
from ftstab_mj.simulation.records import COMPLETED, LOOP_FIELDS, RunInfo
from synthetic_runs import synthetic_run, write_run

OLD_JSON_LOG = Path(__file__).parent / "data" / "json_log_v0.1.mcap"  # written by ftstab_mj 0.1 (JSON loops)


@pytest.fixture(scope="module")
def small_log(tmp_path_factory):
    """A real log of 500 samples in 5 chunks, and the samples it was given."""
    info, loops, pos, quat = synthetic_run("adaptive", duration=0.5, period=1e-3)
    path = tmp_path_factory.mktemp("integrity") / "run.mcap"
    write_run(McapSink(path, pose_rate=100.0), info, loops, pos, quat, COMPLETED,
              compute_metrics(info, loops, COMPLETED), batch=100)
    return path, loops["cart"], read_log(path)


def _chunk_spans(data: bytes, with_record_start=False):
    """(start, end) of every Chunk record's compressed data, in file order (and the record's start)."""
    spans, pos = [], 8
    while pos + 9 <= len(data):
        op, length = struct.unpack_from("<BQ", data, pos)
        if op == 0x06:
            comp_len = struct.unpack_from("<I", data, pos + 9 + 28)[0]
            start = pos + 9 + 28 + 4 + comp_len + 8
            spans.append((pos, start, pos + 9 + length) if with_record_start else (start, pos + 9 + length))
        if op == 0x0F:
            break
        pos += 9 + length
    return spans


def test_a_clean_log_has_every_crc_and_they_hold(small_log):
    path, arrays, log = small_log
    assert log.complete and log.crc_checked and log.warning is None and log.encoding == "protobuf"
    from mcap.records import Chunk, DataEnd, Footer
    from mcap.stream_reader import StreamReader, breakup_chunk

    with open(path, "rb") as f:  # the plain mcap library finds the CRCs and checks them
        records = list(StreamReader(f, emit_chunks=True, validate_crcs=True).records)
    chunks = [r for r in records if isinstance(r, Chunk)]
    assert len(chunks) == 7  # start (/scenario, /run_info, /scene), 5 batches, /metrics
    for c in chunks:
        assert c.uncompressed_crc != 0
        breakup_chunk(c, validate_crc=True)  # raises on a mismatch
    (data_end,) = [r for r in records if isinstance(r, DataEnd)]
    (footer,) = [r for r in records if isinstance(r, Footer)]
    assert data_end.data_section_crc != 0 and footer.summary_crc != 0


def test_one_bit_flipped_anywhere_gives_the_intact_samples_or_names_the_damage(small_log, tmp_path):
    # Seeded: 400 offsets over the whole file, one bit each. Every outcome is either exactly the
    # samples the run gave (the flip hit something outside them: an index, the summary) or a
    # one-line DamagedLog/LogError. Never silently different samples, never another exception.
    import lz4.frame

    path, arrays, clean = small_log
    data = path.read_bytes()
    rng = np.random.default_rng(20261201)
    offsets = rng.integers(0, len(data), 400)
    in_chunks = [s for s in _chunk_spans(data)]
    flipped = tmp_path / "flipped.mcap"
    outcomes = {"intact": 0, "damaged": 0, "not a log": 0, "unused bits": 0}
    for off in offsets.tolist():
        bad = bytearray(data)
        bad[off] ^= 1 << int(rng.integers(8))
        flipped.write_bytes(bytes(bad))
        try:
            log = read_log(flipped)
        except DamagedLog as exc:
            assert "\n" not in str(exc) and "damaged log" in str(exc) and "intact before it" in str(exc)
            outcomes["damaged"] += 1
            continue
        except LogError as exc:
            assert "\n" not in str(exc)
            outcomes["not a log"] += 1
            continue
        for a, b in in_chunks:  # a flip in a chunk may pass only where lz4 ignores it (same bytes out)
            if a <= off < b:
                assert lz4.frame.decompress(bytes(bad[a:b])) == lz4.frame.decompress(data[a:b]), off
                outcomes["unused bits"] += 1
        for f in LOOP_FIELDS:
            assert np.array_equal(log.loops["cart"][f], arrays[f], equal_nan=True), (off, f)
        assert np.array_equal(log.pose_pos, clean.pose_pos) and np.array_equal(log.pose_t, clean.pose_t), off
        outcomes["intact"] += 1
    hits = sum(any(a <= off < b for a, b in in_chunks) for off in offsets.tolist())
    assert outcomes["damaged"] >= hits - outcomes["unused bits"] and hits > 100  # every flip in the samples' bytes
    assert outcomes["intact"] > 0  # flips in indexes and summary leave the samples usable


def test_replay_of_a_damaged_chunk_is_one_line_exit_2_saying_what_is_intact(small_log, tmp_path):
    path, arrays, _ = small_log
    data = bytearray(path.read_bytes())
    spans = _chunk_spans(bytes(data))
    a, b = spans[3]  # the 4th chunk: the third batch (samples 200-299), after the start and two batches
    data[(a + b) // 2] ^= 0x10
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    for verb in (("replay", "--json"), ("check", "--pin", str(tmp_path / "x.toml"))):
        res = run_cli(*verb[:1], bad, *verb[1:])
        assert res.returncode == 2 and res.stdout == "", verb
        line, = res.stderr.strip().splitlines()
        assert "chunk 4 fails its CRC check" in line and "200 samples of /loop/cart (up to t = 0.199 s)" in line, line
        assert "Traceback" not in res.stderr


def test_old_json_logs_read_like_the_plain_mcap_reader_reads_them(tmp_path):
    # Reference: the plain mcap reader and json (null = NaN) over the 0.1 file, independent of read_log.
    with open(OLD_JSON_LOG, "rb") as f:
        ref = {}
        for schema, channel, message in make_reader(f).iter_messages():
            assert channel.message_encoding == "json"
            ref.setdefault(channel.topic, []).append(json.loads(message.data))
    log = read_log(OLD_JSON_LOG)
    assert log.encoding == "json" and not log.crc_checked and log.complete  # 0.1 wrote no chunk CRCs
    samples = ref["/loop/cart"]
    for f in LOOP_FIELDS:
        want = np.array([s[f] for s in samples], dtype=float)
        assert np.array_equal(log.loops["cart"][f], want, equal_nan=True), f
    assert log.pose_pos[:, 0, 0].tolist() == [tf["transforms"][0]["translation"]["x"] for tf in ref["/tf"]]
    assert log.recorded == ref["/metrics"][0]
    res = run_cli("replay", OLD_JSON_LOG, "--rrd", tmp_path / "old.rrd")
    assert res.returncode == 0, res.stderr
    assert "identical to the ones recomputed" in res.stdout


def test_new_per_sample_fields_are_logged_and_read_back_generically(tmp_path):
    # The encoding follows the batch's fields: a loop that adds a vector and a scalar field (as
    # an observer's z_hat and an actuator's u_applied would) gets them in the schema and back.
    info, loops, pos, quat = synthetic_run("robust", params={"phibar": 0.1, "gamma_m": 0.9}, duration=0.3)
    arrays = dict(loops["cart"])
    rng = np.random.default_rng(3)
    arrays["z_hat"] = arrays["z"] + rng.normal(0, 1e-3, arrays["z"].shape)
    arrays["u_applied"] = np.clip(arrays["u"], -1.0, 1.0)
    path = tmp_path / "extra.mcap"
    write_run(McapSink(path), info, {"cart": arrays}, pos, quat, COMPLETED,
              compute_metrics(info, loops, COMPLETED), batch=64)
    log = read_log(path)
    assert set(log.loops["cart"]) == set(arrays)
    for f, a in arrays.items():
        assert np.array_equal(log.loops["cart"][f], a), f


def _crafted(tmp_path, name, model_xml, body_names=()):
    """A log written by the sink for a RunInfo carrying ``model_xml`` (no /scene: no body names)."""
    info, loops, pos, quat = synthetic_run("nominal", duration=0.05, with_model=False)
    info = RunInfo(**{**info.__dict__, "model_xml": model_xml, "body_names": tuple(body_names)})
    path = tmp_path / f"{name}.mcap"
    write_run(McapSink(path), info, loops, pos, quat, COMPLETED, compute_metrics(info, loops, COMPLETED))
    return path


@pytest.mark.parametrize("xml, named", [
    ('<mujoco><include file="/dev/zero"/><worldbody/></mujoco>', "<include>"),
    ('<mujoco><compiler meshdir="/etc"/><worldbody/></mujoco>', "meshdir"),
    ('<mujoco><asset><mesh name="m" file="/etc/passwd"/></asset><worldbody/></mujoco>', "<mesh>"),
    ('<mujoco><asset><texture builtin="checker" width="100000" height="100000"/></asset></mujoco>', "<texture>"),
    ('<mujoco><worldbody><replicate count="100000000"><geom size="1"/></replicate></worldbody></mujoco>', "<replicate>"),
    ('<!DOCTYPE m [<!ENTITY a "aaaa">]><mujoco>&a;</mujoco>', "DOCTYPE"),
])
def test_a_logs_model_naming_files_or_bulk_is_never_compiled(tmp_path, xml, named):
    log = read_log(_crafted(tmp_path, "crafted", xml))
    assert log.info.model_xml is None and named in log.warning and "3D model is left out" in log.warning


def test_replay_of_a_log_whose_model_includes_dev_zero_ends_with_a_warning(tmp_path):
    path = _crafted(tmp_path, "zero", '<mujoco><include file="/dev/zero"/><worldbody/></mujoco>')
    res = run_cli("replay", path, "--rrd", tmp_path / "c.rrd", timeout=60)  # compiling it would never end
    assert res.returncode == 0, res.stderr
    assert res.stderr.startswith("warning: ") and "<include>" in res.stderr and len(res.stderr.splitlines()) == 1


def test_declared_lengths_beyond_the_file_are_refused_before_allocating(small_log, tmp_path):
    path, _, _ = small_log
    data = bytearray(path.read_bytes())
    chunk_start = _chunk_spans(bytes(data), with_record_start=True)[2][0]
    cases = {}
    huge_record = bytearray(data)
    struct.pack_into("<Q", huge_record, chunk_start + 1, 1 << 62)  # the chunk record's length
    cases["huge record"] = (huge_record, "declares 4611686018427387904 bytes, past the end")
    huge_chunk = bytearray(data)
    struct.pack_into("<Q", huge_chunk, chunk_start + 9 + 16, 1 << 40)  # its uncompressed size
    cases["huge chunk"] = (huge_chunk, "beyond what a log of")
    for name, (bad, expect) in cases.items():
        p = tmp_path / f"{name}.mcap"
        p.write_bytes(bytes(bad))
        with pytest.raises(DamagedLog, match=expect):
            read_log(p)


def test_a_run_info_with_absurd_sizes_is_one_line(tmp_path):
    from ftstab_mj.logs.mcap_file import McapFile

    for r, expect in ((10 ** 9, "loops.r: expected an integer from 1 to 64"), ("2", "loops.r")):
        path = tmp_path / "r.mcap"
        with open(path, "wb") as f:
            w = McapFile(f)
            w.start()
            sid = w.register_schema("ftstab.Object", "jsonschema", b'{"type":"object"}')
            ch = w.register_channel("/run_info", "json", sid)
            w.add_message(ch, 0, json.dumps({"loops": [{"name": "cart", "r": r}], "period": 1e-3,
                                             "physics_step": 1e-3}).encode())
            w.finish()
        with pytest.raises(LogError, match=expect):
            read_log(path)


@pytest.mark.parametrize("model", ["cart", "cart_integrating", "arm"])
def test_the_models_our_runs_log_pass_the_untrusted_model_check(model):
    # The check must refuse what names files, not what our own plants write (e.g. <light dir=...>).
    from ftstab_mj.plants.callback import control_callback
    from ftstab_mj.logs.scene import check_untrusted_model, model_shapes
    from ftstab_mj.plants import make_plant

    plant = make_plant(model)
    with control_callback(None):
        _, _, xml = plant.compile(1e-3, "euler", nuserdata=4)
    check_untrusted_model(xml, model)  # raises LogError if refused
    assert model_shapes(xml, plant.body_names)

"""What a long run holds does not grow with its length: the MCAP writer's chunk index goes to a
temporary file, a Rerun recording of many chunks is written without Rerun's footer (whose index Rerun
keeps in memory until the file closes), and the final window stops growing at final_window_max (issue
16; RSS figures: benchmarks/memory_flat.py)."""

import io
import os
import tracemalloc
import warnings

import numpy as np
import pytest
from mcap.reader import make_reader

from ftstab_mj.logs.mcap_file import McapFile
from ftstab_mj.metrics.run_metrics import MetricsStream
from ftstab_mj.simulation.records import MetricSettings
from ftstab_mj.logs import rerun_sink
from ftstab_mj.logs.rerun_sink import RerunSink
from ftstab_mj.scenario import find_scenario, load_scenario
from ftstab_mj.scenario.run import run_scenario


def _chunks(w: McapFile, channel: int, start: int, n: int) -> None:
    """n chunks of one message each, at times start.. ns."""
    for k in range(start, start + n):
        w.add_messages(channel, [k], [b"x" * 8])
        w.flush()


def test_mcap_writer_holds_no_index_per_chunk():
    # Each chunk's ChunkIndex (times, offsets, a dict of message-index offsets) cost ~500 B of Python
    # objects, held until the summary: 5 MB over 10^4 chunks (a 10^7-sample run). Serialized into the
    # temporary file instead, 4000 more chunks leave < 8 kB (2 B a chunk) of traced memory; the old
    # index added 2.0 MB.
    f = io.BytesIO()
    w = McapFile(f, compression="")
    w.start()
    channel = w.register_channel("/x", "raw", w.register_schema("x", "", b""))
    _chunks(w, channel, 0, 1000)  # first allocations (the file, the builder) outside the count
    f.seek(0), f.truncate(0)  # the log's own bytes (an in-memory file here) are not what is measured
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        for k in range(4):
            _chunks(w, channel, 1000 + 1000 * k, 1000)
            f.seek(0), f.truncate(0)
        grown = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert grown < 8000, f"{grown} B held after 4000 chunks"


def test_mcap_chunk_index_from_its_file_is_the_plain_readers(tmp_path):
    # the summary copied from the temporary file: every chunk indexed, the indexed reader finds every
    # message, and a rollback forgets the index entry of the chunk it cuts
    path = tmp_path / "x.mcap"
    with open(path, "w+b") as raw:
        f = _FailingFlush(raw)
        w = McapFile(f, compression="lz4")
        w.start()
        channel = w.register_channel("/x", "raw", w.register_schema("x", "", b""))
        _chunks(w, channel, 0, 3000)
        w.add_messages(channel, [3000], [b"cut"])
        f.fail = True
        with pytest.raises(OSError):
            w.flush()  # the chunk and its index entry were written, the file's flush failed
        f.fail = False
        w.rollback()  # as after a write error: that chunk goes, with its index entry
        w.finish()
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert len(summary.chunk_indexes) == 3000 == summary.statistics.chunk_count
        assert [c.message_start_time for c in summary.chunk_indexes] == list(range(3000))
        times = [m.log_time for _, _, m in reader.iter_messages()]
    assert times == list(range(3000))


class _FailingFlush:
    """A file whose flush raises OSError while ``fail`` (a full disk)."""

    def __init__(self, f):
        self.f, self.fail = f, False

    def __getattr__(self, name):
        return getattr(self.f, name)

    def flush(self):
        if self.fail:
            raise OSError(28, "No space left on device")
        self.f.flush()


def _recording(tmp_path, name: str, samples: int, batch_size: int):
    sc = load_scenario(find_scenario("cart_r2_nominal"), [f"sim.duration={samples * 0.001!r}"])
    sink = RerunSink(tmp_path / f"{name}.rrd")
    run_scenario(sc, [sink], batch_size=batch_size)
    return sink


def _chunks_read(path):
    """(has a footer, the batches' chunks: temporal ones of the entities every batch writes) of an .rrd."""
    from rerun.chunk import RrdReader

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        chunks = list(RrdReader(str(path)).stream())
    once = ("/loop/cart/V1/settle_level", "/loop/cart/V1/envelope", "/loop/cart/V1/T_z0")  # logged at the start
    footer = not any("no footer" in str(w.message) for w in caught)
    return footer, [c for c in chunks if not c.is_static and c.entity_path not in once]


def test_rerun_recording_of_many_chunks_has_no_footer(tmp_path, capfd, monkeypatch):
    # the bound lowered from 12,000 chunks to 60 (cost): cart_r2_nominal makes 6 chunks a batch (5 plotted
    # entities and its body), so 10 batches of 100 samples are at the bound, 11 above it
    monkeypatch.setattr(rerun_sink, "FOOTER_MAX_CHUNKS", 60)
    at, above = _recording(tmp_path, "at", 1000, 100), _recording(tmp_path, "above", 1001, 100)
    footer, chunks = _chunks_read(tmp_path / "at.rrd")
    assert at.footer and footer and at.expected_chunks == len(chunks) == 60  # the estimate is the count
    footer, chunks = _chunks_read(tmp_path / "above.rrd")
    assert above.footer is False and not footer and above.expected_chunks == len(chunks) == 66
    os.write(2, b"stderr is back\n")  # the descriptor quieted while the sink was attached is put back
    err = capfd.readouterr().err
    assert "write_footer" not in err and "stderr is back" in err  # Rerun's warning (naming the sink's pipe) not shown
    # the file holds every sample all the same (read by Rerun's decoder, the viewer's)
    entity = "/loop/cart/V1/log10_V1"
    assert sum(c.num_rows for c in chunks if c.entity_path == entity) == 1001



def _stream_peak(samples: int, settings) -> tuple[int, dict]:
    """(traced peak in B, metrics) of MetricsStream fed a chattering run of ``samples`` at 1 ms in
    batches of 1000, made as they are fed (each batch freed before the next)."""
    import dataclasses

    from synthetic_runs import synthetic_run

    info = dataclasses.replace(synthetic_run("nominal", duration=0.01)[0], metric_settings=settings)
    stream = MetricsStream(info)
    tracemalloc.start()
    try:
        for k0 in range(0, samples, 1000):
            t = np.arange(k0, k0 + 1000) * 1e-3
            z = np.column_stack([1e-3 * np.sin(t), 1e-3 * np.cos(t)])
            u = np.where(np.arange(k0, k0 + 1000) % 3 == 0, 2.0, -1.0)  # chattering
            stream.update({"cart": {"t": t, "z": z, "u": u, "V1": z[:, 0] ** 2 + z[:, 1] ** 2, "phi_hat": u}})
        metrics = stream.result("completed")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    return peak, metrics


def test_memory_of_the_final_window_stops_growing_at_final_window_max():
    # A final window of 0.2 n samples costs, at the end, its u (8 B a sample) and one array of its size
    # (np.diff, the FFT's half spectrum) as NumPy allocates them (pocketfft's own buffers are not traced):
    # without final_window_max the peak at 10^6 samples is 3.0 MB above the one at 10^5 (16.5 B a window
    # sample). Cut to its last 10 s (10^4 samples) for any run longer than 50 s, it costs the same for
    # 10^5 samples as for 10^6: measured 1.1 kB more (the block sums' carries, 8 B every 32768 samples).
    settings = MetricSettings(final_window_max=10.0)
    small, m_small = _stream_peak(100_000, settings)
    large, m_large = _stream_peak(1_000_000, settings)
    assert m_small["loops"]["cart"]["final_window_start"] == 90.0 and m_large["loops"]["cart"]["final_window_start"] == 990.0
    assert large - small < 64_000, f"peak {small / 1e6:.2f} MB at 10^5 samples, {large / 1e6:.2f} MB at 10^6"


def test_a_short_write_of_the_chunk_index_file_falls_back_to_memory_with_every_byte(monkeypatch):
    """os.pwrite may write fewer bytes than asked (a disk that fills): the spilled chunk index then
    continues in memory from the last complete record, so the summary never holds a cut record."""
    from ftstab_mj.logs import mcap_file

    spill = mcap_file._Spill()
    records = [bytes([i]) * (100 + i) for i in range(6)]
    for rec in records[:3]:
        spill.append(rec)
    real = os.pwrite

    def short(fd, data, offset):  # the disk takes half of the record
        return real(fd, data[: len(data) // 2], offset)

    monkeypatch.setattr(mcap_file.os, "pwrite", short)
    for rec in records[3:]:
        spill.append(rec)
    assert spill._file is None  # now in memory
    assert b"".join(spill.blocks()) == b"".join(records)

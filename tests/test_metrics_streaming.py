"""Metrics streamed as the batches come (ftstab_mj.metrics.run_metrics.MetricsStream) are the metrics of the whole
arrays, and a run holds no sample unless asked (flat memory)."""

import tracemalloc

import numpy as np
import pytest

from ftstab_mj.logs import McapSink
from ftstab_mj.logs.reader import read_log, stream_metrics
from ftstab_mj.metrics.run_metrics import (MetricsStream, _BlockSum, _finite_or_nan, _num, _Ring, band_rms, chattering, compute_metrics, du_dt_variance, saturated_time, theorem3_check, workspace_left, zero_crossing_rate)
from metrics_reference import effort, eps_ball, estimation_error, final_abs_max, settle_time
from ftstab_mj.simulation.records import LOOP_FIELDS
from ftstab_mj.scenario import load_scenario, shipped_scenarios
from ftstab_mj.scenario.run import run_scenario

SHIPPED = [(name, path) for name, path, _ in shipped_scenarios()]
CART = dict(SHIPPED)["cart_r2_nominal"]


def _short(path, samples=2100):
    """The scenario run for `samples` control periods (more than two batches: the window's ring drops)."""
    sc = load_scenario(path)
    return load_scenario(path, [f"sim.duration={min(sc.sim.duration, samples * sc.sim.period)!r}"])


def _whole_array_checks(info, lp, arrays, m):
    """Each streamed metric against its definition on the whole arrays (exact; effort to 1e-12 relative)."""
    a = {k: _finite_or_nan(v) for k, v in arrays.items()}
    t, V1, u, z, h, ms = a["t"], a["V1"], a["u"], a["z"], info.period, info.metric_settings
    assert m["n_samples"] == len(t)
    assert m["settle_time"] == settle_time(t, V1, ms.settle_level)
    assert m["settle_time_z1"] == settle_time(t, np.abs(z[:, 0]), ms.settle_z1)
    entry, v_min, v_max = eps_ball(t, V1, m["eps"])
    assert (m["eps_entry_time"], m["V1_min_after_entry"], m["V1_max_after_entry"]) == (entry, v_min, v_max)
    e_abs, e_sq, u_max = effort(u, h)
    assert m["u_max_abs"] == u_max
    # block sums (_BlockSum): np.sum's bits up to 32768 samples, rounding beyond (1e-12 relative)
    assert m["effort_abs"] == pytest.approx(e_abs, rel=1e-12, abs=0.0)
    assert m["effort_sq"] == pytest.approx(e_sq, rel=1e-12, abs=0.0)
    if len(t) <= 32768:
        assert (m["effort_abs"], m["effort_sq"]) == (e_abs, e_sq)
    assert m["workspace_left"] == workspace_left(lp, z, u)
    assert m["phi_hat_max"] == float(np.max(a["phi_hat"])) and m["V1_final"] == float(V1[-1])
    # the final window: the last final_fraction of the run, and no more than its last final_window_max s
    win = t >= t[0] + (1.0 - ms.final_fraction) * len(t) * h
    if ms.final_window_max is not None:
        win &= t >= t[0] + (len(t) * h - ms.final_window_max)
    assert m["final_window_start"] == float(t[win][0])
    assert m["final_abs_z_max"] == final_abs_max(z[win])
    assert m["chattering"] == chattering(u[win], h)
    assert m["chattering_band_rms"] == band_rms(u[win], h, ms.chatter_band)
    assert m["chattering_du_dt_var"] == du_dt_variance(u[win], h)
    assert m["chattering_zero_crossings"] == zero_crossing_rate(u[win], h)
    if not m["workspace_left"]:
        V1w, phw = V1[win], a["phi_hat"][win]
        assert m["theorem3"] == theorem3_check(lp, np.max(V1w), np.max(phw), np.min(V1w))
    if lp.stages is not None:
        assert m["time_saturated"] == saturated_time(u, lp.stages, h)
        e_max, e_rms = estimation_error(a["z_hat"][win], z[win])  # exact: r >= 2 (or a window of <= 32768)
        assert (m["estimation_error_max"], m["estimation_error_rms"]) == (e_max, e_rms)
        assert m["chattering_applied"] == chattering(a["u_applied"][win], h)


@pytest.mark.parametrize("name,path", SHIPPED, ids=[n for n, _ in SHIPPED])
def test_streamed_metrics_are_the_whole_arrays_metrics_and_replays(name, path, tmp_path):
    _check_streamed_metrics(_short(path), tmp_path)


@pytest.mark.parametrize("name", ["cart_r2_nominal", "cart_r2_output_feedback"])
def test_a_window_cut_to_final_window_max_is_the_definition_and_replays(name, tmp_path):
    # 2100 samples at 1 ms: the final fifth is 0.42 s, cut to its last 0.3 s (301 samples); a loop with
    # stages too (its estimation error and u_applied over the same window)
    sc = load_scenario(dict(SHIPPED)[name], ["sim.duration=2.1", "sim.period=0.001", "sim.physics_step=0.001",
                                             "metrics.final_window_max=0.3"])
    metrics = _check_streamed_metrics(sc, tmp_path)
    for m in metrics["loops"].values():
        assert m["final_window_start"] == pytest.approx(1.8, abs=1e-12)


def test_an_infinite_final_window_max_is_refused_in_one_line_that_says_what_to_write():
    """inf has no JSON form (a log records the settings), so it is refused, and the line names the
    key and the finite value that lifts the cap; that value is no cap: the window starts where the
    uncapped one (None, as logs before the key replay) does, up to 1e7 samples of up to 100 s."""
    from ftstab_mj.config.errors import ScenarioError
    from ftstab_mj.metrics.run_metrics import final_window_start
    from ftstab_mj.simulation.records import MetricSettings

    with pytest.raises(ScenarioError) as exc:
        load_scenario(dict(SHIPPED)["cart_r2_nominal"], ["metrics.final_window_max=inf"])
    line = str(exc.value)
    assert "\n" not in line and "metrics.final_window_max" in line and "found inf" in line
    assert "write a value >= final_fraction x sim.duration, e.g. 1e9" in line
    for n, h in ((2100, 1e-3), (10 ** 7, 1e-3), (10 ** 7, 100.0)):
        for frac in (0.2, 1.0):
            lifted, none = (MetricSettings(final_fraction=frac, final_window_max=cap) for cap in (1e9, None))
            assert final_window_start(0.0, n, h, lifted) == final_window_start(0.0, n, h, none), (n, h, frac)


def _check_streamed_metrics(sc, tmp_path) -> dict:
    """Run sc: its streamed metrics against the definitions on the whole arrays, against replay, and
    in batches of 7 with the ring in memory and in its file; returns them."""
    log = tmp_path / "run.mcap"
    run = run_scenario(sc, [McapSink(log)], keep_samples=True)
    res = run.result
    assert run.metrics["n_samples"] == res.n_samples > 2000
    for lp in res.info.loops:
        _whole_array_checks(res.info, lp, res.loops[lp.name], run.metrics["loops"][lp.name])
    # the same bits from the whole arrays in one piece (what replay does), from the log, and in batches of 7
    assert compute_metrics(res.info, res.loops, res.status) == run.metrics
    data = read_log(log)
    assert compute_metrics(data.info, data.loops, data.recorded["status"]) == run.metrics == data.recorded["metrics"]
    streamed, metrics = stream_metrics(log)  # replay: the log's chunks fed to MetricsStream
    assert metrics == run.metrics and streamed.n_samples == res.n_samples and streamed.complete
    stream = MetricsStream(res.info, res.n_samples)  # batches of 7 samples: boundaries everywhere
    for k in range(0, res.n_samples, 7):
        stream.update({name: {f: x[k:k + 7] for f, x in arrays.items()} for name, arrays in res.loops.items()})
    assert stream.result(res.status) == run.metrics
    # the final window's ring in its temporary file (as a long run's is), wrapping round many times
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(_Ring, "RING_IN_MEMORY", 0)
        mp.setattr(_Ring, "READ_ROWS", 100)
        stream = MetricsStream(res.info, res.n_samples)
        assert all(s.ring.file is not None for s in stream.loops.values())
        for k in range(0, res.n_samples, 7):
            stream.update({name: {f: x[k:k + 7] for f, x in arrays.items()} for name, arrays in res.loops.items()})
        assert stream.result(res.status) == run.metrics
    return run.metrics


@pytest.mark.parametrize("limit", [1 << 30, 0, 4000], ids=["memory", "file", "memory-then-file"])
def test_the_ring_holds_the_last_rows_as_it_grows(limit, monkeypatch):
    # the ring grows as a run's final window does (a fifth of the rows so far): in memory, in its file
    # (rewritten larger), or first in memory then in the file once past the limit (4000 B: 166 rows of 3)
    rows = np.random.default_rng(4).normal(size=(5000, 3))
    monkeypatch.setattr(_Ring, "RING_IN_MEMORY", limit)
    monkeypatch.setattr(_Ring, "READ_ROWS", 64)
    for start in (1, 37, 1000, 6000):
        ring, k = _Ring(3, start), 0
        for size in np.random.default_rng(start).integers(1, 300, size=10_000):
            part = rows[k:k + size]
            ring.grow(max(start, (k + len(part)) // 5))
            ring.append(part)
            k += len(part)
            held = np.concatenate(list(ring.chunks()))
            assert len(held) == ring.held >= min(k, max(start, k // 5))  # never fewer than asked for
            assert np.array_equal(held, rows[k - len(held):k])  # the last rows, in order, bit for bit
            if k >= len(rows):
                break
        assert (ring.file is None) == (limit == 1 << 30)  # 1000 rows and more pass 4000 B
        if ring.file is not None:
            assert ring.held <= ring.capacity  # the file holds no more than its capacity
        ring.close()


def test_a_ring_whose_file_cannot_grow_goes_back_to_memory(monkeypatch):
    import os

    rows = np.arange(3000.0).reshape(1000, 3)
    monkeypatch.setattr(_Ring, "RING_IN_MEMORY", 0)
    ring = _Ring(3, 500)
    ring.append(rows[:600])
    real = os.pwrite

    def full(fd, data, offset):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "pwrite", full)
    ring.append(rows[600:700])
    monkeypatch.setattr(os, "pwrite", real)
    ring.append(rows[700:])
    assert ring.file is None
    held = np.concatenate(list(ring.chunks()))
    assert len(held) >= 500 and np.array_equal(held, rows[len(rows) - len(held):])


def test_the_chattering_indices_keep_the_bits_of_their_numpy_definitions():
    # computed in place or in blocks of 65536 (a long window costs about one extra array): the bits
    # of the one-line NumPy definitions, on windows longer than the blocks, with zeros and NaN
    rng = np.random.default_rng(5)
    for m in (2, 3, 65535, 65537, 200_001):
        for kind in ("plain", "offset", "zeros", "nan"):
            u = rng.normal(size=m) + (5.0 if kind == "offset" else 0.0)
            if kind in ("zeros", "nan"):
                u[rng.random(m) < 0.3] = 0.0
            if kind == "nan":
                u[rng.random(m) < 0.05] = np.nan
            h = 1e-3
            assert chattering(u, h) == _num(np.sum(np.abs(np.diff(u))) / (m * h))
            assert du_dt_variance(u, h) == _num(np.var(np.diff(u) / h))
            s = np.sign(u[np.isfinite(u)])
            s = s[s != 0]
            assert zero_crossing_rate(u, h) == _num(np.count_nonzero(s[1:] != s[:-1]) / (m * h))
            U, f = np.fft.rfft(u), np.fft.rfftfreq(m, h)
            amp2 = (2.0 * np.abs(U) / m) ** 2 / 2.0
            if m % 2 == 0:
                amp2[-1] = (np.abs(U[-1]) / m) ** 2
            for band in ((10.0, 1000.0), (0.0, 10.0), (1 / (m * h), 3 / (m * h)), (500.0, 500.0), (600.0, 700.0)):
                sel = (f > 0.0) & (f >= band[0]) & (f <= band[1])
                assert band_rms(u, h, band) == _num(np.sqrt(np.sum(amp2[sel]))), (m, kind, band)


def test_block_sums_do_not_depend_on_the_batching():
    x = np.random.default_rng(1).lognormal(size=100_000)
    whole, cut = _BlockSum(), _BlockSum()
    whole.update(x)
    edges = np.cumsum(np.random.default_rng(2).integers(1, 5000, size=100))
    for part in np.split(x, edges[edges < len(x)]):
        cut.update(part)
    assert cut.result() == whole.result()
    # against np.sum of the whole array: one rounding per block (4 blocks) on top of np.sum's own
    assert whole.result() == pytest.approx(np.sum(x), rel=1e-14, abs=0.0)
    assert _BlockSum.BLOCK >= 1000 and whole.result() != 0.0
    short = _BlockSum()
    short.update(x[:_BlockSum.BLOCK])
    assert short.result() == np.sum(x[:_BlockSum.BLOCK])  # one block: np.sum's bits, as logs before streaming


def test_a_run_keeps_no_sample_unless_asked():
    sc = _short(CART, samples=10)
    assert run_scenario(sc).result.loops is None
    kept = run_scenario(sc, keep_samples=True).result
    assert kept.n_samples == 10 and set(LOOP_FIELDS) <= set(kept.loops["cart"])


def test_memory_of_a_run_does_not_grow_with_its_samples():
    # 4 x 10^5 samples (400 s at 1 ms) of the cart without keep_samples. One sample as the run used to
    # keep it is >= 12 float64 per loop field row (t, z (2), u, V1, phi, gamma, phi_hat, gamma_hat ...)
    # plus the body poses (7 per body): >= 150 bytes (the issue measured 378 B of RSS per sample): 60 MB
    # kept. The final window's samples in memory (final_fraction 0.2: 80,002 rows of t, z, u, V1, phi_hat,
    # 48 B each) would be 3.8 MB, twice that when joined at the end. Streaming holds: one batch (1000
    # samples, ~0.4 MB with its copies), the ring's rows in its temporary file (not memory) read back
    # 8192 at a time (0.4 MB, twice when masked), the window's u (80,002 x 8 B = 0.64 MB) and one array
    # of its size for the chattering indices (np.diff, the FFT's half spectrum), the effort block sums'
    # carries (< 2 x 32768 x 8 B = 0.5 MB): < 3 MB in all; the threshold 4 MB (what 10^5 samples were
    # allowed before) is exceeded if the window is held in memory again.
    sc = load_scenario(CART, ["sim.duration=400", "sim.period=0.001", "sim.physics_step=0.001"])
    assert sc.metrics.final_fraction == 0.2
    run_scenario(load_scenario(CART, ["sim.duration=0.01"]))  # imports and caches outside the count
    tracemalloc.start()
    try:
        run = run_scenario(sc)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert run.metrics["n_samples"] == 400_000
    assert peak < 4e6, f"peak {peak / 1e6:.1f} MB for 4 x 10^5 samples"


def test_replay_of_a_log_does_not_hold_its_samples(tmp_path):
    # a log of 10^5 samples (100 s of the cart at 1 ms, 4.3 MB) read as it streams (replay, check). Read
    # whole, its bytes alone would be 4.3 MB and its decoded loop fields (11 float64 a sample) 8.8 MB.
    # Streaming holds: one chunk's messages and their decoded batch (1000 samples, < 0.3 MB), the final
    # window's ring (20,002 rows of 48 B: 0.96 MB, in memory below 1 MiB), the window's u and one array of
    # its size at the end (0.32 MB), the effort block sums' carries (< 0.5 MB): < 2.5 MB; the threshold
    # 4 MB is under the file's size. The file itself is mapped, not read into Python objects, and its
    # pages given back after each chunk (RSS: benchmarks/memory_flat.py).
    sc = load_scenario(CART, ["sim.duration=100", "sim.period=0.001", "sim.physics_step=0.001"])
    path = tmp_path / "long.mcap"
    run = run_scenario(sc, [McapSink(path)])
    assert path.stat().st_size > 4e6
    stream_metrics(_short_log(tmp_path))  # imports and caches outside the count
    tracemalloc.start()
    try:
        log, metrics = stream_metrics(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert metrics == run.metrics and log.n_samples == 100_000
    assert peak < 4e6, f"peak {peak / 1e6:.1f} MB to replay 10^5 samples"


def _short_log(tmp_path):
    path = tmp_path / "short.mcap"
    run_scenario(load_scenario(CART, ["sim.duration=0.01"]), [McapSink(path)])
    return path

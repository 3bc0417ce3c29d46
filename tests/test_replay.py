"""Reader, ``ftstab replay`` and ``ftstab check``: round trip, truncation, SIGKILL, expectations."""

import json
import os
import signal
import subprocess
import sys

import numpy as np
import pytest

from conftest import ROOT, rrd_rows, run_cli
from ftstab_mj.config.errors import LogError
from ftstab_mj.logs import McapSink
from ftstab_mj.logs.reader import read_log
from ftstab_mj.metrics.run_metrics import compute_metrics
from ftstab_mj.simulation.records import COMPLETED, INTERRUPTED, LOOP_FIELDS
from synthetic_runs import batches, synthetic_run, write_run

BATCH = 250


@pytest.fixture(scope="module")
def run():
    info, loops, pos, quat = synthetic_run("adaptive", duration=2.0, period=1e-3)
    return info, loops, pos, quat, compute_metrics(info, loops, COMPLETED)


@pytest.fixture(scope="module")
def log_with_flush_sizes(run, tmp_path_factory):
    """A complete log and the file size after every flushed batch."""
    info, loops, pos, quat, metrics = run
    path = tmp_path_factory.mktemp("log") / "run.mcap"
    sink = McapSink(path)
    sink.open(info)
    sizes = [os.path.getsize(path)]
    for b in batches(loops, pos, quat, BATCH):
        sink.write(b)
        sizes.append(os.path.getsize(path))
    sink.close(COMPLETED, metrics)
    return path, sizes


def test_round_trip_replay_metrics_equal_the_recorded_ones(run, log_with_flush_sizes):
    info, loops, _, _, metrics = run
    path, _ = log_with_flush_sizes
    log = read_log(path)
    assert log.complete and log.warning is None
    for f in LOOP_FIELDS:
        assert np.array_equal(log.loops["cart"][f], loops["cart"][f]), f
    assert log.recorded["metrics"] == metrics
    res = run_cli("replay", path, "--json")
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout) == metrics == log.recorded["metrics"]


def test_replay_reports_recorded_metrics_that_do_not_match_the_samples(run, tmp_path):
    info, loops, pos, quat, metrics = run
    wrong = json.loads(json.dumps(metrics))
    wrong["loops"]["cart"]["chattering"] *= 1.5
    path = tmp_path / "tampered.mcap"
    write_run(McapSink(path), info, loops, pos, quat, COMPLETED, wrong)
    res = run_cli("replay", path)
    assert res.returncode == 1
    assert "loops.cart.chattering: recorded" in res.stderr


def test_replay_accepts_a_certificate_another_branch_and_bound_computed_when_the_brackets_overlap(run, tmp_path):
    """A log whose certificate an older version computed (stopped elsewhere inside its gap) replays as
    consistent: the certificate depends on the controller and the B&B's code, not on the samples. Its
    bracket must still hold c: one that does not overlap the recomputed bracket is a difference."""
    info, loops, pos, quat, metrics = run
    cert = metrics["loops"]["cart"]["certificate"]
    assert cert["status"] == "certified"
    older = json.loads(json.dumps(metrics))
    oc = older["loops"]["cart"]["certificate"]
    oc["c_lower"] *= 1 - 1e-3  # another stop inside the 2e-3 gap: still below c
    oc["c_prime_upper"] *= 1 + 1e-3
    older["loops"]["cart"]["time_bound"] *= 1 + 1e-3  # T(z0) ~ 1 / c_lower
    path = tmp_path / "older.mcap"
    write_run(McapSink(path), info, loops, pos, quat, COMPLETED, older)
    res = run_cli("replay", path)
    assert res.returncode == 0, res.stderr
    assert "another version of the branch and bound" in res.stdout
    assert "loops.cart.certificate.c_lower" in res.stdout and "loops.cart.time_bound" in res.stdout

    wrong = json.loads(json.dumps(metrics))
    wc = wrong["loops"]["cart"]["certificate"]
    wc["c_lower"], wc["c_upper"] = 1.01 * cert["c_upper"], 1.02 * cert["c_upper"]  # a bracket without c
    path = tmp_path / "wrong.mcap"
    write_run(McapSink(path), info, loops, pos, quat, COMPLETED, wrong)
    res = run_cli("replay", path)
    assert res.returncode == 1
    assert "loops.cart.certificate.c_lower: recorded" in res.stderr


def test_truncated_anywhere_recovers_every_flushed_batch(run, log_with_flush_sizes, tmp_path):
    info, loops, _, _, _ = run
    path, sizes = log_with_flush_sizes
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    n_total = len(loops["cart"]["t"])
    # Cut exactly at each flush, and at points between flushes (inside chunks and their indexes).
    rng = np.random.default_rng(1)
    points = sorted(set(sizes) | set(rng.integers(sizes[0], len(data), 40).tolist()))
    for at in points:
        cut.write_bytes(data[:at])
        log = read_log(cut)
        flushed = sum(1 for s in sizes[1:] if s <= at) * BATCH  # samples fully written before the cut
        n = log.n_samples
        assert n >= min(flushed, n_total), at
        assert n % BATCH == 0 or n == n_total
        for f in LOOP_FIELDS:  # what is recovered is exactly the run's beginning
            assert np.array_equal(log.loops["cart"][f], loops["cart"][f][:n]), (at, f)
        if at < len(data):
            assert not log.complete and f"recovered {n} samples per loop" in log.warning
            assert f"of {at} bytes" in log.warning


def test_truncated_log_replays_with_a_warning_and_interrupted_status(log_with_flush_sizes, tmp_path):
    path, sizes = log_with_flush_sizes
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[: sizes[3] + 100])
    res = run_cli("replay", cut, "--json")
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["status"] == INTERRUPTED and json.loads(res.stdout)["n_samples"] == 3 * BATCH
    assert res.stderr.startswith("warning: ") and "recovered 750 samples per loop" in res.stderr


def test_a_file_that_is_not_a_log_gives_exit_2_and_one_line(tmp_path, log_with_flush_sizes):
    path, sizes = log_with_flush_sizes
    bad = tmp_path / "notes.mcap"
    bad.write_text("just text\n")
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    header_only = tmp_path / "header.mcap"
    header_only.write_bytes(path.read_bytes()[:40])  # MCAP magic, but no run description
    for p in (bad, empty, header_only, tmp_path / "missing.mcap"):
        res = run_cli("replay", p)
        assert res.returncode == 2, p
        assert res.stdout == "" and len(res.stderr.strip().splitlines()) == 1 and str(p) in res.stderr
        assert "Traceback" not in res.stderr
    with pytest.raises(LogError, match="not an ftstab run log"):
        read_log(header_only)


def test_replay_writes_a_rerun_recording_from_the_log(log_with_flush_sizes, tmp_path, run):
    from rerun.chunk import RrdReader

    path, _ = log_with_flush_sizes
    out = tmp_path / "replay.rrd"
    res = run_cli("replay", path, "--rrd", out)
    assert res.returncode == 0, res.stderr
    rows = {}
    for chunk in RrdReader(str(out)).stream():
        rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
    n = len(run[1]["cart"]["t"])
    assert rows["/loop/cart/V1/log10_V1"] == n + 1 and rows["/loop/cart/z"] == n + 1  # + the series style
    assert rows["/world/cart"] == len(read_log(path).pose_t) > 0


# A child process that writes a run in batches through both sinks and reports each flush.
_CHILD = r"""
import sys
sys.path[:0] = [{root!r}, {tests!r}]
from ftstab_mj.logs import McapSink, RerunSink
from synthetic_runs import batches, synthetic_run
info, loops, pos, quat = synthetic_run("adaptive", duration=12.0, period=1e-3)
sinks = [McapSink({mcap!r}), RerunSink({rrd!r})]
for s in sinks:
    s.open(info)
done = 0
for b in batches(loops, pos, quat, {batch}):
    for s in sinks:
        s.write(b)
    done += len(b)
    print(done, flush=True)
"""


def test_sigkill_mid_run_leaves_logs_readable_up_to_the_last_flush(tmp_path, run):
    mcap, rrd = tmp_path / "killed.mcap", tmp_path / "killed.rrd"
    code = _CHILD.format(root=str(ROOT), tests=str(ROOT / "tests"), mcap=str(mcap), rrd=str(rrd), batch=BATCH)
    child = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        reported = 0
        while reported < 6 * BATCH:  # let a few batches through, then kill while it keeps writing
            line = child.stdout.readline()
            assert line, "child ended before being killed"
            reported = int(line)
        os.kill(child.pid, signal.SIGKILL)
    finally:
        child.kill()
        child.wait()
    assert child.returncode == -signal.SIGKILL
    log = read_log(mcap)
    assert not log.complete and log.recorded is None
    assert log.n_samples >= reported  # at least every sample up to the last reported flush
    info, loops = synthetic_run("adaptive", duration=log.n_samples * 1e-3, period=1e-3)[:2]
    for f in LOOP_FIELDS:
        assert np.array_equal(log.loops["cart"][f], loops["cart"][f][: log.n_samples]), f
    assert rrd_rows(rrd, "/loop/cart/control") >= reported  # readable as far as it goes (see rrd_rows)
    res = run_cli("replay", mcap, "--json")
    assert res.returncode == 0 and json.loads(res.stdout)["status"] == INTERRUPTED


@pytest.mark.filterwarnings("ignore:RRD file has no footer")
def test_sigkilled_ftstab_run_replays_and_verifies_up_to_where_it_got(tmp_path):
    # The real command: kill `ftstab run` once its MCAP log holds a few flushed batches; what the
    # log holds must be the exact beginning of the run (--verify re-runs the recorded scenario).
    import time

    env = dict(os.environ, PYTHONPATH=str(ROOT))
    child = subprocess.Popen([sys.executable, "-m", "ftstab_mj", "run", "cart_r2_robust", "--set",
                              "sim.duration=60", "--out", str(tmp_path), "--rrd"], stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL, env=env, cwd=ROOT)
    mcap, rrd = tmp_path / "cart_r2_robust.mcap", tmp_path / "cart_r2_robust.rrd"
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:  # a few 1000-sample chunks (~100 kB each) are on disk
            if mcap.exists() and mcap.stat().st_size > 300_000:
                break
            assert child.poll() is None, "ftstab run ended before being killed"
            time.sleep(0.02)
        os.kill(child.pid, signal.SIGKILL)
    finally:
        child.kill()
        child.wait()
    log = read_log(mcap)
    assert not log.complete and log.n_samples >= 2000 and log.n_samples % 1000 == 0
    assert log.info.model_xml is not None and not log.notes  # a real run's model passes the untrusted-model check
    res = run_cli("replay", mcap, "--verify")
    assert res.returncode == 0, res.stderr
    assert "truncated log" in res.stderr and "bit-identical" in res.stdout
    # The .rrd is flushed batch by batch too; SIGKILL may cut its last frame (see rrd_rows).
    assert rrd_rows(rrd, "/loop/cart/V1/log10_V1") >= log.n_samples - 1000

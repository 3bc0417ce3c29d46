"""``ftstab replay --verify`` streams: the log is read chunk by chunk and each batch of the re-run compared
as it comes (logs/verify.py StreamingComparison), whatever the log's chunks are against the re-run's batches."""

import numpy as np

from ftstab_mj.logs import McapSink
from ftstab_mj.logs.reader import LogStream, read_log, stream_metrics
from ftstab_mj.simulation.records import LOOP_FIELDS
from ftstab_mj.scenario import load_scenario, shipped_scenarios
from ftstab_mj.scenario.run import run_scenario, verify_log
from synthetic_runs import write_run

CART = dict((n, p) for n, p, _ in shipped_scenarios())["cart_r2_robust"]


def _log(tmp_path, name, res, loops, pos, batch=7):
    """The run's samples (maybe altered) written as a log of `batch`-sample chunks."""
    path = tmp_path / f"{name}.mcap"
    write_run(McapSink(path), res.info, loops, pos, res.body_quat, res.status, run_metrics(res, loops), batch=batch)
    return path


def run_metrics(res, loops):
    from ftstab_mj.metrics.run_metrics import compute_metrics

    return compute_metrics(res.info, loops, res.status)


def test_verify_compares_every_sample_and_pose_across_chunks_and_batches(tmp_path):
    sc = load_scenario(CART, ["sim.duration=2.5"])
    res = run_scenario(sc, keep_samples=True).result
    n = res.n_samples
    same = _log(tmp_path, "same", res, res.loops, res.body_pos)
    log = stream_metrics(same)[0]
    v = verify_log(log)
    whole = read_log(same)  # what is compared: every loop field of every sample, every /tf pose
    per_sample = sum(np.asarray(whole.loops["cart"][f]).size for f in whole.loops["cart"])
    assert set(LOOP_FIELDS) <= set(whole.loops["cart"]) and len(whole.pose_t) > 100
    assert v.ok and v.compared == per_sample + whole.pose_pos.size + whole.pose_quat.size, v.problems
    # one ulp in u at sample 1500 (inside a 7-sample chunk, in the re-run's second batch), z at 2001 and a
    # body position at a /tf sample (every 17th at 60 Hz and 1 ms): each reported at its first difference
    loops = {k: {f: a.copy() for f, a in v.items()} for k, v in res.loops.items()}
    pos = res.body_pos.copy()
    loops["cart"]["u"][1500] = np.nextafter(loops["cart"]["u"][1500], np.inf)
    loops["cart"]["z"][2001, 1] = np.nextafter(loops["cart"]["z"][2001, 1], -np.inf)
    pos[17 * 70, 0, 0] += 1e-9
    altered = _log(tmp_path, "altered", res, loops, pos)
    v = verify_log(stream_metrics(altered)[0])
    assert not v.ok and v.problems == (
        f"/loop/cart z differs first at sample 2001 (t = 2.001 s): logged {loops['cart']['z'][2001].tolist()!r}, "
        f"re-run {res.loops['cart']['z'][2001].tolist()!r}",
        f"/loop/cart u differs first at sample 1500 (t = 1.5 s): logged {float(loops['cart']['u'][1500])!r}, "
        f"re-run {float(res.loops['cart']['u'][1500])!r}",
        "/tf body position differs first at t = 1.19 s"), v.problems
    assert n == 2500


def test_verify_of_a_truncated_log_compares_the_prefix_it_holds(tmp_path):
    sc = load_scenario(CART, ["sim.duration=2.5"])
    res = run_scenario(sc, keep_samples=True).result
    path = _log(tmp_path, "cut", res, res.loops, res.body_pos, batch=1000)
    data = path.read_bytes()
    path.write_bytes(data[:len(data) * 2 // 3])  # cut inside a chunk: the complete chunks before it remain
    log = stream_metrics(path)[0]
    kept = read_log(path).n_samples
    assert not log.complete and log.n_samples == kept in (1000, 2000) and "truncated" in log.warning
    v = verify_log(log)
    assert v.ok and v.compared > kept * 10, v.problems
    reading = LogStream(path)
    assert sum(len(b["cart"]["t"]) for b in reading.batches()) == kept

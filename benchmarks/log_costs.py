"""Cost of the run logs (the figures of issue 5's closing note): write time and size per 10,000 samples.

    python -m benchmarks.log_costs [--repeat 5]

1. The sinks alone: the 10,000 samples of scenario cart_r2_robust (10 s at 1 ms, one loop, one
   body) written in batches of 1000 by McapSink and by RerunSink; best of --repeat; file sizes.
2. A whole run of that scenario (MuJoCo stepping, Python controller in the callback): without
   sinks, with the MCAP log, with both logs; best of --repeat, per sample.
3. Reading back: read_log of the MCAP file and the metrics recomputed from it.
"""

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from ftstab_mj.logs import McapSink, RerunSink
from ftstab_mj.logs.reader import read_log
from ftstab_mj.metrics.run_metrics import compute_metrics
from ftstab_mj.simulation.records import COMPLETED, SampleBatch
from ftstab_mj.scenario import find_scenario, load_scenario
from ftstab_mj.scenario.run import run_scenario

SCENARIO = "cart_r2_robust"
BATCH = 1000


def best(fn, repeat):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    sc = load_scenario(find_scenario(SCENARIO))
    run = run_scenario(sc)
    res = run.result
    n = res.n_samples
    per = 10_000 / n
    print(f"{SCENARIO}: {n} samples, period {sc.sim.period} s, physics step {sc.sim.physics_step} s")
    batches = [SampleBatch({k: {f: a[i:i + BATCH] for f, a in v.items()} for k, v in res.loops.items()},
                           res.body_pos[i:i + BATCH], res.body_quat[i:i + BATCH]) for i in range(0, n, BATCH)]
    with tempfile.TemporaryDirectory() as tmp:
        for name, make, ext in (("MCAP ", McapSink, "mcap"), ("Rerun", RerunSink, "rrd")):
            path = Path(tmp) / f"log.{ext}"

            def write():
                sink = make(path)
                sink.open(res.info)
                for b in batches:
                    sink.write(b)
                sink.close(COMPLETED, run.metrics)

            open_close = best(lambda: (lambda s: (s.open(res.info), s.close(COMPLETED, run.metrics)))(make(path)),
                              args.repeat)
            t = best(write, args.repeat)
            print(f"  {name} sink: {(t - open_close) * per * 1e3:7.1f} ms per 10,000 samples "
                  f"({(t - open_close) / n * 1e6:.2f} us a sample; open + close {open_close * 1e3:.0f} ms), "
                  f"file {path.stat().st_size * per / 1e6:.2f} MB per 10,000 samples")
        mcap = Path(tmp) / "log.mcap"
        t = best(lambda: compute_metrics(*(lambda lg: (lg.info, lg.loops, COMPLETED))(read_log(mcap))), args.repeat)
        print(f"  read_log + compute_metrics: {t * per * 1e3:.0f} ms per 10,000 samples")

        def full(sinks):
            return lambda: run_scenario(sc, [s(Path(tmp) / f"full.{e}") for s, e in sinks])

        bare = best(full([]), args.repeat)
        one = best(full([(McapSink, "mcap")]), args.repeat)
        both = best(full([(McapSink, "mcap"), (RerunSink, "rrd")]), args.repeat)
        print(f"  whole run, {n} samples: bare {bare / n * 1e6:.1f} us a sample; with MCAP {one / n * 1e6:.1f} "
              f"(x{one / bare:.2f}); with MCAP + Rerun {both / n * 1e6:.1f} (x{both / bare:.2f})")
    assert np.isfinite(bare)


if __name__ == "__main__":
    main()

"""Cost of the run logs: write time and size per 10,000 samples, and reading them back.

    python -m benchmarks log_costs [--repeat 5]

1. The sinks alone: the 10,000 samples of scenario cart_r2_robust (10 s at 1 ms, one loop, one
   body) written in batches of 1000 by McapSink and by RerunSink; best of --repeat; file sizes.
2. Reading back: read_log of the MCAP file and the metrics recomputed from it, and the .rrd that
   `ftstab view` makes from it (read_log + metrics + write_rrd).

A whole run with and without each log, in process and as a whole process: benchmarks/run_speed.py.
"""

import argparse
import tempfile
import time
from pathlib import Path

from ftstab_mj.logs import McapSink, RerunSink
from ftstab_mj.logs.reader import read_log
from ftstab_mj.logs.rerun_sink import write_rrd
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
    run = run_scenario(sc, keep_samples=True)
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

            write()  # untimed: the first one imports the writer's package
            open_close = best(lambda: (lambda s: (s.open(res.info), s.close(COMPLETED, run.metrics)))(make(path)),
                              args.repeat)
            t = best(write, args.repeat)
            print(f"  {name} sink: {(t - open_close) * per * 1e3:7.1f} ms per 10,000 samples "
                  f"({(t - open_close) / n * 1e6:.2f} us a sample; open + close {open_close * 1e3:.0f} ms), "
                  f"file {path.stat().st_size * per / 1e6:.2f} MB per 10,000 samples")
        mcap = Path(tmp) / "log.mcap"
        t = best(lambda: compute_metrics(*(lambda lg: (lg.info, lg.loops, COMPLETED))(read_log(mcap))), args.repeat)
        print(f"  read_log + compute_metrics: {t * per * 1e3:.0f} ms per 10,000 samples")

        def view():  # what `ftstab view` does once the log is read (cli/common.write_log_rrd)
            log = read_log(mcap)
            metrics = compute_metrics(log.info, log.loops, COMPLETED)
            write_rrd(Path(tmp) / "view.rrd", log.info, log.loops, (log.pose_t, log.pose_pos, log.pose_quat),
                      COMPLETED, metrics)

        t = best(view, args.repeat)
        print(f"  the .rrd from the MCAP log (ftstab view, without its viewer): {t * per * 1e3:.0f} ms per 10,000 "
              "samples")


if __name__ == "__main__":
    main()

"""Repeated interruption of real `ftstab run` processes: a signal (SIGINT, SIGTERM, SIGHUP in turn)
at seeded random moments over the whole command (interpreter start, imports, setup, every batch,
closing), and what the logs hold afterwards.

    python benchmarks/interruptions.py [--tries 60] [--seed 1] [--scenario cart_r2_robust]

Each try is classified: "no log" (stopped before the logs were opened: none written, exit
128 + signal), "interrupted" (two complete logs, the same samples in both, status interrupted,
recorded metrics equal to the replayed ones, exit 128 + signal), "completed" (the signal came
after the run), or a failure (anything else: printed, and the script exits 1).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def rrd_rows(path, entity):
    from rerun.chunk import RrdReader

    return sum(c.num_rows for c in RrdReader(str(path)).stream() if c.entity_path == entity)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tries", type=int, default=60)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--scenario", default="cart_r2_robust")
    ap.add_argument("--duration", type=float, default=3.0, help="sim.duration of each run (s)")
    args = ap.parse_args()
    import numpy as np

    from ftstab_mj.logs.reader import read_log
    from ftstab_mj.metrics import compute_metrics

    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    cmd = [sys.executable, "-m", "ftstab_mj", "run", args.scenario, "--set", f"sim.duration={args.duration}"]

    def start(out):
        return subprocess.Popen(cmd + ["--out", str(out)], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                text=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))

    with tempfile.TemporaryDirectory() as tmp:
        ref = Path(tmp) / "ref"
        t0 = time.monotonic()
        p = start(ref)
        p.communicate()
        whole = time.monotonic() - t0
        assert p.returncode == 0
        static = rrd_rows(ref / f"{args.scenario}.rrd", f"/loop/{next(iter(read_log(ref / f'{args.scenario}.mcap').loops))}/V1/log10_V1") \
            - read_log(ref / f"{args.scenario}.mcap").n_samples
        rng = np.random.default_rng(args.seed)
        sigs = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
        outcomes, failures = Counter(), []
        for k, delay in enumerate(rng.uniform(0.0, whole, args.tries)):
            sig = sigs[k % 3]
            out = Path(tmp) / f"t{k}"
            p = start(out)
            time.sleep(delay)
            p.send_signal(sig)
            _, err = p.communicate()
            mcap, rrd = out / f"{args.scenario}.mcap", out / f"{args.scenario}.rrd"
            why = ""
            if "Traceback" in err:
                why = "traceback"
            elif not mcap.exists() and not rrd.exists():
                kind = "no log" if p.returncode in (128 + sig, -sig) else "?"
                why = "" if kind == "no log" else f"no log but exit {p.returncode}"
            else:
                log = read_log(mcap)
                status = log.recorded["status"] if log.recorded else None
                kind = status or "?"
                if not log.complete or status is None:
                    why = "log without status"
                elif (status == "interrupted") != (p.returncode == 128 + sig) or (status == "completed") != (p.returncode == 0):
                    why = f"status {status} but exit {p.returncode}"
                elif json.loads(json.dumps(compute_metrics(log.info, log.loops, status))) != log.recorded["metrics"]:
                    why = "recorded metrics differ from the replayed ones"
                elif any(rrd_rows(rrd, f"/loop/{n}/V1/log10_V1") - static != log.n_samples for n in log.loops):
                    why = "the .rrd and the .mcap hold different samples"
            if why:
                failures.append(f"try {k}: {signal.Signals(sig).name} at {delay:.3f} s: {why}: {err.strip()[-300:]}")
                kind = "FAILED"
            outcomes[kind] += 1
    print(f"{args.tries} tries, {args.scenario}, sim.duration {args.duration} s, whole command {whole:.2f} s, "
          f"seed {args.seed}: " + ", ".join(f"{n} {k}" for k, n in sorted(outcomes.items())))
    for line in failures:
        print(line)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())

"""Repeated interruption of real `ftstab run` processes: a signal (SIGINT, SIGTERM, SIGHUP in turn)
at seeded random moments over the whole command (interpreter start, imports, setup, every batch,
closing), and what the logs hold afterwards.

    python -m benchmarks interruptions [--tries 60] [--seed 1] [--scenario cart_r2_robust] [--entry both]

The command is started as ``python -m ftstab_mj`` and as the installed ``ftstab`` script in turn
(--entry both; each gets every signal). Each try is classified: "no log" (stopped before the
logs were opened: none written, exit 128 + signal), "interrupted" (two complete logs, the same
samples in both, status interrupted, recorded metrics equal to the replayed ones, exit 128 +
signal, "the logs say so" only then), "completed" (the signal came after the logs were closed:
exit 0), "start-up" (a traceback of Python's own start-up, before the entry's first line runs:
no frame of ours, no log; listed, not a failure of the command, whose handlers do not exist yet),
or a failure (anything else: printed, and the script exits 1).
"""

from __future__ import annotations

import argparse
import json
import os
import re
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
    ap.add_argument("--entry", choices=("module", "script", "both"), default="both",
                    help="python -m ftstab_mj, the ftstab script next to this Python, or both in turn")
    args = ap.parse_args()
    import numpy as np

    from ftstab_mj.logs.reader import read_log
    from ftstab_mj.metrics.run_metrics import compute_metrics

    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    entries = {"module": [sys.executable, "-m", "ftstab_mj"], "script": [str(Path(sys.executable).parent / "ftstab")]}
    entries = {k: v for k, v in entries.items() if args.entry in (k, "both")}
    run = ["run", args.scenario, "--set", f"sim.duration={args.duration}", "--rrd"]  # both logs: do they agree?

    def start(out, entry=next(iter(entries))):
        return subprocess.Popen(entries[entry] + run + ["--out", str(out)], env=env, stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, text=True,
                                preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))

    def ours(err):  # a traceback through our code (after the entry's first line), not Python's start-up:
        # only a SIGINT has a handler (Python's) in the start-up, that of SIGTERM and SIGHUP kills quietly
        return any("ftstab_mj" + os.sep in f and not f.endswith("__init__.py") for f in re.findall(r'File "([^"]+)"', err))

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
        outcomes, failures, startup, same = Counter(), [], [], 0
        for k, delay in enumerate(rng.uniform(0.0, whole, args.tries)):
            sig = sigs[k % 3]
            entry = list(entries)[(k // 3) % len(entries)]
            out = Path(tmp) / f"t{k}"
            p = start(out, entry)
            time.sleep(delay)
            p.send_signal(sig)
            _, err = p.communicate()
            mcap, rrd = out / f"{args.scenario}.mcap", out / f"{args.scenario}.rrd"
            why = ""
            if (sig == signal.SIGINT and err.rstrip().endswith("KeyboardInterrupt") and not ours(err)
                    and not mcap.exists() and not rrd.exists()):
                outcomes["start-up"] += 1
                startup.append(f"try {k}: {entry} {signal.Signals(sig).name} at {delay * 1e3:.1f} ms: exit {p.returncode}: "
                               + " / ".join(err.strip().splitlines()[-2:]))
                continue
            if "Traceback" in err or "Exception ignored" in err:
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
                elif "the logs say so" in err and status != "interrupted":
                    why = f"says the logs say so, but they say {status}"
                elif json.loads(json.dumps(compute_metrics(log.info, log.loops, status))) != log.recorded["metrics"]:
                    why = "recorded metrics differ from the replayed ones"
                elif any(rrd_rows(rrd, f"/loop/{n}/V1/log10_V1") - static != log.n_samples for n in log.loops):
                    why = "the .rrd and the .mcap hold different samples"
                else:
                    same += 1
            if why:
                failures.append(f"try {k}: {entry} {signal.Signals(sig).name} at {delay:.3f} s: {why}: {err.strip()[-300:]}")
                kind = "FAILED"
            outcomes[kind] += 1
    print(f"{args.tries} tries ({' and '.join(entries)}), {args.scenario}, sim.duration {args.duration} s, whole "
          f"command {whole:.2f} s, seed {args.seed}: " + ", ".join(f"{n} {k}" for k, n in sorted(outcomes.items())))
    print(f"the .mcap and the .rrd hold the same samples: {same} of the {same + sum('different samples' in f for f in failures)}"
          " tries that left logs with a status")
    for line in startup:
        print("start-up (Python's, before the entry's first line):", line)
    for line in failures:
        print(line)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())

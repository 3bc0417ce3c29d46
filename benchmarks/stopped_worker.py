"""A worker of `ftstab sweep` stopped (SIGSTOP) mid-sweep: how long the command takes, and is its table right?

    python -m benchmarks.stopped_worker [--samples 1500] [--after 100] -- ENGINE OPTIONS...
    e.g. python -m benchmarks.stopped_worker -- --engine dask --workers 2
         python -m benchmarks.stopped_worker -- --workers 2

The rows case of benchmarks/sweep_speedup.py (``--samples`` rows of 1 s of the r = 2 robust cart) run by
the real command in a fresh process; once ``--after`` rows are in its journal, one worker process (a
grandchild for a local Dask cluster, whose workers are forked by a forkserver; a child for processes)
gets SIGSTOP. Prints when it was stopped, the command's wall and exit code, its last lines, and whether
every row of its table equals the serial run's (run afterwards). Run on a tree at 9a127bf (before the
local cluster had its own worker-ttl) to see distributed's default at work (5 minutes, checked every 5
minutes). The stopped process is killed at the end if it is still there.
"""

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.sweep_speedup import ROOT, sweep_file
from ftstab_mj.studies.sweep.table import VARYING_COLUMNS, read_table


def children(pid: int) -> list[int]:
    kids = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as f:
                    if int(f.read().rsplit(")", 1)[1].split()[1]) == pid:
                        kids.append(int(entry))
            except (OSError, ValueError, IndexError):
                continue
    return kids


def worker_of(pid: int) -> int | None:
    """A worker process of the command ``pid``: a forkserver's child (local Dask), else a child that is not
    multiprocessing's resource tracker (processes)."""
    grand = [g for c in children(pid) for g in children(c)]
    if grand:
        return grand[0]
    for c in children(pid):
        with open(f"/proc/{c}/cmdline", "rb") as f:
            if b"resource_tracker" not in f.read():
                return c
    return None


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=1500)
    ap.add_argument("--after", type=int, default=100, help="rows journaled before the stop")
    ap.add_argument("engine", nargs=argparse.REMAINDER, help="-- then the command's engine options")
    args = ap.parse_args()
    extra = [a for a in args.engine if a != "--"]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        sweep = sweep_file(tmp, "rows", samples=args.samples)
        out, journal = tmp / "run", tmp / "run" / "rows.jsonl"
        t0 = time.monotonic()
        proc = subprocess.Popen([sys.executable, "-m", "ftstab_mj", "sweep", str(sweep), "--out", str(out), *extra],
                                cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        victim = None
        while victim is None and proc.poll() is None:
            time.sleep(0.1)
            if journal.exists() and journal.read_bytes().count(b"\n") >= args.after:
                victim = worker_of(proc.pid)
                if victim is not None:
                    os.kill(victim, signal.SIGSTOP)
                    print(f"worker {victim} stopped at {time.monotonic() - t0:.1f} s (load {os.getloadavg()[0]:.2f})",
                          flush=True)
        stdout, stderr = proc.communicate()
        print(f"exit {proc.returncode} after {time.monotonic() - t0:.1f} s")
        for line in (stdout.strip().splitlines()[-2:] + stderr.strip().splitlines()[-2:]):
            print("  " + (line if len(line) < 300 else line[:297] + "..."))
        if victim is not None:
            try:
                os.kill(victim, signal.SIGKILL)
            except ProcessLookupError:
                pass
        subprocess.run([sys.executable, "-m", "ftstab_mj", "sweep", str(sweep), "--out", str(tmp / "serial")], cwd=ROOT,
                       capture_output=True, check=True)
        ref, got = read_table(tmp / "serial" / "rows.parquet"), read_table(out / "rows.parquet")
        at = {r: k for k, r in enumerate(ref["row"])}
        cols = [c for c in got if c not in VARYING_COLUMNS]
        same = all(got[c][k] == ref[c][at[r]] for k, r in enumerate(got["row"]) for c in cols)
        print(f"table: {len(got['row'])} of {args.samples} rows, each equal to the serial run's: {'yes' if same else 'NO'}")


if __name__ == "__main__":
    main()

"""Where the wall of a sweep goes, per engine: a timeline of every row on every worker.

    python -m benchmarks.sweep_timeline [--samples 200] [--repeat 3] [--scheduler ADDRESS]

The rows case of benchmarks/sweep_speedup.py (``--samples`` rows of 1 s of the r = 2 robust cart),
run through the engines' own code (runner.prepare, engine.started_ahead and engine.execute, as
``ftstab sweep`` calls them) in a fresh process per run, serial, 2 processes and a 2-worker Dask
LocalCluster (and an external scheduler's workers with ``--scheduler``), alternately, --repeat times.
Each row reports its worker process, its start (Unix s, the worker's clock: this machine's), its
wall and its thread's CPU. Printed per engine, medians of the runs [min, max]:

- before the first row: process start -> rows validated (imports, load, prepare; a Dask cluster
  starting beside them in a thread) and -> engine ready (the cluster's workers up);
- the rows: first start -> last end; per worker the rows it ran, its first row's CPU, the median CPU
  and wall of a row, the idle time between its rows (per-task cost: scheduling, a round trip,
  unpickling), and the idle time before its first and after its last row (imbalance);
- after the rows: last end -> the engine closed;
- CPU s of the parent during the rows (journal, scheduler, client, nannies) and of every worker.

Wall times depend on the machine's other load (printed); CPU times much less.
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

# one run, in a fresh process: argv = engine, workers, sweep file, scheduler or "", output json
CHILD = r"""
import json, os, sys, time
T0 = time.time()
from ftstab_mj.studies.batch_env import batch_environment, start_forkserver


class Timed:  # the task with the row's worker and thread CPU added (pickled by value onto the workers)
    def __init__(self, task):
        self.task = task

    def carrying(self, indices):
        return Timed(self.task.carrying(indices))

    def __call__(self, index, params):
        c0 = time.thread_time()
        out = self.task(index, params)
        out["pid"], out["cpu"] = os.getpid(), time.thread_time() - c0
        return out


def cpu_of(pid):
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def main():
    batch_environment()
    engine_name, workers, path, scheduler, out = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4] or None, sys.argv[5]
    if engine_name == "dask" and not scheduler:
        start_forkserver()  # as cmd_sweep
    from ftstab_mj.studies.sweep import engine, expand, load_sweep
    from ftstab_mj.studies.sweep.row import prepare

    sweep = load_sweep(path)
    rows = expand(sweep)
    with engine.started_ahead(engine_name, workers, scheduler) as ahead:
        task, _ = prepare(sweep, rows)
        t_prepared = time.time()
        if ahead is not None:
            ahead.connection.result()
        t_ready = time.time()
        cpu0 = time.process_time()
        got, t_last = [], None
        for i, r in engine.execute([(r.index, r.params) for r in rows], Timed(task), engine_name, workers, scheduler,
                                   ahead=ahead):
            got.append({k: r[k] for k in ("started_at", "elapsed_s", "pid", "cpu", "status")})
            if len(got) == len(rows):
                t_last, cpu1 = time.time(), time.process_time()
                workers_cpu = {p: cpu_of(p) for p in {g["pid"] for g in got} if p != os.getpid()} if not scheduler else {}
    t_closed = time.time()
    json.dump({"t0": T0, "prepared": t_prepared, "ready": t_ready, "last": t_last, "closed": t_closed,
               "parent_cpu": cpu1 - cpu0, "workers_cpu": workers_cpu, "parent": os.getpid(), "rows": got}, open(out, "w"))


if __name__ == "__main__":
    main()
"""


def summary(run: dict) -> dict:
    """The figures of one run (s unless named ms)."""
    rows = run["rows"]
    first = min(r["started_at"] for r in rows)
    end = max(r["started_at"] + r["elapsed_s"] for r in rows)
    by = {}
    for r in sorted(rows, key=lambda r: r["started_at"]):
        by.setdefault(r["pid"], []).append(r)
    out = {"to prepared": run["prepared"] - run["t0"], "to engine ready": run["ready"] - run["t0"],
           "to first row": first - run["t0"], "rows": end - first, "last row -> closed": run["closed"] - end,
           "whole": run["closed"] - run["t0"], "parent CPU in rows": run["parent_cpu"]}
    workers = [rs for pid, rs in by.items() if len(rs) > 1 or len(by) == 1]
    out["rows per worker"] = sorted(len(rs) for rs in workers)
    out["first row CPU ms"] = statistics.median(rs[0]["cpu"] * 1e3 for rs in workers)
    out["row CPU ms"] = statistics.median(r["cpu"] * 1e3 for rs in workers for r in rs[1:] or rs)
    out["row wall ms"] = statistics.median(r["elapsed_s"] * 1e3 for rs in workers for r in rs[1:] or rs)
    out["idle between rows"] = max(sum(b["started_at"] - a["started_at"] - a["elapsed_s"] for a, b in zip(rs, rs[1:]))
                                   for rs in workers)
    out["idle before first, after last"] = max(rs[0]["started_at"] - first + end - rs[-1]["started_at"] - rs[-1]["elapsed_s"]
                                               for rs in workers)
    out["workers CPU"] = sum(run["workers_cpu"].values())
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=200)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--scheduler", help="also run on the workers of this Dask scheduler")
    args = ap.parse_args()
    from benchmarks.sweep_speedup import sweep_file
    from ftstab_mj.studies.batch_env import batch_environment

    configs = {"serial": ("serial", 1), "processes, 2": ("processes", 2), "dask LocalCluster, 2": ("dask", 2)}
    if args.scheduler:
        configs["external dask"] = ("dask", 1)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        sweep = sweep_file(tmp, "rows", samples=args.samples)
        child = tmp / "child.py"
        child.write_text(CHILD)
        runs, loads = {name: [] for name in configs}, []
        for rep in range(args.repeat):
            for name, (engine, workers) in configs.items():
                loads.append(os.getloadavg()[0])
                out = tmp / "out.json"
                scheduler = args.scheduler if name == "external dask" else ""
                proc = subprocess.run([sys.executable, str(child), engine, str(workers), str(sweep), scheduler, str(out)],
                                      cwd=ROOT, capture_output=True, text=True, env=batch_environment(dict(os.environ)))
                if proc.returncode != 0:
                    sys.exit(f"{name}: exit {proc.returncode}: {proc.stderr.strip()[-2000:]}")
                run = json.loads(out.read_text())
                bad = [r["status"] for r in run["rows"] if r["status"] != "completed"]
                if bad or len(run["rows"]) != args.samples:
                    sys.exit(f"{name}: {len(bad)} rows not completed of {len(run['rows'])}: nothing to measure")
                runs[name].append(summary(run))
                print(f"{name:<22} {runs[name][-1]['whole']:.2f} s (load {loads[-1]:.2f})", flush=True)
            time.sleep(0.5)
    print(f"\n{args.samples} rows of 1 s, median [min, max] of {args.repeat} (load {min(loads):.2f} to {max(loads):.2f}):")
    names = list(configs)
    print(f"{'':<32}" + "".join(f"{n:>26}" for n in names))
    for key in runs[names[0]][0]:
        cells = []
        for n in names:
            vals = [r[key] for r in runs[n]]
            if key == "rows per worker":
                cells.append(" ".join("/".join(str(x) for x in v) for v in vals))
            else:
                cells.append(f"{statistics.median(vals):.3f} [{min(vals):.3f}, {max(vals):.3f}]")
        print(f"{key:<32}" + "".join(f"{c:>26}" for c in cells))


if __name__ == "__main__":
    main()

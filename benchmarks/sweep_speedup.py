"""Speed-up of `ftstab sweep` from 1 to 2 workers, and the set-up cost of one sweep row.

    python -m benchmarks.sweep_speedup [--case rows|periods] [--repeat 3] [--no-external]

Cases:
- ``rows`` (default, issue 16): 200 rows of 1 s simulated of the r = 2 robust cart, z0[0] drawn in
  [-1, 1] m: ~4 ms of CPU a row, so engine start-up and per-task costs weigh as much as the runs.
- ``periods`` (issue 7): the 7 control periods of robust_accuracy_vs_period.toml at 20 s, physics step
  0.1 ms, times 8 initial positions: 56 rows of ~0.3 s of CPU each.

First the set-up cost of a row, in this process: CPU per row of 1 s and of 2 s rows (the task the
engines call, 40 rows each, alternated, median of 5), extrapolated linearly to a 0 s row. Then each
configuration runs the real command in a fresh process (engine start-up included), alternately,
--repeat times: serial, 2 dask workers (LocalCluster), 2 processes, and 2 workers of an external
``dask scheduler`` started once by this script (``dask worker --nworkers 2 --nthreads 1``: start-up
paid once, as on a standing cluster). Prints median and range of the wall times, the speed-up of the
medians over serial, the 1-minute load average before each run, and checks that every configuration
wrote the same table. The machine's other load counts: read the load column.
"""

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from ftstab_mj.sweep.table import VARYING_COLUMNS, read_table

ROOT = Path(__file__).resolve().parent.parent
BASE = ROOT / "scenarios" / "cart_r2_robust.toml"
CASES = {
    "rows": '''samples = 200
[set]
"sim.duration" = {duration}
[draw]
"loops.cart.z0[0]" = {{uniform = [-1.0, 1.0]}}
''',
    "periods": '''samples = 8
[set]
"sim.duration" = 20.0
"sim.physics_step" = 1e-4
[grid]
"sim.period" = [1e-4, 2e-4, 5e-4, 1e-3, 2e-3, 5e-3, 1e-2]
[draw]
"loops.cart.z0[0]" = {{uniform = [-1.0, 1.0]}}
''',
}


def sweep_file(folder: Path, case: str, duration: float = 1.0) -> Path:
    path = folder / f"{case}.toml"
    path.write_text(f'name = "{case}"\ndescription = "benchmark"\nscenario = "{BASE}"\nseed = 1\n'
                    + CASES[case].format(duration=duration))
    return path


def setup_cost(folder: Path) -> tuple[float, float, float]:
    """(ms of CPU per 1 s row, per 2 s row, extrapolated to a 0 s row): the task as the engines call it."""
    from ftstab_mj.sweep import expand, load_sweep
    from ftstab_mj.sweep.engine import run_chunk
    from ftstab_mj.sweep.runner import prepare

    tasks = {}
    for d in (1.0, 2.0):
        sw = load_sweep(sweep_file(folder, "rows", d))
        rows = expand(sw)[:40]
        task, _ = prepare(sw, rows)
        items = [(r.index, r.params) for r in rows]
        run_chunk(task, items[:2])  # warm: imports, the certificate, the caches of the first run
        tasks[d] = (task, items)
    per_row = {1.0: [], 2.0: []}
    for _ in range(5):
        for d, (task, items) in tasks.items():
            t0 = time.process_time()
            run_chunk(task, items)
            per_row[d].append((time.process_time() - t0) / len(items) * 1e3)
    c1, c2 = statistics.median(per_row[1.0]), statistics.median(per_row[2.0])
    return c1, c2, 2 * c1 - c2


def start_external(folder: Path):
    """A `dask scheduler` and `dask worker --nworkers 2 --nthreads 1` as subprocesses; (address, procs)."""
    addr_file = folder / "scheduler.json"
    dask = [sys.executable, "-m", "distributed.cli.dask_scheduler"]
    sched = subprocess.Popen(dask + ["--scheduler-file", str(addr_file), "--port", "0", "--dashboard-address", ":0"],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    for _ in range(300):
        if addr_file.exists() and addr_file.stat().st_size:
            break
        time.sleep(0.1)
    worker = subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", "--scheduler-file", str(addr_file),
                               "--nworkers", "2", "--nthreads", "1", "--no-dashboard"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    from distributed import Client

    with Client(scheduler_file=str(addr_file), timeout="30s") as client:
        client.wait_for_workers(2, timeout=60)
        address = client.scheduler.address
    return address, (worker, sched)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", choices=tuple(CASES), default="rows")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-external", action="store_true", help="skip the external dask scheduler")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        c1, c2, c0 = setup_cost(tmp)
        print(f"CPU per row: {c1:.2f} ms (1 s rows), {c2:.2f} ms (2 s rows); set-up of a row (0 s extrapolated): "
              f"{c0:.2f} ms   (load: {os.getloadavg()[0]:.2f})", flush=True)
        sweep = sweep_file(tmp, args.case)
        configs = {
            "serial": ("--workers", "1"),
            "dask, 2 workers": ("--workers", "2"),
            "processes, 2 workers": ("--engine", "processes", "--workers", "2"),
        }
        procs = ()
        if not args.no_external:
            address, procs = start_external(tmp)
            configs["external dask, 2 workers"] = ("--scheduler", address)
        try:
            walls, tables = {}, {}
            for rep in range(args.repeat):
                for k, (name, extra) in enumerate(configs.items()):
                    out = tmp / f"{rep}-{k}"
                    load = os.getloadavg()[0]
                    t0 = time.perf_counter()
                    proc = subprocess.run([sys.executable, "-m", "ftstab_mj", "sweep", str(sweep), "--out", str(out),
                                           *extra], cwd=ROOT, capture_output=True, text=True)
                    wall = time.perf_counter() - t0
                    if proc.returncode != 0:
                        sys.exit(f"{name}: exit {proc.returncode}: {proc.stderr.strip().splitlines()[-1]}")
                    print(f"{name:<26} {wall:6.2f} s   (load before: {load:.2f})", flush=True)
                    walls.setdefault(name, []).append(wall)
                    table = read_table(out / f"{args.case}.parquet")
                    tables[name] = {c: v for c, v in table.items() if c not in VARYING_COLUMNS}
        finally:
            for p in procs:
                p.terminate()
                p.wait(timeout=30)
        n = len(tables["serial"]["row"])
        serial = statistics.median(walls["serial"])
        print(f"\n{n} runs, median [min, max] of {args.repeat}, on {os.cpu_count()} cores:")
        for name, ws in walls.items():
            med = statistics.median(ws)
            print(f"  {name:<26} {med:6.2f} s [{min(ws):.2f}, {max(ws):.2f}]   speed-up {serial / med:4.2f}")
        same = all(t == tables["serial"] for t in tables.values())
        print(f"  tables identical across engines: {'yes' if same else 'NO'}")


if __name__ == "__main__":
    main()

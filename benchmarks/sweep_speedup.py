"""Speed-up of `ftstab sweep` from 1 to 2 workers (the figure of issue 7's closing note).

    python -m benchmarks.sweep_speedup [--repeat 2] [--runs 8]

The sweep: the r = 2 robust cart of robust_accuracy_vs_period.toml (20 s, physics step 0.1 ms, the
7 control periods), times --runs initial positions drawn uniformly in [-1, 1] m: 7 * runs runs of
~0.3 s of CPU each (MuJoCo steps in C). Each configuration runs the real command in a fresh process
(engine start-up included), alternately, --repeat times; prints the best wall time of each, the
speed-up over serial, the 1-minute load average before each run, and checks that every
configuration wrote the same table. The machine's other load counts: read the load column.
"""

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from ftstab_mj.sweep.table import VARYING_COLUMNS, read_table

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = {
    "serial": ("--workers", "1"),
    "dask, 2 workers": ("--workers", "2"),
    "processes, 2 workers": ("--engine", "processes", "--workers", "2"),
}


def sweep_file(folder: Path, runs: int) -> Path:
    path = folder / "speedup.toml"
    path.write_text(f'''name = "speedup"
description = "robust r = 2 cart, 7 periods x {runs} initial positions"
scenario = "{ROOT / "scenarios" / "cart_r2_robust.toml"}"
samples = {runs}
[set]
"sim.duration" = 20.0
"sim.physics_step" = 1e-4
[grid]
"sim.period" = [1e-4, 2e-4, 5e-4, 1e-3, 2e-3, 5e-3, 1e-2]
[draw]
"loops.cart.z0[0]" = {{uniform = [-1.0, 1.0]}}
''')
    return path


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--runs", type=int, default=8, help="initial positions per period (default 8: 56 runs)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        sweep = sweep_file(tmp, args.runs)
        best, tables = {}, {}
        for rep in range(args.repeat):
            for name, extra in CONFIGS.items():
                out = tmp / f"{rep}-{name.split(',')[0]}"
                load = os.getloadavg()[0]
                t0 = time.perf_counter()
                proc = subprocess.run([sys.executable, "-m", "ftstab_mj", "sweep", str(sweep), "--out", str(out), *extra],
                                      cwd=ROOT, capture_output=True, text=True)
                wall = time.perf_counter() - t0
                if proc.returncode != 0:
                    sys.exit(f"{name}: exit {proc.returncode}: {proc.stderr.strip().splitlines()[-1]}")
                print(f"{name:<22} {wall:6.2f} s   (load before: {load:.2f})", flush=True)
                best[name] = min(best.get(name, wall), wall)
                table = read_table(out / "speedup.parquet")
                tables[name] = {k: v for k, v in table.items() if k not in VARYING_COLUMNS}
        n = len(tables["serial"]["row"])
        print(f"\n{n} runs, best of {args.repeat}, on {os.cpu_count()} cores:")
        for name, wall in best.items():
            print(f"  {name:<22} {wall:6.2f} s   speed-up {best['serial'] / wall:4.2f}")
        same = all(t == tables["serial"] for t in tables.values())
        print(f"  tables identical across engines: {'yes' if same else 'NO'}")


if __name__ == "__main__":
    main()

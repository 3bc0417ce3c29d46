"""The batch engine against the serial one, Monte Carlo on the plant against bare stepping, chain memory.

    python -m benchmarks.batch_engine [--rows 96] [--states 200,1000] [--chain-states 2000] [--long 100] [--repeat 3]

Prints, measured in this one run (alternated, medians of --repeat):

1. ``ftstab sweep`` of --rows rows of 2 s on the r = 2 robust cart (a grid over the disturbance's
   amplitude): CPU s of the whole process (children included) for --engine serial, batch --workers 1
   and batch --workers 2, their ratios to serial, the wall-time speed-up of 2 threads over 1, and
   whether the three tables agree in every column but the elapsed time; and the floor: one process
   that imports what ``ftstab sweep`` imports and steps the same rows bare (mj_step, no control, no
   log, no metrics), as a ratio to the serial sweep (no engine can go below it).
2. ``ftstab montecarlo --on plant --engine batch`` on the same cart, for each of --states (a list)
   states of 2 s: CPU s of the whole process against a bare reference, one process that steps the
   same states (mj_step over the same number of steps on one MjData, reset to each z0) after
   importing the same modules.
3. ``ftstab montecarlo --on chain`` of --chain-states states at 10 s and 50 s simulated: the peak RSS
   of each process, and their ratio.
4. The same sweep with rows of --long s (>= 20 s of row CPU at the default 100 s: set-up amortized):
   the wall-time speed-up of ``--engine batch --workers 2`` over ``--workers 1``, and their CPU s.
"""

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks._common import child_env

ROOT = Path(__file__).resolve().parents[1]
CART = ROOT / "scenarios" / "cart_r2_robust.toml"

BARE = """
import sys, numpy as np, mujoco
states, duration, what = int(sys.argv[1]), float(sys.argv[2]), sys.argv[3]
if what == "sweep":  # what `ftstab sweep` imports (the table's writer too)
    import ftstab_mj.cli.sweep, ftstab_mj.studies.sweep, ftstab_mj.studies.sweep.row, ftstab_mj.scenario.run
    from ftstab_mj.studies.sweep.table import load_writer
    load_writer("table.parquet")
else:  # what `ftstab montecarlo` imports
    import ftstab_mj.cli.montecarlo, ftstab_mj.studies.montecarlo, ftstab_mj.scenario.run
from ftstab_mj.plants import make_plant
from ftstab_mj.plants.callback import timer_off
from ftstab_mj.studies import montecarlo as mc
plant = make_plant("cart")
m, d, _ = plant.compile(0.001)
if what == "sweep":  # the sweep's rows all start at the scenario's z0; the Monte Carlo's from its draw
    from ftstab_mj.scenario import load_scenario
    Z0 = np.tile(load_scenario(sys.argv[4]).loops[0].z0, (states, 1))
else:
    Z0 = mc.Distribution(states, (1.0, 1.0), seed=0).draw()
steps = int(round(duration / 0.001))
with timer_off():  # as the runs step (no profiling timer)
    for z in Z0:
        mujoco.mj_resetData(m, d)
        d.qpos[0], d.qvel[0] = z
        mujoco.mj_step(m, d, nstep=steps)
"""


# a fresh process runs the command and reports its children's CPU and peak RSS: only this command's
WRAP = ("import resource, subprocess, sys; r = subprocess.run(sys.argv[1:]); "
        "u = resource.getrusage(resource.RUSAGE_CHILDREN); "
        "print(r.returncode, u.ru_utime + u.ru_stime, u.ru_maxrss, file=sys.stderr)")


def run(cmd: list, cwd) -> tuple[float, float, float]:
    """(CPU s of the command's processes, wall s, peak RSS MB of the largest) of one command."""
    env = child_env()
    w0 = time.perf_counter()
    res = subprocess.run([sys.executable, "-c", WRAP, *map(str, cmd)], cwd=cwd, env=env, capture_output=True,
                         text=True)
    wall = time.perf_counter() - w0
    code, cpu, rss = res.stderr.strip().splitlines()[-1].split()
    if int(code) != 0:
        sys.exit(f"benchmark command failed: {' '.join(map(str, cmd))}\n{res.stderr}")
    return float(cpu), wall, int(rss) / 1024


def sweep_file(tmp: Path, rows: int, duration: float = 2.0, name: str = "bench") -> Path:
    amps = ", ".join(f"{0.1 + 0.9 * i / max(1, rows - 1):.6f}" for i in range(rows))
    path = tmp / f"{name}.toml"
    path.write_text(f'name = "{name}"\ndescription = "batch engine benchmark"\nscenario = "{CART}"\n'
                    f'[set]\n"sim.duration" = {duration}\n[grid]\n"loops.cart.disturbance.amplitude" = [{amps}]\n')
    return path


def table(path: Path) -> dict:
    """The sweep's table but its varying columns (elapsed time)."""
    from ftstab_mj.studies.sweep.table import VARYING_COLUMNS, read_table

    return {k: v for k, v in read_table(path).items() if k not in VARYING_COLUMNS}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rows", type=int, default=96)
    ap.add_argument("--states", default="200,1000", help="state counts of the Monte Carlo (2.), comma-separated")
    ap.add_argument("--chain-states", type=int, default=2000)
    ap.add_argument("--long", type=float, default=100.0, help="s simulated per row of the speed-up sweep (4.)")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    py = [sys.executable, "-m", "ftstab_mj"]
    with tempfile.TemporaryDirectory(prefix="ftstab-bench-") as tmp:
        tmp = Path(tmp)
        sweep = sweep_file(tmp, args.rows)
        engines = {"serial": [], "batch1": ["--engine", "batch"], "batch2": ["--engine", "batch", "--workers", "2"]}
        cpu = {k: [] for k in engines}
        wall = {k: [] for k in engines}
        tables, floors = {}, []
        bare = tmp / "bare.py"
        bare.write_text(BARE)
        for rep in range(args.repeat):
            for name, extra in engines.items():
                out = tmp / f"{name}{rep}"
                c, w, _ = run(py + ["sweep", str(sweep), "--out", str(out)] + extra, tmp)
                cpu[name].append(c)
                wall[name].append(w)
                tables[name] = table(out / "bench.parquet")
            floors.append(run([sys.executable, str(bare), str(args.rows), "2.0", "sweep", str(CART)], tmp)[0])
        floor = statistics.median(floors)
        med = {k: statistics.median(v) for k, v in cpu.items()}
        medw = {k: statistics.median(v) for k, v in wall.items()}
        print(f"1. sweep of {args.rows} rows of 2 s on the cart (load {os.getloadavg()[0]:.2f}), CPU s of the whole "
              f"process: serial {med['serial']:.2f}, batch --workers 1 {med['batch1']:.2f} "
              f"({med['batch1'] / med['serial']:.2f}x serial), batch --workers 2 {med['batch2']:.2f} "
              f"({med['batch2'] / med['serial']:.2f}x serial; goal <= 0.5x); floor (the sweep's imports and bare "
              f"stepping of the same rows) {floor:.2f} ({floor / med['serial']:.2f}x serial); wall speed-up of 2 "
              f"threads over 1: {medw['batch1'] / medw['batch2']:.2f}x; tables identical but elapsed time: "
              f"{tables['batch1'] == tables['serial'] and tables['batch2'] == tables['serial']}")

        for states in (int(x) for x in args.states.split(",")):
            mc_cpu, bare_cpu = [], []
            for rep in range(args.repeat):
                out = tmp / f"mc{states}-{rep}"
                c, _, _ = run(py + ["montecarlo", str(CART), "--on", "plant", "--engine", "batch", "--states",
                                    str(states), "--set", "sim.duration=2", "--out", str(out)], tmp)
                mc_cpu.append(c)
                c, _, _ = run([sys.executable, str(bare), str(states), "2.0", "montecarlo"], tmp)
                bare_cpu.append(c)
            a, b = statistics.median(mc_cpu), statistics.median(bare_cpu)
            print(f"2. montecarlo --on plant --engine batch, {states} states of 2 s on the cart (load "
                  f"{os.getloadavg()[0]:.2f}): {a:.2f} CPU s against {b:.2f} for bare stepping of the same states: "
                  f"{a / b:.2f}x (goal <= 1.4x)")

        peaks = {}
        for duration in (10, 50):
            _, _, rss = run(py + ["montecarlo", str(CART), "--on", "chain", "--states", str(args.chain_states),
                                  "--set", f"sim.duration={duration}", "--out", str(tmp / f"chain{duration}"),
                                  "--json"], tmp)
            peaks[duration] = rss
        print(f"3. montecarlo --on chain, {args.chain_states} states: peak RSS {peaks[10]:.0f} MB at 10 s, "
              f"{peaks[50]:.0f} MB at 50 s: {peaks[50] / peaks[10]:.2f}x (goal <= 1.2x)")

        long = sweep_file(tmp, args.rows, args.long, "long")
        lcpu, lwall = {1: [], 2: []}, {1: [], 2: []}
        for rep in range(args.repeat):
            for w in (1, 2):
                c, wl, _ = run(py + ["sweep", str(long), "--out", str(tmp / f"long{w}-{rep}"), "--engine", "batch",
                                     "--workers", str(w)], tmp)
                lcpu[w].append(c)
                lwall[w].append(wl)
        c1, c2 = statistics.median(lcpu[1]), statistics.median(lcpu[2])
        w1, w2 = statistics.median(lwall[1]), statistics.median(lwall[2])
        print(f"4. sweep of {args.rows} rows of {args.long:g} s (load {os.getloadavg()[0]:.2f}), --engine batch: "
              f"--workers 1 {w1:.2f} s wall / {c1:.2f} CPU s, --workers 2 {w2:.2f} s wall / {c2:.2f} CPU s: "
              f"speed-up of 2 threads over 1 {w1 / w2:.2f}x (2 cores shared)")


if __name__ == "__main__":
    main()

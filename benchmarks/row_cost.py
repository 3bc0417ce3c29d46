"""The fixed CPU cost of a sweep row on the cart, in one process, against bare stepping of the same rows.

    python -m benchmarks row_cost [--rows 96] [--duration 2] [--repeat 7]

The sweep of benchmarks/batch_engine.py (--rows rows of --duration s on the r = 2 robust cart, a grid
over the disturbance's amplitude), run as ``ftstab sweep`` runs it serially, after one untimed pass
(imports, the certificate cache, the compiled model): ``prepare`` (every row validated) then every
row run by the serial engine (set-up, stepping with the native law, metrics). Against it, bare
``mj_step`` of the same rows (the cart's model, reset to z0, the same number of steps, MuJoCo's timer
off as the runs have it). CPU time of this process, alternated, medians of --repeat. The issue's goal:
a fixed cost (row - bare) <= 1 ms a row; it includes the control law's own cost at every step.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

from benchmarks.batch_engine import sweep_file


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rows", type=int, default=96)
    ap.add_argument("--duration", type=float, default=2.0)
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args()

    import mujoco

    from ftstab_mj.plants import make_plant
    from ftstab_mj.plants.callback import timer_off
    from ftstab_mj.studies.sweep.engine import execute
    from ftstab_mj.studies.sweep.expand import expand
    from ftstab_mj.studies.sweep.row import prepare
    from ftstab_mj.studies.sweep.spec import load_sweep

    with tempfile.TemporaryDirectory(prefix="ftstab-rowcost-") as tmp:
        sweep = load_sweep(sweep_file(Path(tmp), args.rows, args.duration))
    rows = expand(sweep)
    items = [(r.index, r.params) for r in rows]
    m, d, _ = make_plant("cart").compile(0.001)
    steps = int(round(args.duration / 0.001))

    def validate():
        return prepare(sweep, rows)[0]

    def run(task):
        for _, res in execute(items, task):
            assert res["status"] == "completed", res

    def bare():
        with timer_off():
            for _ in rows:
                mujoco.mj_resetData(m, d)
                d.qpos[0] = 1.0  # cart_r2_robust's z0
                mujoco.mj_step(m, d, nstep=steps)

    run(validate())  # untimed: imports, caches
    bare()
    cpu = {"validate": [], "run": [], "bare": []}
    for _ in range(args.repeat):
        t = time.process_time()
        task = validate()
        cpu["validate"].append(time.process_time() - t)
        t = time.process_time()
        run(task)
        cpu["run"].append(time.process_time() - t)
        t = time.process_time()
        bare()
        cpu["bare"].append(time.process_time() - t)
    ms = {k: 1000 * statistics.median(v) / args.rows for k, v in cpu.items()}
    fixed = ms["validate"] + ms["run"] - ms["bare"]
    print(f"sweep rows of {args.duration:g} s on the cart, {args.rows} rows, medians of {args.repeat} "
          f"(load {os.getloadavg()[0]:.2f}), CPU ms a row: validation {ms['validate']:.2f}, run {ms['run']:.2f}, "
          f"bare mj_step {ms['bare']:.2f}; fixed cost (validation + run - bare) {fixed:.2f} ms (goal <= 1)")


if __name__ == "__main__":
    main()

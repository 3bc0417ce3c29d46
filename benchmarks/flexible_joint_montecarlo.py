"""Monte Carlo of Theorem 1 on the flexible joint (r = 4): the long study behind the flexible joint page.

    python -m benchmarks flexible_joint_montecarlo [--states 1000] [--seeds 1] [--workers 2] [--save PATH]

Runs scenarios/montecarlo/flexible_joint_r4.toml on the plant (``ftstab montecarlo --on plant``, the
batch engine) for --states initial states uniform in |z0| <= (0.2, 0.3, 0.3, 0.3), in --seeds draws of
--states / --seeds states each (seeds 1, 2, ...: a draw finished is kept if a later one is stopped),
and prints the distribution of settle time / T(z0), the states where the bound applies, those beyond
it, and the CPU seconds per state. --save writes the rows (parquet) that the docs' figure and
tests/test_montecarlo.py's check of the page's numbers read (tests/data/flexible_joint_montecarlo.parquet).
About 0.75 CPU-second per state (5 s simulated at 1 ms): 1,000 states are some 6 minutes on 2 free
cores (27 minutes on a shared, loaded machine, --engine processes, for the committed rows).
"""

import argparse
import os
import time
from pathlib import Path

import numpy as np

from ftstab_mj.scenario import load_scenario
from ftstab_mj.studies import montecarlo as mc

FILE = Path(__file__).resolve().parents[1] / "scenarios" / "montecarlo" / "flexible_joint_r4.toml"
BOX = (0.2, 0.3, 0.3, 0.3)


def cpu() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--states", type=int, default=1000)
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--engine", default="batch")
    ap.add_argument("--save", type=Path)
    args = ap.parse_args()
    sc = load_scenario(FILE, [])
    rows, c0, w0 = [], cpu(), time.perf_counter()
    for seed in range(1, args.seeds + 1):
        Z0 = mc.Distribution(args.states // args.seeds, BOX, seed).draw()
        part, _ = mc.run_on("plant", sc, FILE, [], "link", Z0, args.engine, args.workers)
        rows += [dict(r, row=len(rows) + i, seed=seed) for i, r in enumerate(part)]
    c1, w1 = cpu(), time.perf_counter()
    applies = [r["bound_applies"] for r in rows]
    s = mc.summarize(rows, all(applies))
    q = s["ratio"]
    ratio = np.array([r["ratio"] for r in rows], dtype=float)
    print(f"{len(rows)} states in |z0| <= {BOX}: settled {s['settled']}, bound applies in {sum(applies)}, "
          f"beyond their bound {int(np.sum(ratio > 1))}")
    print(f"settle time / T(z0): min {q['min']:.4g}, median {q['median']:.4g}, p99 {q['p99']:.4g}, max {q['max']:.4g}")
    if s["worst"]:
        w = s["worst"]
        print(f"worst: z0 = {[round(x, 6) for x in w['z0']]}, settle {w['settle_time']:.4g} s, T(z0) {w['time_bound']:.4g} s")
    print(f"max settle time {np.nanmax([r['settle_time'] for r in rows]):.4g} s, max V1_final "
          f"{np.nanmax([r['V1_final'] for r in rows]):.3g}")
    print(f"{(c1 - c0) / len(rows):.3g} CPU s per state, {(w1 - w0) / len(rows):.3g} wall s per state "
          f"(load average {os.getloadavg()[0]:.1f})")
    if args.save:
        from ftstab_mj.studies.sweep.table import write_table

        write_table(rows, args.save)
        print(f"rows: {args.save}")


if __name__ == "__main__":
    main()

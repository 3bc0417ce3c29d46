"""The certificate within its time budget, on random problems of the whole admissible domain.

`ftstab certify --budget B` promises an answer that is never wrong within about B CPU seconds:
certified (c_lower > 0), not certified (a witness state with dV1/dt >= 0) or undecided (both
bounds, no claim). This draws problems and certifies each with the budget the project aims at,
2 s for r <= 3 and 30 s for r = 4, and prints per r and population: how many ended in each
status, the CPU seconds (median and largest, the budget's share of the largest), and how many
went over the budget (the witness search before the branch and bound is not under the budget).

Two populations, seeded:
- "domain": k uniform in (-1/r, 0], gains log-uniform in [0.1, 1e5] (Hurwitz at k = 0 not
  required: most such gains are refuted at once, which is an answer too);
- "near certified": k uniform in [1.5 k_d, 0] and each gain of a certified gain set (k_d its k) times
  2^u, u uniform in [-1, 1]: problems near the certified region, where the bounds must close.

    python -m benchmarks certificate_budget [--n 30] [--r 2,3,4] [--seed 0]

One core; about 3 minutes with the defaults (r = 4 rows take up to their 30 s).
"""

import argparse
import time

import numpy as np

from ftstab_mj.control import HongController, certify

BUDGET = {1: 2.0, 2: 2.0, 3: 2.0, 4: 30.0}
CERTIFIED_SETS = {  # (k, gains) certified by `ftstab certify` (README: the paper's examples and designs)
    2: (-0.2, (1.0, 2.0)),
    3: (-0.1, (1.0, 1.7, 5.0)),
    4: (-0.05, (0.83467, 1.4216, 2.8157, 100.0)),
}


def draw(r: int, population: str, rng) -> tuple[float, tuple]:
    if population == "domain":
        k = -rng.uniform(0.0, 1.0) / r  # (-1/r, 0]: uniform(0, 1) excludes 1
        return k, tuple(float(g) for g in 10.0 ** rng.uniform(-1.0, 5.0, r))
    k_d, gains = CERTIFIED_SETS[r]
    k = rng.uniform(1.5 * k_d, 0.0)
    return k, tuple(float(f"{g * 2.0 ** rng.uniform(-1.0, 1.0):.5g}") for g in gains)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=30, help="problems per r and population (default 30)")
    ap.add_argument("--r", default="2,3,4")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    print("| r | population | budget s | certified | not certified | undecided | CPU s median | CPU s largest "
          "(share of budget) | over budget |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in (int(x) for x in args.r.split(",")):
        for population in ("domain", "near certified"):
            statuses, cpu = [], []
            for _ in range(args.n):
                k, gains = draw(r, population, rng)
                hong = HongController(r, k, gains, check_hurwitz=False)
                t = time.process_time()
                cert = certify(hong, budget=BUDGET[r])
                cpu.append(time.process_time() - t)
                statuses.append(cert.status)
            cpu = np.array(cpu)
            count = {s: statuses.count(s) for s in ("certified", "not certified", "undecided")}
            print(f"| {r} | {population} | {BUDGET[r]:g} | {count['certified']} | {count['not certified']} | "
                  f"{count['undecided']} | {np.median(cpu):.2f} | {cpu.max():.2f} ({cpu.max() / BUDGET[r]:.2f}) | "
                  f"{int(np.sum(cpu > BUDGET[r]))} of {len(cpu)} |", flush=True)


if __name__ == "__main__":
    main()

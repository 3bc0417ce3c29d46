"""The r = 6 frontier at k = 0: the best c of the linear law (linear_limit.linear_c, closed form) over gain
sets with every gain in [0.01, B], for several B. c only grows with l_6, so the span of the gains
that can be certified is bounded from below by this table (and k < 0 only lowers c).

For each B: a simplex search (design.nelder_mead, 3 restarts of 600 iterations) on the log-gains
from 40 random starts (log-uniform in [0.01, B], seed 0), gains outside [0.01, B] infeasible.
Deterministic; one core, about 25 s.

    python benchmarks/r6_frontier.py [--starts 40] [--bounds 1000,3000,1e4,1e5,1e6]
"""

import argparse

import numpy as np

from ftstab_mj.control.nelder_mead import nelder_mead
from ftstab_mj.control.linear_limit import linear_c


def best_c(r: int, B: float, starts: int, rng) -> tuple[float, np.ndarray]:
    lo, hi = np.log(0.01), np.log(B)

    def cost(x):
        if np.any(x < lo) or np.any(x > hi):
            return np.inf
        c = linear_c(np.exp(x))
        return -c if np.isfinite(c) else np.inf

    best, arg = -np.inf, None
    for _ in range(starts):
        x = np.sort(rng.uniform(lo, hi, r))  # increasing gains: where the optima lie
        for _ in range(3):
            x, f = nelder_mead(cost, x, step=0.3, iters=600, tol=1e-12)
        if np.isfinite(f) and -f > best:
            best, arg = -f, np.exp(x)
    return best, arg


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--starts", type=int, default=40)
    ap.add_argument("--bounds", default="1000,3000,1e4,1e5,1e6")
    args = ap.parse_args(argv)
    print("| B | best c at k = 0 | its gains |")
    print("|---|---|---|")
    for B in (float(b) for b in args.bounds.split(",")):
        c, g = best_c(6, B, args.starts, np.random.default_rng(0))
        print(f"| {B:g} | {c:.4g} | {', '.join(f'{x:.4g}' for x in g)} |", flush=True)


if __name__ == "__main__":
    main()

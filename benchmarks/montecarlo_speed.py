"""Monte Carlo throughput of `ftstab montecarlo --on chain`: initial states per CPU-second.

    python -m benchmarks montecarlo_speed [--states 20000] [--repeat 3]

The r = 2 robust cart (10 s at 1 ms, its sine disturbance) on the native ideal chain. Alternately,
--repeat times: A = run_chain (chunks of 128 states, reduced to per-trajectory rows before the next
chunk), B = the bare batched chain on one chunk of the same size scaled to the same number of states
(what the kernel alone costs, recording included). Prints states per CPU-second and per wall-second
of A, the ratio A / B in CPU time (the cost of the reduction), with the 1-minute load average.
Before any B (which records its whole chunk and so raises the peak), A runs on --states / 10 and
then on --states states, and the peak RSS growth over the start is printed after each: flat memory
means the second is no larger than the first.
"""

import argparse
import os
import resource
import time

import numpy as np

from ftstab_mj.studies import montecarlo as mc
from ftstab_mj.simulation.ideal_chain import simulate_chain
from ftstab_mj.scenario import find_scenario, load_scenario


def cpu() -> float:
    t = os.times()
    return t.user + t.system


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--states", type=int, default=20000)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    sc = load_scenario(find_scenario("cart_r2_robust"), ["sim.duration=10"])
    lp = sc.loops[0]
    law = lp.law(2)
    Z0 = mc.Distribution(args.states, (1.0, 1.0), seed=0).draw()
    a_cpu, a_wall, ratios = [], [], []
    peak = lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # noqa: E731 (MB, Linux: KB)
    rss0 = peak()
    growth = []
    for n in (max(1, args.states // 10), args.states):  # A only: B's full recording would set the peak
        mc.run_chain(sc, "cart", Z0[:n])
        growth.append((n, peak() - rss0))
    for _ in range(args.repeat):
        load = os.getloadavg()[0]
        c0, w0 = cpu(), time.perf_counter()
        mc.run_chain(sc, "cart", Z0)
        ca, wa = cpu() - c0, time.perf_counter() - w0
        c0 = cpu()
        simulate_chain(law, Z0[:128], sc.sim.period, sc.sim.duration, phi=lp.disturbance, gamma=lp.gain, native="auto")
        cb = (cpu() - c0) * args.states / 128
        a_cpu.append(args.states / ca)
        a_wall.append(args.states / wa)
        ratios.append(ca / cb)
        print(f"load {load:.2f}: {args.states / ca:,.0f} states/CPU-s, {args.states / wa:,.0f} states/wall-s,"
              f" run_chain / bare chain (CPU) {ca / cb:.2f}")
    med = np.median
    print(f"median: {med(a_cpu):,.0f} states/CPU-s ({min(a_cpu):,.0f}-{max(a_cpu):,.0f}),"
          f" {med(a_wall):,.0f} states/wall-s, ratio {med(ratios):.2f} ({min(ratios):.2f}-{max(ratios):.2f});"
          f" peak RSS growth of A: {growth[0][1]:.0f} MB after {growth[0][0]:,} states,"
          f" {growth[1][1]:.0f} MB after {growth[1][0]:,};"
          f" 10^5 states take ~{1e5 / med(a_wall) / 60:.1f} min wall")


if __name__ == "__main__":
    main()

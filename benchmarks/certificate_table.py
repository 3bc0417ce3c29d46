"""The certificate on a table of gain sets, r = 1..6: CPU time, c_lower, c_upper, gap, status,
then the soundness figure: an adversarial search on every row's claim.

k = 0 rows also show the exact c (c = 2 lambda_min(-(B + B^T)/2) in the backstepping coordinates,
at 50 digits). "designed" rows are `ftstab design --r R --k K` gains; "poles at -1" rows place every
linear closed-loop pole at -1 (the Hurwitz pole-placement choice). One core, CPU seconds
(time.process_time), one run per row (the B&B is deterministic without a budget; with one, its
stopping point depends on the machine's speed). The soundness figure: for every row with a finite
c_lower, the largest dV1/dt / V1^alpha that a gradient ascent with the controller's own Lie
derivative finds from 512 starts, as (found + c_lower) / |c_lower| (the claim is that it is <= 0).

    python -m benchmarks certificate_table [--budget S] [--rows N] [--r R] [--no-soundness] [--rounding]
    python -m benchmarks certificate_table --against DIR [--repeat 3] [--select 10,14,...] [--budget S]

--against DIR: before/after on the same rows. DIR is another source tree of the project (e.g.
`git archive main | tar -x -C DIR`); each row is certified in a fresh process of each tree in turn,
alternating A (DIR) and B (this tree), --repeat times: median CPU seconds with their range, the
ratio A/B of the medians, and each side's status, c_lower and boxes (deterministic without a budget).
--select: the row numbers (0-based, as listed in ROWS) to compare.

--rounding: only the cost of one outward rounding (interval.round_up) against np.nextafter on 1e6
floats, alternating the two, 15 rounds: median and range of the per-element times and their ratio.
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_control_certificate import _max_ratio_search, exact_k0  # noqa: E402

from ftstab_mj.control import HongController, certify  # noqa: E402
from ftstab_mj.control.hong import gains_for_polynomial  # noqa: E402


def _poles_at_minus_one(r):
    return tuple(round(g, 6) for g in gains_for_polynomial(np.poly([-1.0] * r)))


ROWS = [  # (r, k, gains, origin)
    (1, -0.3, (2.0,), "hand"),
    (2, -0.2, (1.0, 2.0), "NOTES table"),
    (2, -0.2, (6.8565, 100.0), "designed"),
    (2, 0.0, (0.1, 1e5), "k = 0, 6 decades"),
    (3, -0.1, (1.0, 1.7, 5.0), "NOTES table"),
    (3, -0.1, (1.0, 2.0, 3.0), "NOTES table (fails)"),
    (3, -0.1, (1.3427, 2.5314, 100.0), "designed"),
    (3, -0.02, (3.233, 46.004, 1e5), "5 decades"),
    (3, 0.0, (0.1, 45.94, 1e5), "k = 0, 6 decades"),
    (4, -0.05, (0.83467, 1.4216, 2.8157, 100.0), "designed"),
    (4, -0.05, _poles_at_minus_one(4), "poles at -1"),
    (4, 0.0, (1.08, 1.72, 4.46, 100.0), "k = 0"),
    (4, 0.0, (1.253, 3.042, 50.211, 1e5), "k = 0, 5 decades"),
    (4, -0.02, (1.253, 3.042, 50.211, 1e5), "5 decades"),
    (5, 0.0, (0.65, 1.2, 1.62, 12.63, 1000.0), "k = 0, 4 decades"),
    (5, 0.0, (0.993, 1.541, 3.158, 49.278, 1e5), "k = 0, 6 decades"),
    (5, -0.02, (0.65, 1.2, 1.62, 12.63, 1000.0), "4 decades"),
    (5, -0.02, (0.78947, 1.185, 1.8612, 7.6323, 1000.0), "designed"),
    (5, -0.02, (0.4129, 0.9883, 1.1662, 2.2767, 16.3051), "designed by uniform states (refuted)"),
    (5, -0.02, _poles_at_minus_one(5), "poles at -1"),
    (6, 0.0, (0.62, 1.15, 1.54, 3.88, 39.13, 1e5), "k = 0, 6 decades"),
    (6, -0.002, (0.62, 1.15, 1.54, 3.88, 39.13, 1e5), "6 decades"),
    (6, -0.05, (0.62, 1.15, 1.54, 3.88, 39.13, 1e5), "6 decades"),
    (6, -0.005, (0.64341, 1.1855, 1.4617, 3.5771, 41.866, 1e5), "designed (first search)"),
    (6, -0.01, (0.67895, 1.0737, 1.4911, 3.0208, 37.59, 1e5), "designed (first search)"),
    (6, -0.02, (0.5534, 0.8051, 1.7204, 1.4749, 4.6221, 100.0), "designed by uniform states (refuted)"),
    (6, -0.02, _poles_at_minus_one(6), "poles at -1"),
    (5, -0.01, (0.65, 1.2, 1.62, 12.63, 1000.0), "4 decades"),
    (5, -0.02, (0.70786, 1.2531, 1.7263, 8.945, 1000.0), "designed (first search, zero-set estimate)"),
    (6, -0.001, (0.59676, 1.0886, 1.4182, 4.3498, 99.289, 1e6), "limit k -> 0- optimum, l_6 = 1e6"),
    (6, -0.002, (0.55176, 1.0437, 1.3353, 3.3293, 46.148, 1e5), "limit k -> 0- optimum, l_6 = 1e5"),
    (5, -0.02, (0.71995, 1.2204, 1.7251, 8.1008, 1000.0), "designed (candidates by guaranteed c_upper)"),
    (6, -0.002, (0.59181, 1.0888, 1.4066, 4.3734, 99.27, 1e6), "designed (the first search's start)"),
]


def rounding():
    from ftstab_mj.control.interval import round_up

    x = np.random.default_rng(0).standard_normal(1_000_000)
    t_up, t_na = [], []
    for _ in range(15):
        for f, out in ((lambda: round_up(x), t_up), (lambda: np.nextafter(x, np.inf), t_na)):
            t = time.perf_counter()
            f()
            out.append((time.perf_counter() - t) / x.size * 1e9)
    ratio = np.array(t_na) / np.array(t_up)
    print(f"outward rounding per element: round_up {np.median(t_up):.2f} ns [{min(t_up):.2f}, {max(t_up):.2f}], "
          f"np.nextafter {np.median(t_na):.2f} ns [{min(t_na):.2f}, {max(t_na):.2f}]; "
          f"nextafter / round_up = {np.median(ratio):.1f} [{ratio.min():.1f}, {ratio.max():.1f}]")


_ONE = """
import json, sys, time
from ftstab_mj.control import HongController, certify
r, k, gains, budget = json.loads(sys.argv[1])
t = time.process_time()
c = certify(HongController(r, k, tuple(gains)), budget=budget)
print(json.dumps(dict(cpu=time.process_time() - t, status=c.status, c_lower=c.c_lower, c_upper=c.c_upper,
                      boxes=c.boxes)))
"""


def against(ref, rows, repeat, budget):
    """Each row in a fresh process of the reference tree (A) and of this one (B), alternating."""
    import json
    import os
    import subprocess

    here = str(Path(__file__).resolve().parents[1])
    print(f"A = {ref}, B = {here}; CPU s per row, median [range] of {repeat} alternated runs")
    print("| row | r | k | gains | A CPU s | B CPU s | A / B | A status, c_lower, boxes | B status, c_lower, boxes |")
    print("|---|---|---|---|---|---|---|---|---|")
    for i in rows:
        r, k, gains, origin = ROWS[i]
        out = {"A": [], "B": []}
        for _ in range(repeat):
            for side, tree in (("A", ref), ("B", here)):
                env = dict(os.environ, PYTHONPATH=tree, OPENBLAS_NUM_THREADS="1")
                res = subprocess.run([sys.executable, "-c", _ONE, json.dumps([r, k, list(gains), budget])],
                                     env=env, capture_output=True, text=True, check=True, cwd=tree)
                out[side].append(json.loads(res.stdout.splitlines()[-1]))
        cpu = {s: np.array([o["cpu"] for o in out[s]]) for s in out}
        med = {s: float(np.median(cpu[s])) for s in cpu}
        desc = {s: f"{out[s][-1]['status']}, {out[s][-1]['c_lower']:.6g}, {out[s][-1]['boxes']}" for s in out}
        print(f"| {i} | {r} | {k:g} | {', '.join(f'{g:g}' for g in gains)} | {med['A']:.2f} [{cpu['A'].min():.2f}, "
              f"{cpu['A'].max():.2f}] | {med['B']:.2f} [{cpu['B'].min():.2f}, {cpu['B'].max():.2f}] | "
              f"{med['A'] / med['B']:.2f} | {desc['A']} | {desc['B']} |", flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--budget", type=float, default=60.0, help="CPU seconds per row (default 60)")
    ap.add_argument("--rows", type=int, default=len(ROWS))
    ap.add_argument("--r", type=int, default=None, help="only the rows of this chain length")
    ap.add_argument("--no-soundness", action="store_true", help="skip the adversarial search")
    ap.add_argument("--rounding", action="store_true", help="only time one outward rounding against np.nextafter")
    ap.add_argument("--against", metavar="DIR", help="before/after: DIR is the reference source tree")
    ap.add_argument("--repeat", type=int, default=3, help="--against: alternated runs per row and side")
    ap.add_argument("--select", default=None, help="--against: comma-separated row numbers (default: all)")
    args = ap.parse_args()
    if args.against:
        rows = [int(x) for x in args.select.split(",")] if args.select else range(len(ROWS))
        return against(args.against, rows, args.repeat, args.budget)
    if args.rounding:
        return rounding()
    print("| r | k | gains | origin | status | c_lower | c_upper | gap | exact c (k = 0) | c'_upper | boxes | CPU s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    claims = []
    for r, k, gains, origin in ROWS[:args.rows]:
        if args.r is not None and r != args.r:
            continue
        hong = HongController(r, k, gains)
        t = time.process_time()
        cert = certify(hong, budget=args.budget)
        dt = time.process_time() - t
        gap = f"{100 * cert.gap:.2f} %" if cert.gap is not None and np.isfinite(cert.gap) else "-"
        ex = f"{exact_k0(gains):.6g}" if k == 0 else ""
        cp = f"{cert.c_prime_upper:.5g}" if cert.c_prime_upper is not None else "-"
        print(f"| {r} | {k:g} | {', '.join(f'{g:g}' for g in gains)} | {origin} | {cert.status} | {cert.c_lower:.6g} | "
              f"{cert.c_upper:.6g} | {gap} | {ex} | {cp} | {cert.boxes} | {dt:.2f} |", flush=True)
        if np.isfinite(cert.c_lower) and r >= 2:
            claims.append((hong, cert))
    if args.no_soundness:
        return
    rng = np.random.default_rng(0)
    worst, where = -np.inf, None
    for hong, cert in claims:
        found = _max_ratio_search(hong, cert.alpha, rng, starts=512, steps=100)
        margin = (found + cert.c_lower) / max(abs(cert.c_lower), 1e-12)
        if margin > worst:
            worst, where = margin, (hong.r, hong.k, hong.gains, cert.status)
    print(f"\nsoundness: {len(claims)} claims searched (512 starts, 100 ascent steps each); largest "
          f"(found + c_lower) / |c_lower| = {worst:.3g} at r = {where[0]}, k = {where[1]:g} ({where[3]})"
          + ("  VIOLATED" if worst > 1e-9 else ""))


if __name__ == "__main__":
    main()

"""The certificate on a table of gain sets, r = 1..6: CPU time, c_lower, c_upper, gap, status.

k = 0 rows also show the exact c (LITERATURE: c = 2 lambda_min(-(B + B^T)/2) in the backstepping
coordinates). Designed rows are ftstab design's gains. One core, CPU seconds (time.process_time),
one run per row (the B&B is deterministic; its time is what varies).

    python benchmarks/certificate_table.py [--budget S]
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_control_certificate import exact_k0  # noqa: E402

from ftstab_mj.control import HongController, certify  # noqa: E402

ROWS = [  # (r, k, gains, origin)
    (1, -0.3, (2.0,), "hand"),
    (2, -0.2, (1.0, 2.0), "NOTES table"),
    (2, -0.2, (6.8561, 100.0), "designed"),
    (2, 0.0, (46.407, 1e5), "k = 0, 4 decades"),
    (3, -0.1, (1.0, 1.7, 5.0), "NOTES table"),
    (3, -0.1, (1.0, 2.0, 3.0), "NOTES table (fails)"),
    (3, -0.1, (1.3957, 2.8557, 100.0), "designed"),
    (3, -0.02, (3.233, 46.004, 1e5), "5 decades"),
    (3, 0.0, (3.233, 46.004, 1e5), "k = 0, 5 decades"),
    (4, -0.05, (0.8246, 1.5017, 3.0841, 102.5134), "designed"),
    (4, 0.0, (1.08, 1.72, 4.46, 100.0), "k = 0"),
    (4, 0.0, (1.253, 3.042, 50.211, 1e5), "k = 0, 5 decades"),
    (4, -0.02, (1.253, 3.042, 50.211, 1e5), "5 decades"),
    (5, 0.0, (0.65, 1.2, 1.62, 12.63, 1000.0), "k = 0, 4 decades"),
    (5, 0.0, (0.993, 1.541, 3.158, 49.278, 1e5), "k = 0, 6 decades"),
    (5, -0.02, (0.65, 1.2, 1.62, 12.63, 1000.0), "4 decades"),
    (6, 0.0, (0.62, 1.15, 1.54, 3.88, 39.13, 1e5), "k = 0, 6 decades"),
    (6, -0.05, (0.62, 1.15, 1.54, 3.88, 39.13, 1e5), "6 decades"),
]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--budget", type=float, default=60.0, help="CPU seconds per row (default 60)")
    ap.add_argument("--rows", type=int, default=len(ROWS))
    args = ap.parse_args()
    print(f"| r | k | gains | origin | status | c_lower | c_upper | gap | exact c (k = 0) | c'_upper | boxes | CPU s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r, k, gains, origin in ROWS[:args.rows]:
        t = time.process_time()
        cert = certify(HongController(r, k, gains), budget=args.budget)
        dt = time.process_time() - t
        gap = f"{100 * cert.gap:.2f} %" if cert.gap is not None and np.isfinite(cert.gap) else "-"
        ex = f"{exact_k0(np.array(gains)):.6g}" if k == 0 else ""
        cp = f"{cert.c_prime_upper:.5g}" if cert.c_prime_upper is not None else "-"
        print(f"| {r} | {k:g} | {', '.join(f'{g:g}' for g in gains)} | {origin} | {cert.status} | {cert.c_lower:.6g} | "
              f"{cert.c_upper:.6g} | {gap} | {ex} | {cp} | {cert.boxes} | {dt:.2f} |", flush=True)


if __name__ == "__main__":
    main()

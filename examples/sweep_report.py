"""A sweep with its report: `ftstab sweep --report` on a shortened sweep (examples/sweep_period.toml).

The robust law on the cart at five control periods (0.5 to 8 ms): the state settles into a band
whose width max |x| over the last 1.5 s the sweep records, one table row per run, and the report
draws it against the period on log-log axes with its fitted slope (the file's [[report.plot]]).
This script runs the command and fits the table itself: with u held over the period h, the band is O(h).

The full sweep (r = 2 and 3, seven periods, 20 s): ftstab sweep robust_accuracy_vs_period --workers 2 --report
Run: python examples/sweep_report.py [--out DIR] [--workers N]
"""

import argparse
import csv
import subprocess
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
Y = "metrics.loops.cart.final_abs_z_max[0]"  # the table's column: max |z_1| over the final window


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="runs/sweep_period", help="where the table and the report go")
    ap.add_argument("--workers", default="1", help="parallel runs (default 1)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    # the same as typing: ftstab sweep examples/sweep_period.toml --out DIR --report --format csv
    subprocess.run([sys.executable, "-m", "ftstab_mj", "sweep", str(HERE / "sweep_period.toml"), "--out", str(out),
                    "--report", "--format", "csv", "--workers", args.workers], check=True)
    with open(out / "sweep_period.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    h = np.array([float(r["sim.period"]) for r in rows])
    acc = np.array([float(r[Y]) for r in rows])
    slope, _ = np.polyfit(np.log(h), np.log(acc), 1)
    print(f"max |x| over the last 1.5 s ~ h^{slope:.2f} over h = {h.min():g}..{h.max():g} s")
    return sorted((out / "report").glob("*.png"))


if __name__ == "__main__":
    main()

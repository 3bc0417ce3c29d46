"""Comparing laws: `ftstab compare` on a shortened comparison (examples/compare_laws.toml).

Five laws (the paper's robust and adaptive laws, Levant's quasi-continuous 2-sliding controller,
super-twisting, linear feedback) on the cart under the same sine disturbance and actuator gain, at
three control periods. The command prints the table, writes it (CSV, Parquet), the log-log slopes of
the final accuracy against the period, and two figures: DIR/compare_laws_time.png (u and |z1| of
every law at the shortest period) and DIR/compare_laws_accuracy.png (final accuracy against the
period). This script runs it and reads the slopes back: Levant's r-sliding accuracy |z1| = O(h^2).

The full comparison (9 laws x 4 periods, 10 s): ftstab compare scenarios/compare/cart_r2.toml --workers 2
Run: python examples/compare_laws.py [--out DIR] [--workers N]
"""

import argparse
import csv
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="runs/compare_laws", help="where the table and the figures go")
    ap.add_argument("--workers", default="1", help="parallel runs (default 1)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    # the same as typing: ftstab compare examples/compare_laws.toml --out DIR
    subprocess.run([sys.executable, "-m", "ftstab_mj", "compare", str(HERE / "compare_laws.toml"),
                    "--out", str(out), "--workers", args.workers], check=True)
    with open(out / "compare_laws_slopes.csv", newline="") as f:
        slopes = {row["label"]: row for row in csv.DictReader(f)}
    print(f"levant_qc: final |z1| ~ h^{float(slopes['levant_qc']['slope_z1']):.2f} "
          f"(Levant 2005: O(h^r) at r = 2)")
    return out / "compare_laws_time.png", out / "compare_laws_accuracy.png"


if __name__ == "__main__":
    main()

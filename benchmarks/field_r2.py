"""The field's comparison at full length: does every one of the six field laws converge on the cart?

    python -m benchmarks field_r2 [--workers 2] [--duration 10] [--out DIR] [--no-check]

Runs ``ftstab compare scenarios/compare/field_r2.toml`` (every law registered for r = 2, the cart,
phi = 0.8 sin(pi t) m/s^2, gamma in [0.8, 1.2], periods 0.5..4 ms) through the real CLI, then prints,
for the six field laws (twisting, terminal, fixed_time, adaptive_super_twisting, integral_hosm,
huang_adaptive), final |z_1| and the settling time at the shortest period. Exit 1 unless each of
them ends with final |z_1| <= 1e-2 m there (issue 40's criterion); ``--no-check`` only prints (the
suite runs it shortened that way). Minutes of CPU at full length (15 laws x 4 periods, most on the
Python path), hence a benchmark and not a test.
"""

from __future__ import annotations

import argparse
import csv
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FIELD = ("twisting", "terminal", "fixed_time", "adaptive_super_twisting", "integral_hosm", "huang_adaptive")
LEVEL = 1e-2  # m


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", default="1")
    ap.add_argument("--duration", type=float, default=None, help="sim.duration override, s (default: the file's 10 s)")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--no-check", action="store_true", help="print only, exit 0 whatever the accuracy")
    args = ap.parse_args(argv)
    out = args.out or Path(tempfile.mkdtemp(prefix="field_r2_"))
    cmd = [sys.executable, "-m", "ftstab_mj", "compare", str(ROOT / "scenarios" / "compare" / "field_r2.toml"),
           "--out", str(out), "--workers", str(args.workers)]
    if args.duration is not None:
        cmd += ["--set", f"sim.duration={args.duration}"]
    res = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    if res.returncode != 0:
        print(res.stderr, file=sys.stderr)
        return res.returncode
    with open(out / "field_r2.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    h = min(float(r["sim.period"]) for r in rows)
    ok = True
    print(f"field_r2 at the shortest period h = {h * 1e3:g} ms (criterion: final |z_1| <= {LEVEL:g} m)")
    print(f"{'law':26s} {'final |z_1| (m)':>16s} {'settle_time_z1 (s)':>19s}  converged")
    for law in FIELD:
        (row,) = [r for r in rows if r["label"] == law and float(r["sim.period"]) == h]
        z1 = float(row["final_abs_z1"])
        good = row["status"] == "completed" and z1 <= LEVEL
        ok &= good
        print(f"{law:26s} {z1:16.3g} {row['settle_time_z1'] or '-':>19s}  {'yes' if good else 'NO'}")
    print(f"table: {out / 'field_r2.csv'}")
    return 0 if ok or args.no_check else 1


if __name__ == "__main__":
    sys.exit(main())

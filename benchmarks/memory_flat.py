"""Peak RSS of `ftstab run` (both logs written) at 10, 100 and 1000 s simulated at 1 ms, each in a fresh
process: flat memory means the 1000 s run peaks at <= 1.2x the 10 s one (issue 16).

    python benchmarks/memory_flat.py [--scenario cart_r2_nominal] [--durations 10 100 1000]
"""

import argparse
import subprocess
import sys
import tempfile

CHILD = """
import resource, sys
from ftstab_mj.cli import main
code = main(sys.argv[1:])
print("PEAK_KB", resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr)
"""


def peak_mb(scenario: str, duration: float, out: str) -> float:
    args = [sys.executable, "-c", CHILD, "run", scenario, "--out", out, "--json", "--set", f"sim.duration={duration}",
            "--set", "sim.period=0.001", "--set", "sim.physics_step=0.001"]
    res = subprocess.run(args, capture_output=True, text=True, check=True)
    kb = [line.split()[1] for line in res.stderr.splitlines() if line.startswith("PEAK_KB")]
    return int(kb[-1]) / 1024


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="cart_r2_nominal")
    ap.add_argument("--durations", type=float, nargs="+", default=[10.0, 100.0, 1000.0])
    a = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for d in a.durations:
            rows.append((d, peak_mb(a.scenario, d, tmp)))
            print(f"{d:8g} s simulated ({int(d * 1000):>9,} samples): peak RSS {rows[-1][1]:7.1f} MB", flush=True)
    print(f"ratio {rows[-1][0]:g} s / {rows[0][0]:g} s: {rows[-1][1] / rows[0][1]:.2f} (target <= 1.2)")


if __name__ == "__main__":
    main()

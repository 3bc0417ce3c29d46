"""Peak RSS of `ftstab run` (both logs written) and of `ftstab replay` of the log it wrote, at 10, 100,
1000 and 10,000 s simulated at 1 ms (10^4 to 10^7 samples), each in a fresh process: flat memory means
the 1000 s run peaks at <= 1.2x the 10 s one (issue 16), the 10,000 s one likewise, and the replay
reads the log as it streams. The 10,000 s run takes ~1 min and writes 1.3 GB of logs (deleted after).

    python -m benchmarks memory_flat [--scenario cart_r2_nominal] [--durations 10 100 1000 10000] [--repeat 3]

Each repeat runs every duration (in alternating order: forward, then backward), then replays each log;
printed: per duration the median peak and the range over the repeats, and the ratio of each duration's
median to the first's with the range of the per-repeat ratios.
"""

import argparse
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # also as `python benchmarks/memory_flat.py`
from benchmarks._common import child_env  # noqa: E402

CHILD = """
import contextlib, os, resource, sys
from ftstab_mj.cli import main
with open(os.devnull, "w") as out, contextlib.redirect_stdout(out):
    code = main(sys.argv[1:])
print("PEAK_KB", resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr)
sys.exit(code)
"""


def peak_mb(argv: list) -> float:
    """Peak RSS (MB) of `ftstab ARGV` in a fresh process."""
    res = subprocess.run([sys.executable, "-c", CHILD, *argv], capture_output=True, text=True, env=child_env())
    if res.returncode != 0:
        raise SystemExit(f"ftstab {' '.join(argv)} failed (exit {res.returncode}): {res.stderr.strip()[-400:]}")
    kb = [line.split()[1] for line in res.stderr.splitlines() if line.startswith("PEAK_KB")]
    return int(kb[-1]) / 1024


def run_argv(scenario: str, duration: float, out: Path) -> list:
    return ["run", scenario, "--out", str(out), "--force", "--rrd", "--set", f"sim.duration={duration}",
            "--set", "sim.period=0.001", "--set", "sim.physics_step=0.001"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="cart_r2_nominal")
    ap.add_argument("--durations", type=float, nargs="+", default=[10.0, 100.0, 1000.0, 10000.0])
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    peaks = {(verb, d): [] for verb in ("run", "replay") for d in a.durations}
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(a.repeat):
            order = a.durations if k % 2 == 0 else a.durations[::-1]
            for d in order:
                out = Path(tmp) / f"{d:g}"
                peaks["run", d].append(peak_mb(run_argv(a.scenario, d, out)))
                log = next(out.glob("*.mcap"))
                peaks["replay", d].append(peak_mb(["replay", str(log)]))
                for f in out.iterdir():  # the 10,000 s logs are 1.3 GB
                    f.unlink()
            print(f"repeat {k + 1}: " + ", ".join(f"{v} {d:g} s {peaks[v, d][-1]:.1f} MB" for v in ("run", "replay")
                                                  for d in a.durations), flush=True)
    first = a.durations[0]
    print(f"\npeak RSS, median (range) of {a.repeat} repeats, {a.scenario} at 1 ms:")
    for verb in ("run", "replay"):
        cells = [f"{d:g} s ({int(d * 1000):,} samples): {statistics.median(peaks[verb, d]):.1f} MB "
                 f"({min(peaks[verb, d]):.1f}-{max(peaks[verb, d]):.1f})" for d in a.durations]
        print(f"  {verb:6s} " + "; ".join(cells))
        for last in a.durations[1:]:
            ratios = [b / f for f, b in zip(peaks[verb, first], peaks[verb, last])]
            ratio = statistics.median(peaks[verb, last]) / statistics.median(peaks[verb, first])
            print(f"  {verb:6s} ratio {last:g} s / {first:g} s: {ratio:.2f} (per repeat {min(ratios):.2f}-"
                  f"{max(ratios):.2f}; target <= 1.2)")


if __name__ == "__main__":
    main()

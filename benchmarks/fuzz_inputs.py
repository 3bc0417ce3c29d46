"""The long run of the input fuzzer (tests/fuzzing.py; the suite runs 200 cases of it).

    python -m benchmarks fuzz_inputs [--cases 20000] [--seed 0]

Mutated shipped scenarios and random --set texts through `ftstab run`'s main, in process. Prints the
number of cases, how they ended (exit code; "accepted, not run" for valid scenarios too long to run
here), the runs that diverged or failed (exit 1, allowed), and every failure of the contract
(another exit code, a traceback, more than one line for exit 2, a log left by a refused input).
Exit status 1 when there is a failure.
"""

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from fuzzing import fuzz  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=20000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    t0 = time.perf_counter()

    def progress(report, done):
        print(f"  {done} cases, {len(report.failures)} failures, {time.perf_counter() - t0:.0f} s", file=sys.stderr)

    with tempfile.TemporaryDirectory() as d:
        report = fuzz(args.seed, args.cases, Path(d), progress=progress)
    print(f"fuzz seed {args.seed}: {report.cases} cases in {time.perf_counter() - t0:.0f} s, "
          f"{report.runs} runs started, failures: {len(report.failures)}")
    print("  endings: " + ", ".join(f"{k}: {v}" for k, v in sorted(report.exits.items(), key=str)))
    for case, what in report.completed_badly:
        print(f"  exit 1 (diverged or failed run, allowed) case {case}: {'; '.join(what)}")
    for case, problem, what in report.failures:
        print(f"  FAILURE case {case}: {problem}\n    {'; '.join(what)}")
    return 1 if report.failures else 0


if __name__ == "__main__":
    sys.exit(main())

"""``ftstab replay``: a run's metrics recomputed from its log and compared with the recorded ones
(logs.recorded_metrics), optionally a Rerun recording of it and a bit-for-bit re-run (--verify)."""

from __future__ import annotations

import json
import sys

from ftstab_mj.cli.common import read_log, replayed_metrics, streamed_metrics, write_log_rrd

VERB = "replay"
ORDER = 30  # its place in `ftstab --help`


def add_parser(sub) -> None:
    rp = sub.add_parser("replay", help="recompute the metrics of a run from its MCAP log",
                        description="Read LOG.mcap (a truncated log up to its last complete chunk), recompute "
                                    "the metrics from the logged samples and compare them with the ones recorded "
                                    "at the end of the run (exit 1 if they differ, or if --verify finds a "
                                    "difference).")
    rp.add_argument("log", metavar="LOG.mcap")
    rp.add_argument("--json", action="store_true", help="print the metrics as JSON")
    rp.add_argument("--rrd", metavar="OUT.rrd", help="also write a Rerun recording of the log")
    rp.add_argument("--force", action="store_true",
                    help="let --rrd replace a file that is not an ftstab log (or a symbolic link)")
    rp.add_argument("--verify", action="store_true",
                    help="re-run the scenario recorded in the log and check that the samples are bit-identical "
                         "(within a few ulp per sample when the log was written on the other kernel path, "
                         "native or Python)")
    rp.set_defaults(func=handle)


def handle(args) -> int:
    from ftstab_mj.metrics.run_metrics import format_table

    if args.rrd:  # the recording needs the samples themselves
        log = read_log(args.log)
        metrics = replayed_metrics(log)
    else:
        log, metrics = streamed_metrics(args.log)
    diff, derived, moved = [], [], []
    if log.recorded and log.recorded.get("metrics"):  # a failed run records its status without metrics
        from ftstab_mj.logs.recorded_metrics import compare_recorded

        found = compare_recorded(log.recorded["metrics"], metrics)
        derived, moved = found.derived, found.moved
        diff = [f"  {k}: recorded {rec!r}, recomputed {now!r}" for k, rec, now in found.differ]
    if args.rrd:
        write_log_rrd(log, metrics, args.rrd, force=args.force)
    if args.json:
        print(json.dumps(metrics, indent=2, allow_nan=False))
    else:
        v = log.versions
        print(f"{args.log}: {log.n_samples} samples, {'complete' if log.complete else 'truncated'} log"
              f" (ftstab_mj {v.get('ftstab_mj', '?')}, MuJoCo {v.get('mujoco', '?')}, "
              f"{log.info.kernel or 'unrecorded'} kernel path)")
        print(format_table(metrics))
        if log.recorded is None:
            print("recorded metrics: none (the run did not finish); status taken as interrupted")
        elif not log.recorded.get("metrics"):
            print(f"recorded metrics: none (run {log.recorded['status']}: {log.recorded.get('message', '')})")
        elif not diff:
            print("recorded metrics: identical to the ones recomputed from the samples"
                  + (f", except {len(derived)} derived from the certificate, which this log recorded with a "
                     f"sampled estimate of c (recomputed with the guaranteed c_lower): {', '.join(derived)}"
                     if derived else "")
                  + (f", except {len(moved)} from the certificate, which another version of the branch and bound "
                     f"computed for this log (both brackets hold c; recomputed here): {', '.join(moved)}"
                     if moved else ""))
        if args.rrd:
            print(f"wrote {args.rrd}")
    failed = False
    if diff:
        print(f"{args.log}: metrics recomputed from the log differ from the recorded ones:", file=sys.stderr)
        print("\n".join(diff), file=sys.stderr)
        failed = True
    if args.verify:
        from ftstab_mj.scenario.run import verify_log
        from ftstab_mj.simulation.interrupts import interruption

        try:
            v = verify_log(log)
        except KeyboardInterrupt as exc:  # the re-run was stopped: nothing was compared, nothing differs
            stop = interruption(exc)
            print(f"{args.log}: verify {stop.label}: the re-run of the recorded scenario was stopped before "
                  "it could be compared with the log", file=sys.stderr)
            return stop.exit_code
        if v.ok:
            paths = None if v.paths is None else f"written on the {v.paths[0]} kernel path, re-run on the {v.paths[1]} one"
            if paths is None:
                same = "are bit-identical"
            elif v.worst == 0:  # across paths, yet the same operations gave the same bits
                same = f"are bit-identical ({paths})"
            else:
                same = (f"agree within the cross-path tolerance ({paths}; largest difference {v.worst:.2g} "
                        "of that tolerance)")
            print(f"verify: re-ran the recorded scenario: all {v.compared} logged values {same}",
                  file=sys.stderr if args.json else sys.stdout)
        else:
            print(f"{args.log}: verify failed: the re-run of the recorded scenario differs from the log:", file=sys.stderr)
            print("\n".join(f"  {p}" for p in v.problems), file=sys.stderr)
            failed = True
    return 1 if failed else 0


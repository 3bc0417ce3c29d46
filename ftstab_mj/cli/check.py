"""``ftstab check``: a log's metrics against pinned values and tolerances (metrics.expectations)."""

from __future__ import annotations

import os

from ftstab_mj.cli.common import UsageError, output_file, streamed_metrics

VERB = "check"
ORDER = 40  # its place in `ftstab --help`


def add_parser(sub) -> None:
    ck = sub.add_parser("check", help="compare a log's metrics with pinned values and tolerances",
                        description="Exit 0 when every expectation of EXPECT.toml holds for the metrics "
                                    "recomputed from LOG.mcap, 1 with the failing ones listed otherwise (or when the "
                                    "log has no samples to check them on). EXPECT.toml: one table per loop, "
                                    "metric = value with a tolerance; `--pin` writes one to start from "
                                    "(format: docs/logs.md, \"Replay and regression\").")
    ck.add_argument("log", metavar="LOG.mcap")
    what = ck.add_mutually_exclusive_group(required=True)
    what.add_argument("--expect", metavar="EXPECT.toml", help="the pinned metrics to compare with")
    what.add_argument("--pin", metavar="OUT.toml", help="write OUT.toml: this log's metrics with the default "
                                                       "tolerances, to check later runs")
    ck.set_defaults(func=handle)


def handle(args) -> int:
    from ftstab_mj.metrics.expectations import (
        PIN_HEADER,
        ExpectationError,
        check_metrics,
        load_expectations,
        pin_expectations,
        to_toml,
    )

    if args.pin:
        output_file(args.pin, f"--pin {args.pin}")  # before the log is read
        log, metrics = streamed_metrics(args.log)
        source = (f"Pinned from {os.path.basename(args.log)}: scenario {log.info.scenario.get('name', '?')}, "
                  f"{metrics['duration']:g} s, control period {log.info.period:g} s.")
        text = to_toml(pin_expectations(metrics, log.info), PIN_HEADER + "\n" + source)
        try:
            with open(args.pin, "w") as f:
                f.write(text)
        except OSError as exc:
            raise UsageError(f"--pin {args.pin}: cannot write the expectation file ({exc.strerror})") from None
        print(f"wrote {args.pin}: the metrics of {args.log} with the default tolerances")
        return 0
    expected = load_expectations(args.expect)
    log, metrics = streamed_metrics(args.log)
    try:
        outcomes = check_metrics(metrics, expected, source=args.expect)
    except ExpectationError as exc:
        if log.n_samples or exc.found != "no such metric":
            raise
        # a log without samples has no per-sample metrics: say so rather than blame the expectations
        run = f"run {log.recorded['status']}: {log.recorded.get('message') or 'no message'}" if log.recorded \
            else "the run did not finish writing it"
        print(f"{args.log}: the log has no samples ({run}), so {exc.path} of {args.expect} cannot be checked; "
              f"{len(log.loops)} loop(s), 0 samples each")
        return 1
    failed = [o for o in outcomes if not o.ok]
    if not failed:
        print(f"{args.log}: all {len(outcomes)} expectations of {args.expect} hold")
        return 0
    print(f"{args.log}: {len(failed)} of {len(outcomes)} expectations of {args.expect} failed:")
    for o in failed:
        print(f"  {o.line}")
    return 1

"""``ftstab sweep``: many runs of a base scenario (studies.sweep)."""

from __future__ import annotations

import sys

from ftstab_mj.cli.common import header, output_dir, workers

VERB = "sweep"
ORDER = 80  # its place in `ftstab --help`


def add_parser(sub) -> None:
    w = sub.add_parser(
        "sweep", help="run a sweep file: many runs of a base scenario, serially, on local processes or on Dask",
        description="Run every parameter set of SWEEP (grids and seeded Monte Carlo draws over a base "
                    "scenario), write one table of parameters + metrics per run to DIR/<name>.parquet "
                    "(or .csv). A failed run is a row with its error; an interrupted sweep goes on with "
                    "--resume. The table does not depend on the engine or the number of workers. "
                    "Exit 0 when every run is in the table, 1 when runs were lost by dead workers, "
                    "130 when interrupted, 2 on bad input.",
        epilog="example: ftstab sweep scenarios/sweeps/robust_accuracy_vs_period.toml --workers 2 --report")
    w.add_argument("sweep", help="sweep file (.toml) or shipped sweep name (scenarios/sweeps/<name>.toml)")
    w.add_argument("--workers", type=workers, default=1, metavar="N",
                   help="parallel runs (default 1: serial; 'all': one per core); N > 1 starts N local worker "
                        "processes")
    w.add_argument("--engine", choices=("serial", "batch", "processes", "dask"),
                   help="serial, batch (N threads of this process; runs on the native kernel step at once, "
                        "the others one at a time), processes (a local process pool) or dask (a local Dask "
                        "cluster of N processes, or --scheduler's); default: processes when N > 1, dask with "
                        "--scheduler")
    w.add_argument("--scheduler", metavar="ADDRESS",
                   help="a running Dask scheduler (tcp://host:8786) instead of local workers (implies --engine dask); "
                        "its workers need ftstab_mj installed")
    w.add_argument("--out", metavar="DIR", help="output directory (default: runs/<sweep name>)")
    w.add_argument("--resume", action="store_true", help="continue the sweep in DIR: run only the rows not in its table")
    w.add_argument("--set", action="append", default=[], metavar="KEY.PATH=VALUE",
                   help="override a field of the base scenario for every run (repeatable), e.g. sim.duration=1")
    w.add_argument("--format", choices=("parquet", "csv"), default="parquet", help="table format (default parquet)")
    w.add_argument("--logs", action="store_true", help="also write each run's MCAP log, DIR/logs/rowNNNNN.mcap "
                                                          "(`ftstab view` makes its Rerun recording)")
    w.add_argument("--report", action="store_true",
                   help="draw the sweep file's [[report.plot]] figures into DIR/report/ (PNG) and print the fits")
    w.set_defaults(func=handle)


def handle(args) -> int:
    from ftstab_mj.studies.sweep.engine import choose_engine

    engine = choose_engine(args.engine, args.workers, args.scheduler)
    if engine == "dask" and not args.scheduler and not args.resume:  # as engine.started_ahead below
        from ftstab_mj.studies.batch_env import start_forkserver

        start_forkserver()  # the local cluster's workers' imports, made beside this process's own
    from pathlib import Path

    from ftstab_mj.scenario.shipped import find_sweep
    from ftstab_mj.studies.sweep import expand, load_sweep, run_sweep
    from ftstab_mj.studies.sweep.engine import started_ahead
    from ftstab_mj.studies.sweep.row import prepare

    sweep = load_sweep(find_sweep(args.sweep))
    rows = expand(sweep)
    out = output_dir(args.out or Path("runs") / sweep.name, f"--out {args.out}" if args.out else "the output",
                     make=False)  # made by the sweep once every row is checked
    # a Dask cluster starts while the rows are checked; not for --resume, which may have nothing left to run
    with started_ahead("serial" if args.resume else engine, args.workers, args.scheduler) as ahead:
        # every input check, every row validated, before any run or file
        task, identity = prepare(sweep, rows, args.set, out / "logs" if args.logs else None)
        print(header(sweep.name, sweep.description, args.set))
        print(f"  base {sweep.scenario}, {len(rows)} runs -> {out}")
        outcome = run_sweep(sweep.name, rows, task, out, identity, engine=engine, workers=args.workers,
                            scheduler=args.scheduler, resume=args.resume, fmt=args.format, ahead=ahead)
    counts = ", ".join(f"{n} {s}" for s, n in sorted(outcome.statuses.items()))
    own = f" ({outcome.rows_wall_s:.2f} s from the first run's start to the table)" if outcome.ran else ""
    print(f"{outcome.done}/{outcome.total} runs in the table ({counts}); "
          f"{outcome.ran} ran now in {outcome.elapsed_s:.2f} s{own}")
    print(f"table: {outcome.table}")
    if args.report and outcome.done:
        from ftstab_mj.figures.sweep_report import make_report

        paths, fits = make_report(sweep, outcome.table, out / "report")
        for path in paths:
            print(f"figure: {path}")
        for fit in fits:
            if fit.power_law:
                print(f"log-log slope in {fit.plot}, {fit.series}: {fit.slope:.3f} ({fit.points} points, "
                      f"r^2 = {fit.r2:.4f})")
            else:
                print(f"no log-log slope in {fit.plot}, {fit.series}: {fit.why_not}")
    if outcome.interrupted:
        return outcome.interrupted_code
    if outcome.lost:
        print(f"error: {len(outcome.lost)} run(s) lost by dead workers (rows {', '.join(map(str, outcome.lost))});"
              f" --resume runs them", file=sys.stderr)
        return 1
    return 0

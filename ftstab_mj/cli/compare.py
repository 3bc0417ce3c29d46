"""``ftstab compare``: several control laws on one base scenario (studies.compare)."""

from __future__ import annotations

import sys

from ftstab_mj.cli.common import header, output_dir, workers

VERB = "compare"
ORDER = 100  # its place in `ftstab --help`


def add_parser(sub) -> None:
    cp = sub.add_parser(
        "compare", help="several control laws on one base scenario, side by side (table and figures)",
        description="Run every law of COMPARISON (whole controller tables) on its base scenario, at every "
                    "value of its optional grid (control period or disturbance amplitude); print one table "
                    "(laws as rows: settling time, final accuracy per z_i, effort, max |u|, chattering "
                    "indices, bound beaten; wrapped to 100 columns, effort and three chattering indices left to the "
                    "files), write it to DIR/<name>.csv, .parquet (every column) and .md, the log-log slopes "
                    "of the accuracy against the period to DIR/<name>_slopes.csv, and the figures "
                    "DIR/<name>_accuracy.png and DIR/<name>_time.png. Exit 0 when every run is in the "
                    "table (a diverged run is a row with its status), 2 on bad input.",
        epilog="example: ftstab compare cart_r2 --workers 2 (= scenarios/compare/cart_r2.toml)")
    cp.add_argument("comparison", help="comparison file (.toml) or shipped comparison name (scenarios/compare/)")
    cp.add_argument("--workers", type=workers, default=1, metavar="N",
                    help="parallel runs on a local process pool (default 1: serial; 'all': one per core)")
    cp.add_argument("--engine", choices=("serial", "batch", "processes"),
                    help="serial, batch (N threads of this process, as for ftstab sweep) or processes "
                         "(default: processes when N > 1)")
    cp.add_argument("--out", metavar="DIR", help="output directory (default: runs/<name>)")
    cp.add_argument("--set", action="append", default=[], metavar="KEY.PATH=VALUE",
                    help="override a field of the base scenario for every run (repeatable), e.g. sim.duration=1")
    cp.set_defaults(func=handle)


def handle(args) -> int:
    from pathlib import Path

    from ftstab_mj.studies import compare
    from ftstab_mj.studies.sweep.engine import execute
    from ftstab_mj.studies.sweep.table import write_table

    cmp = compare.load_comparison(compare.find_comparison(args.comparison))
    task, items = compare.prepare(cmp, args.set)  # every row validated before any run
    engine = compare.engine_for(args.workers, args.engine)
    out = output_dir(args.out or Path("runs") / cmp.name, f"--out {args.out}" if args.out else "the output")
    print(header(cmp.name, cmp.description, args.set))
    print(f"  base {cmp.scenario}, {len(cmp.laws)} laws x {max(1, len(cmp.grid))} -> {len(items)} runs -> {out}")
    results = dict(execute(items, task, engine, args.workers))
    rows, series, columns = compare.assemble(cmp, task, items, results)
    keep = 2 if cmp.grid_path else 1  # each wrapped block repeats the label and the grid value
    print(compare.format_rows(rows, compare.terminal_columns(columns), compare.TERMINAL_WIDTH, keep))
    paths = [compare.write_csv(rows, out / f"{cmp.name}.csv"), write_table(rows, out / f"{cmp.name}.parquet")]
    sections = [("runs", rows, columns)]
    if cmp.grid_path and len(cmp.grid) >= 2:
        slopes = compare.fit_slopes(rows, cmp.grid_path)
        print(f"log-log slopes of max |z_i| against {cmp.grid_path} ({len(cmp.grid)} values):")
        print(compare.format_rows(slopes, list(slopes[0]), compare.TERMINAL_WIDTH))
        paths.append(compare.write_csv(slopes, out / f"{cmp.name}_slopes.csv"))
        sections.append((f"log-log slopes of max |z_i| against {cmp.grid_path}", slopes, list(slopes[0])))
    paths.append(compare.write_markdown(sections, out / f"{cmp.name}.md", f"{cmp.name}: {cmp.description}"))
    from ftstab_mj.figures.compare_report import draw_figures

    where = f" at {cmp.grid_path} = {cmp.grid[0]:g}" if cmp.grid_path else ""
    paths += draw_figures(cmp.name, rows, cmp.grid_path, cmp.grid, series, out, where)
    for path in paths:
        print(f"wrote {path}")
    lost = compare.lost_line(rows)  # rows lost by dead workers are an error, not a quiet 'lost' cell
    if lost:
        print(lost, file=sys.stderr)
    return 1 if lost else 0

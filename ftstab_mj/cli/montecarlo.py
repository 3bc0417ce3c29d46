"""``ftstab montecarlo``: Theorem 1's time bound on many initial states (studies.montecarlo)."""

from __future__ import annotations

import math
import sys

from ftstab_mj.cli.common import floats, number_in, output_dir, workers

VERB = "montecarlo"
ORDER = 90  # its place in `ftstab --help`


def add_parser(sub) -> None:
    mc = sub.add_parser(
        "montecarlo", help="Theorem 1's time bound checked on many initial states (per-trajectory metrics only)",
        description="Draw N initial states of one loop of SCENARIO uniformly in a box, run each (on the ideal "
                    "chain with the native kernel, or on the plant through the sweep engines), keep only "
                    "per-trajectory metrics (settling time, T(z0), their ratio, V1 at the end, max |u|) and report "
                    "the distribution of settle time / T(z0) and the worst case. Writes DIR/montecarlo.parquet, "
                    ".json and .png.",
        epilog="example: ftstab montecarlo cart_r2_nominal --states 10000 --box 1,1 --set sim.duration=8")
    mc.add_argument("scenario", help="scenario file (.toml) or shipped scenario name")
    mc.add_argument("--states", type=int, required=True, metavar="N", help="number of initial states")
    mc.add_argument("--box", type=floats, metavar="A1,...,AR",
                    help="half-widths of the box of z0 (chain units; default: max |z0_i| of the scenario on every axis)")
    mc.add_argument("--seed", type=number_in(0, 2 ** 63 - 1, int), default=0,
                    help="seed of the draw of initial states (default 0)")
    mc.add_argument("--loop", help="the loop whose z0 is drawn (default: the first)")
    mc.add_argument("--on", choices=("chain", "plant"), default=None,
                    help="chain: the loop on the exact ideal chain (ideal-chain scenarios, carts without friction or damping); "
                         "plant: runs of the scenario itself, like ftstab run (default: chain where the loop has that "
                         "exact twin and no --workers/--engine/--scheduler is given, else plant)")
    mc.add_argument("--workers", type=workers, default=1, metavar="N", help="plant: parallel runs")
    mc.add_argument("--engine", choices=("serial", "batch", "processes", "dask"),
                    help="plant: the sweep engine, as for ftstab sweep (default: processes when N > 1, dask with "
                         "--scheduler)")
    mc.add_argument("--scheduler", metavar="ADDRESS", help="plant: a running Dask scheduler (implies --engine dask)")
    mc.add_argument("--set", action="append", default=[], metavar="KEY.PATH=VALUE", help="override a field (repeatable)")
    mc.add_argument("--out", metavar="DIR", help="output directory (default: runs/<scenario>-montecarlo)")
    mc.add_argument("--json", action="store_true", help="print the summary as JSON")
    mc.set_defaults(func=handle)


def handle(args) -> int:
    from pathlib import Path

    from ftstab_mj.scenario import find_scenario, load_scenario
    from ftstab_mj.studies import montecarlo as mc
    from ftstab_mj.studies.compare import lost_line
    from ftstab_mj.studies.sweep.run import Progress
    from ftstab_mj.studies.sweep.table import write_table

    path = find_scenario(args.scenario)
    sc = load_scenario(path, args.set)
    loop, box, on = mc.plan(sc, args.loop, args.states, args.box, args.on, args.workers, args.engine, args.scheduler)
    Z0 = mc.Distribution(args.states, tuple(box), args.seed).draw()
    out = output_dir(args.out or Path("runs") / f"{sc.name}-montecarlo", f"--out {args.out}" if args.out else "the output")
    shown = Progress(sys.stderr, args.states, unit="states")  # a status line on a terminal, else silent

    def progress(done, total):
        shown.step(count=done - shown.ran)

    say = (lambda *a, **k: None) if args.json else print
    say(f"{sc.name}: {args.states} initial states uniform in |z_i| <= ({', '.join(f'{b:g}' for b in box)}), "
        f"seed {args.seed}, on the {'ideal chain' if on == 'chain' else 'plant ' + sc.plant.model}")
    rows, applies = mc.run_on(on, sc, path, args.set, loop, Z0, args.engine, args.workers, args.scheduler,
                              progress)
    shown.close()
    summary = mc.summarize(rows, applies, sc.sim.duration)
    applies = summary["bound_applies"]  # not where V1(z0) overflows
    write_table(rows, out / "montecarlo.parquet")
    (out / "montecarlo.json").write_text(mc.json_text(summary) + "\n")
    mc.figure(rows, summary, f"{sc.name}: settle time / T(z0)", out / "montecarlo.png")
    lost = lost_line(rows, "state")  # states lost by dead workers are an error
    if lost:
        print(lost, file=sys.stderr)
    if args.json:
        print(mc.json_text(summary))
        return 1 if lost else 0
    q = summary["ratio"]
    print(f"  settled {summary['settled']}/{summary['states']}; with a time bound {summary['with_bound']}"
          f" (bound {'applies' if applies else 'does not apply'})")
    if summary["bound_note"]:
        print(f"  note: {summary['bound_note']}")
    if q["median"] is not None:
        print(f"  settle time / T(z0): min {q['min']:.3g}, median {q['median']:.3g}, p99 {q['p99']:.3g}, max {q['max']:.3g}")
    if summary["violations"] is not None:
        print(f"  states beyond their bound: {summary['violations']}")
    if summary["unsettled_bound_beyond"]:
        print(f"  not settled by the end of the run ({sc.sim.duration:g} s): {summary['unsettled_bound_beyond']}, "
              f"each with its T(z0) beyond it (no claim either way; --set sim.duration={math.ceil(summary['longest_bound']):d} "
              f"to see them settle)")
    if summary["worst"]:
        w = summary["worst"]
        print(f"  worst: state {w['row']}, z0 = [{', '.join(f'{x:.17g}' for x in w['z0'])}],"
              f" settle time {w['settle_time']:.6g} s, T(z0) {w['time_bound']:.6g} s")
    print(f"table: {out / 'montecarlo.parquet'}  summary: {out / 'montecarlo.json'}  figure: {out / 'montecarlo.png'}")
    return 1 if lost else 0

"""``ftstab report``: the figures of one run (figures.run_report)."""

from __future__ import annotations

from ftstab_mj.cli.common import read_log

VERB = "report"
ORDER = 50  # its place in `ftstab --help`


def add_parser(sub) -> None:
    rt = sub.add_parser("report", help="the figures of one run for a paper (PNG or self-contained HTML)",
                        description="Draw from LOG.mcap, per loop: each z_i, u (and u0), V1 on a log axis with the "
                                    "settle level and Theorem 1's envelope and T(z0) (nominal and robust laws with a "
                                    "certificate), phi_hat and gamma_hat with Theorem 3's bounds (adaptive law); "
                                    "axes in their units. FIG.html embeds the PNG (no network needed). What each "
                                    "panel holds: ftstab_mj/figures/run_report.py. Exit 2 on a log that cannot be read.")
    rt.add_argument("log", metavar="LOG.mcap")
    rt.add_argument("--out", required=True, metavar="FIG.png|FIG.html", help="the figure to write")
    rt.set_defaults(func=handle)


def handle(args) -> int:
    from ftstab_mj.figures.run_report import check_out, report_data, write_report

    check_out(args.out)  # a bad file name before the log is read
    rep = report_data(read_log(args.log))
    write_report(rep, args.out)
    panels = sum(len(p) for p in rep.loops.values())
    print(f"wrote {args.out}: {rep.title.replace(chr(10), ', ')}; {len(rep.loops)} loop(s), {panels} panels")
    return 0

"""``ftstab run``: run a scenario, write its logs (logs.run_logs), print its metrics; live viewing."""

from __future__ import annotations

import argparse
import json
import sys

from ftstab_mj.cli.common import UsageError, end_progress, header, host_port, port, progress_line
from ftstab_mj.config.errors import CallbackError, LogWriteError

VERB = "run"
ORDER = 60  # its place in `ftstab --help`


def add_parser(sub) -> None:
    r = sub.add_parser(
        "run", help="run a scenario file, write its logs, print its metrics",
        description="Run SCENARIO (a .toml file, or the name of a shipped scenario: see `ftstab list`), "
                    "write DIR/<name>.mcap (Foxglove, replay; `ftstab view` makes a Rerun recording of it) and, "
                    "with --rrd, DIR/<name>.rrd (Rerun), print the metrics. "
                    "Exit 0 when the run completed (converged or not: convergence is a metric), "
                    "1 when it diverged or failed, 130 when interrupted (Ctrl-C), 2 on bad input.",
        epilog="example: ftstab run scenarios/cart_r2_robust.toml --out runs --set sim.duration=2")
    r.add_argument("scenario", help="scenario file (.toml) or shipped scenario name")
    r.add_argument("--out", default="runs", metavar="DIR", help="directory of the logs (default: runs)")
    r.add_argument("--set", action="append", default=[], metavar="KEY.PATH=VALUE",
                   help="override one field, validated like the file (repeatable), e.g. sim.duration=2 "
                        "or loops.cart.controller.gains[1]=3")
    r.add_argument("--rrd", action="store_true",
                   help="also write DIR/<name>.rrd, the Rerun recording, as the run goes (costs more CPU than the "
                        "physics; `ftstab view DIR/<name>.mcap` makes the same one afterwards)")
    r.add_argument("--json", action="store_true",
                   help="print the metrics as JSON (the /metrics message of the log) instead of the table")
    r.add_argument("--force", action="store_true",
                   help="replace DIR/<name>.mcap/.rrd even when they are not ftstab logs (another program's "
                        "file, a symbolic link: the link is replaced, never written through)")
    view = r.add_argument_group("live view (the logs are written the same way meanwhile)")
    view.add_argument("--live", nargs="?", const="auto", type=_live_target, metavar="spawn|serve|URL",
                      help="stream the run to a Rerun viewer as it happens: a native viewer when there is a "
                           "display, else `serve` (a `rerun --serve-web` server: a web viewer on --web-port, "
                           "gRPC on --grpc-port, kept after the run); or a rerun+http:// URL to stream to")
    view.add_argument("--grpc-port", type=port, default=9876, metavar="PORT",
                      help="the Rerun viewer's or server's gRPC port (default 9876)")
    view.add_argument("--web-port", type=port, default=9090, metavar="PORT",
                      help="--live serve: the web viewer's HTTP port (default 9090)")
    view.add_argument("--foxglove", nargs="?", const=("127.0.0.1", 8765), type=host_port, metavar="[HOST:]PORT",
                      help="serve the run to Foxglove (WebSocket) as it happens, the MCAP log's channels "
                           "and messages (default 127.0.0.1:8765; port 0: any free one, printed)")
    view.add_argument("--realtime", action="store_true",
                      help="pace the run to the wall clock (sim time follows wall time; prints the lag)")
    r.set_defaults(func=handle)


def handle(args) -> int:
    from ftstab_mj.scenario import find_scenario, load_scenario
    from ftstab_mj.scenario.run import ProgressSink, run_scenario
    from ftstab_mj.simulation import interrupts

    path = find_scenario(args.scenario)
    if not path.exists() and not (path.suffix or "/" in args.scenario):  # a name, not a path: the loader says the rest
        raise UsageError(f"run {args.scenario}: expected a scenario file (.toml) or the name of a shipped "
                         "scenario, found neither (`ftstab list` shows the shipped ones)")
    sc = load_scenario(path, args.set)  # every check happens here, before any file
    from ftstab_mj.logs.run_logs import open_run_logs
    from ftstab_mj.metrics.run_metrics import format_table

    run_logs = open_run_logs(args.out, sc.name, force=args.force, what=f"--out {args.out}",  # the paths checked
                             rrd=args.rrd)
    paths = run_logs.paths
    say = (lambda *a, **k: None) if args.json else print  # --json: stdout carries the JSON only
    say(header(sc.name, sc.description, args.set))
    say(f"  plant {sc.plant.model}, {len(sc.loops)} loop(s) ({', '.join(lp.controller.law for lp in sc.loops)}),"
        f" {sc.sim.duration:g} s, control period {sc.sim.period * 1e3:g} ms,"
        f" physics step {sc.sim.physics_step * 1e3:g} ms ({sc.sim.integrator}), seed {sc.seed}")
    if sc.plant.model.endswith(".xml"):  # what the testbed made of a user's model (a saturation kept, ...)
        from ftstab_mj.plants import make_plant

        for note in make_plant(sc.plant.model, sc.plant.params).notes:
            print(f"note: {note}", file=sys.stderr)
    live = _live_view(args)  # servers started (or refused in one line) before any log exists
    logs = run_logs.sinks(live, grpc_port=args.grpc_port)
    sinks = (*logs, ProgressSink(sc.name, sc.sim.duration))

    def logs_say(status: str) -> str:
        """What the logs record, as far as each could be closed (never more)."""
        closed = [str(p) for p, s in zip(paths, logs) if s.closed_status == status]
        cut = [str(p) for p, s in zip(paths, logs) if s.closed_status != status and p.exists()]
        absent = [str(p) for p, s in zip(paths, logs) if s.closed_status != status and not p.exists()]
        said = [f"logs closed with status {status}: {', '.join(closed)}" if closed else "no log could be closed"]
        said += [f"{p} ends at its last complete batch, without a status" for p in cut]
        said += [f"{p} was not written" for p in absent]
        return "; ".join(said)

    # one scope for the run and its report, the command's last run: a signal once the run is over
    # waits until the command ends, so the exit code is the one of the status the logs record
    with interrupts.run_scope(final=True):
        try:  # the pacer first: the logs and viewers get each batch when the clock has reached it
            say_certificate = progress_line()  # on a terminal, while a loop's certificate is computed
            try:
                run = run_scenario(sc, (*live.sinks(), *sinks), batch_size=live.batch_size(sc.sim.period),
                                   progress=say_certificate)
            finally:
                end_progress(say_certificate)
        except (CallbackError, LogWriteError) as exc:  # the controller raised, or a log could not be written
            print(f"error: run failed: {exc} ({logs_say('failed')})", file=sys.stderr)
            return 1
        except MemoryError:  # the run loop closed the logs as "failed" before this came out of it
            print(f"error: run failed: out of memory ({logs_say('failed')})", file=sys.stderr)
            return 1
        finally:
            live.stop()
        if args.json:
            print(json.dumps(run.metrics, indent=2))
        else:
            print(format_table(run.metrics))
            print(f"logs: {'  '.join(map(str, paths))}")
            if run_logs.rrd is None:
                print(f"look: ftstab view {paths[0]}  (Rerun: the plant in 3D and every logged signal)")
        status = run.result.status
        if status == "completed":
            return 0
        stop = (interrupts.last_signal() or interrupts.Interrupted()) if status == "interrupted" else None
        says = ("the logs say so and hold the samples up to there" if all(s.closed_status == status for s in logs)
                else logs_say(status))
        print(f"error: run {stop.label if stop else status}: {run.result.message} ({says})", file=sys.stderr)
        return stop.exit_code if stop else 1


def _live_view(args):
    """The live viewing a run asks for (logs/live.LiveView); a server that cannot start: one line, exit 2."""
    from ftstab_mj.logs.live import LiveView

    try:
        return LiveView(args.live, args.foxglove, args.realtime, grpc_port=args.grpc_port, web_port=args.web_port)
    except OSError as exc:  # the Foxglove server's port in use, or an address not of this host
        host, port = args.foxglove
        raise UsageError(f"--foxglove {host}:{port}: expected an address to serve on, found {exc.strerror}") from None


def _live_target(text: str) -> str:
    """--live's value, checked while parsing (logs/live.rerun_target) so that a scenario name taken by
    --live (``--live NAME`` before the scenario) or a typo is one line, before any log exists."""
    from ftstab_mj.logs.live import rerun_target
    try:
        rerun_target(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"{exc} (write --live after the scenario name)") from None
    return text

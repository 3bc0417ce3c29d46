"""Layer 10, the command line: the ``ftstab`` command. Exit codes: 0 success, 1 a check failed, 2 bad input (one line, no traceback).

May import: every layer below.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys

from ftstab_mj.config.errors import CallbackError, FtstabError, LogWriteError


class UsageError(FtstabError, ValueError):
    """Bad command-line input; reported as one line with exit code 2."""


class _Parser(argparse.ArgumentParser):
    """argparse that reports errors as one line and exit code 2 (argparse's own code for usage)."""

    def error(self, message):  # noqa: D401 - argparse API
        raise UsageError(f"{self.prog}: {message}")


def _gains(text: str) -> tuple[float, ...]:
    try:
        gains = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers like 1,2, got {text!r}") from None
    for i, g in enumerate(gains):
        if not GAIN_MIN <= g <= GAIN_MAX:  # also refuses nan and inf
            raise argparse.ArgumentTypeError(f"expected every gain in [{GAIN_MIN:g}, {GAIN_MAX:g}], "
                                             f"found l_{i + 1} = {g!r}")
    return gains


GAIN_MIN, GAIN_MAX = 1e-3, 1e6  # certify/design: gains the interval bounds stay meaningful for


def _number_in(lo, hi, kind=float, what=""):
    """An argparse type: a number of ``kind`` in [lo, hi] (inclusive), with a one-line error."""
    def parse(text):
        try:
            x = kind(text)
        except ValueError:
            x = None
        if x is None or not lo <= x <= hi:
            fmt = str if kind is int else (lambda v: f"{v:g}")
            raise argparse.ArgumentTypeError(f"expected {'an integer' if kind is int else 'a number'} in "
                                             f"[{fmt(lo)}, {fmt(hi)}]{what}, got {text!r}")
        return x
    return parse


def _json_safe(x):
    """Non-finite floats as null (strict JSON), recursively."""
    if isinstance(x, float):
        return x if x == x and abs(x) != float("inf") else None
    if isinstance(x, dict):
        return {k: _json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_safe(v) for v in x]
    return x


def _header(name: str, description: str, sets) -> str:
    """"name: description", and when --set changed the file, a second line saying that the description
    was written for the file and what changed (it may no longer hold: a duration, a bound, a law)."""
    if not sets:
        return f"{name}: {description}"
    keys = ", ".join(dict.fromkeys(text.split("=", 1)[0].strip() for text in sets))  # (validated by now)
    return (f"{name}: {description}\n  (description possibly stale: written for the file, before --set {keys})")


def _progress_line():
    """A callback that rewrites one status line on stderr when it is a terminal (else None)."""
    if not sys.stderr.isatty():
        return None

    def say(text):
        print(f"\r\033[K{text}", end="", file=sys.stderr, flush=True)
    return say


def _end_progress(say):
    if say is not None:
        print("\r\033[K", end="", file=sys.stderr, flush=True)


def cmd_certify(args) -> int:
    from ftstab_mj.control import HongController, certify

    hong = HongController(args.r, args.k, args.gains, form=args.form)
    say = None if args.json else _progress_line()
    inner, outer = args.region
    try:
        cert = certify(hong, samples=args.samples, seed=args.seed, budget=args.budget, progress=say,
                       region_radius=outer, region_inner=inner)
    finally:
        _end_progress(say)
    if args.json:
        d = cert.to_dict()
        d["gap"] = cert.gap
        print(json.dumps(_json_safe(d), indent=2, allow_nan=False))
        return 0
    print(_certificate_text(hong, cert))
    return 0


def _certificate_text(hong, cert) -> str:
    lines = [f"form {cert.form}, r = {hong.r}, k = {hong.k:g}, gains = {', '.join(f'{g:g}' for g in hong.gains)}"]
    if cert.form == "full":
        gap = f"gap {100 * cert.gap:.2g} %" if cert.gap is not None and cert.gap == cert.gap else "no lower bound"
        lines.append(f"  status: {cert.status}   (c_lower > 0 proven: certified; a state with dV1/dt >= 0: not certified)")
        lines.append(f"  c       = {cert.c_lower:.6g}    (guaranteed: c >= c_lower; best witness c <= {cert.c_upper:.6g}, "
                     f"{gap})   alpha  = {cert.alpha:.6g}   (dV1/dt <= -c V1^alpha)")
        if cert.c_prime_upper is not None:
            lines.append(f"  c'      = {cert.c_prime_upper:.6g}    (guaranteed upper bound)   alpha' = {cert.alpha_prime:.6g}"
                         f"   (|dV1/dz_r| <= c' V1^alpha')")
        lines.append(f"  witness on V1 = 1: z = ({', '.join(f'{x:.6g}' for x in cert.witness)})")
    else:
        neg = {True: "negative (proven)", False: "NOT negative (witness below)", None: "undecided"}[cert.region_negative]
        lines.append(f"  dV1/dt on {cert.region_inner:g} <= |z|_inf <= {cert.region_radius:g}: {neg}")
        if cert.witness is not None:
            lines.append(f"  witness: z = ({', '.join(f'{x:.6g}' for x in cert.witness)}), dV1/dt >= {cert.region_max_dV1dt:.6g}")
    lines.append(f"  {cert.boxes} boxes, {cert.seconds:.2f} s CPU (witness search: {cert.samples} samples, seed {cert.seed})")
    if cert.note:
        lines.append(f"  note: {cert.note}")
    return "\n".join(lines)


def cmd_design(args) -> int:
    from ftstab_mj.control.design import default_gain_max, design
    from ftstab_mj.control.hong import validate_hong

    if args.gain_max is None:  # the user set at most --gain-min: that is the option to name
        if default_gain_max(args.r) <= args.gain_min:
            raise UsageError(f"--gain-min: expected a value below {default_gain_max(args.r):g} (the default --gain-max "
                             f"for r = {args.r}; pass a larger --gain-max to go above it), got {args.gain_min:g}")
    elif args.gain_max <= args.gain_min:
        raise UsageError(f"--gain-max: expected a value above --gain-min = {args.gain_min:g}, got {args.gain_max:g}")
    validate_hong(args.r, args.k, (1.0,) * args.r, check_hurwitz=False)  # k's range, before any work
    z0, region = _design_states(args)
    say = None if args.json else _progress_line()
    if say:
        say(f"designing gains for r = {args.r}, k = {args.k:g} (objective {args.objective}) ...")
    try:
        found = design(args.r, args.k, args.objective, z0=z0, u_max=args.u_max, region=region,
                       gain_min=args.gain_min, gain_max=args.gain_max, budget=args.budget,
                       max_boxes=args.max_boxes, progress=say)
    finally:
        _end_progress(say)
    gains, cert = found.gains, found.certificate
    if args.json:
        d = {"objective": args.objective, "gain_min": args.gain_min, "gain_max": found.gain_max,
             "refuted_gain_max": list(found.refuted_gain_max), "gains": None if gains is None else list(gains),
             "certificate": None if cert is None else _json_safe({**cert.to_dict(), "gap": cert.gap}),
             "time_bound": _json_safe(found.time_bound), "u0_max": found.u0_max,
             "u_max": args.u_max, "region": None if region is None else list(region)}
        print(json.dumps(d, indent=2, allow_nan=False))
        return 0 if found.certified else 1
    from ftstab_mj.control import HongController

    print(f"design r = {args.r}, k = {args.k:g}, objective {args.objective}, gains in "
          f"[{args.gain_min:g}, {found.gain_max:g}]"
          + (f", |u0| <= {args.u_max:g} on |z_i| <= ({', '.join(f'{x:g}' for x in region)})" if region else ""))
    if found.refuted_gain_max:  # why the range is not the one the user may expect
        print(f"  the default range widened tenfold: every candidate with gains up to "
              f"{' and up to '.join(f'{g:g}' for g in found.refuted_gain_max)} was refuted (a state with dV1/dt >= 0 each)")
    if gains is None:
        print("  no Hurwitz gain set found" + (" with |u0| <= --u-max on the region" if region else ""))
        return 1
    print(_certificate_text(HongController(args.r, args.k, gains), cert))
    if found.time_bound is not None:
        print(f"  T(z0) = {found.time_bound:.6g} s   (guaranteed: the largest of Theorem 1's bounds "
              f"V1(z0)^(1-alpha) / (c_lower (1-alpha)) over the {len(z0)} initial state(s))")
    if found.u0_max is not None:
        print(f"  max |u0| on the region = {found.u0_max:.6g} <= {args.u_max:g}   (exact: attained at the vertex "
              f"z = ({', '.join(f'{x:g}' for x in region)}), u0 being monotone in every z_i)")
    if not found.certified:  # no snippet: a scenario would claim a bound these gains do not have
        hint = ("refuted: dV1/dt >= 0 at the witness, so more boxes would not help; try k nearer 0"
                + (" or a larger --gain-max" if found.gain_max < GAIN_MAX else "")
                if cert.status == "not certified" else "raise --max-boxes / --budget, or try k nearer 0 or a larger --gain-max")
        print(f"  no candidate certified ({cert.status}): the gains above are the best estimate, not a result ({hint})")
        return 1
    print("scenario snippet ([loops.<name>.controller]):")
    print(f"  k = {args.k!r}\n  gains = [{', '.join(repr(g) for g in gains)}]")
    return 0


def _design_states(args):
    """(z0 (m, r) or None, region (r,) or None) of ``design`` from --z0 / --region, checked."""
    r = args.r
    if args.objective == "min-time":
        if not args.z0:
            raise UsageError("--z0: expected at least one initial state (r comma-separated numbers) for "
                             "--objective min-time, got none")
        if args.k == 0:
            raise UsageError("--k: expected k < 0 for --objective min-time (k = 0 converges exponentially, "
                             "no finite time), got 0")
    elif args.z0:
        raise UsageError(f"--z0: expected only with --objective min-time, got it with {args.objective}")
    for z in args.z0 or ():
        if len(z) != r:
            raise UsageError(f"--z0: expected {r} numbers (r = {r}), got {len(z)}: {','.join(f'{x:g}' for x in z)}")
    if args.z0 and not any(any(x != 0 for x in z) for z in args.z0):
        raise UsageError("--z0: expected a state other than 0 (T(0) = 0), got only zeros")
    if (args.u_max is None) != (args.region is None):
        given, missing = ("--u-max", "--region") if args.region is None else ("--region", "--u-max")
        raise UsageError(f"{missing}: expected with {given} (|u0| <= U on the box |z_i| <= R_i), got none")
    region = None
    if args.region is not None:
        if len(args.region) not in (1, r):
            raise UsageError(f"--region: expected 1 or {r} half-widths R_i (r = {r}), got {len(args.region)}")
        region = tuple(args.region) * (r if len(args.region) == 1 else 1)
    return (None if not args.z0 else [list(z) for z in args.z0]), region


def _numbers(lo, hi, what):
    """An argparse type: comma-separated finite numbers in [lo, hi] (lo excluded when lo == 0 and
    ``what`` says positive), with a one-line error."""
    def parse(text):
        try:
            xs = tuple(float(x) for x in text.split(","))
        except ValueError:
            xs = None
        if not xs or not all(lo <= x <= hi for x in xs) or (what == "positive" and not all(x > 0 for x in xs)):
            raise argparse.ArgumentTypeError(f"expected comma-separated {what} numbers in [{lo:g}, {hi:g}], got {text!r}")
        return xs
    return parse


def _region(text: str):
    try:
        inner, outer = (float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected R_IN,R_OUT (two numbers), got {text!r}") from None
    if not (0 < inner < outer <= 1e6):
        raise argparse.ArgumentTypeError(f"expected 0 < R_IN < R_OUT <= 1e6, got {text!r}")
    return inner, outer


def _read_log(path):
    """read_log + the truncation warning on stderr."""
    from ftstab_mj.logs.reader import read_log

    log = read_log(path)
    if log.warning:
        print(f"warning: {log.warning}", file=sys.stderr)
    return log


def _replayed_metrics(log):
    """Metrics recomputed from the log's arrays, with the recorded status (interrupted if none)."""
    from ftstab_mj.metrics.run_metrics import compute_metrics
    from ftstab_mj.simulation.records import INTERRUPTED

    status = log.recorded["status"] if log.recorded else INTERRUPTED
    return compute_metrics(log.info, log.loops, status)


def _streamed_metrics(path):
    """reader.stream_metrics (the log read as it streams) + the truncation warning on stderr, and a
    status line on a terminal while a certificate is computed."""
    from ftstab_mj.logs.reader import stream_metrics

    say = _progress_line()
    try:
        log, metrics = stream_metrics(path, say)
    finally:
        _end_progress(say)
    if log.warning:
        print(f"warning: {log.warning}", file=sys.stderr)
    return log, metrics


def cmd_replay(args) -> int:
    from ftstab_mj.metrics.run_metrics import CERTIFICATE_DERIVED, certificate_moved, format_table

    if args.rrd:  # the recording needs the samples themselves
        log = _read_log(args.log)
        metrics = _replayed_metrics(log)
    else:
        log, metrics = _streamed_metrics(args.log)
    diff, derived = [], []
    if log.recorded and log.recorded.get("metrics"):  # a failed run records its status without metrics
        from ftstab_mj.config.keypath import flatten

        rec, now = flatten(log.recorded["metrics"]), flatten(metrics)
        # a metric the recording version did not compute yet (an older log) is not a difference
        changed = [k for k in sorted(rec) if rec.get(k) != now.get(k)]
        # nor one derived from the certificate in a log recorded with the sampled estimate of c
        old_cert = {name for name, m in log.recorded["metrics"].get("loops", {}).items() if "certificate" not in m}
        derived = [k for k in changed if k.split(".")[0] == "loops" and k.split(".")[1] in old_cert
                   and k.split(".")[2] in CERTIFICATE_DERIVED]
        # nor, in a log whose certificate another version of the branch and bound computed (the
        # certificate depends on the controller and that code, not on the samples), the certificate and
        # what derives from it, as long as both brackets hold c
        loops_now = metrics.get("loops", {})
        moved_loops = {name for name, m in log.recorded["metrics"].get("loops", {}).items()
                       if certificate_moved(m.get("certificate"), loops_now.get(name, {}).get("certificate"))}
        moved = [k for k in changed if k.split(".")[0] == "loops" and k.split(".")[1] in moved_loops
                 and k.split(".")[2] in CERTIFICATE_DERIVED + ("certificate",)]
        diff = [f"  {k}: recorded {rec.get(k)!r}, recomputed {now.get(k)!r}" for k in changed
                if k not in derived and k not in moved]
    if args.rrd:
        from ftstab_mj.logs.rerun_sink import write_rrd

        message = log.recorded.get("message", "") if log.recorded else "truncated log"
        write_rrd(args.rrd, log.info, log.loops, (log.pose_t, log.pose_pos, log.pose_quat), metrics["status"],
                  metrics, message, force=args.force)
    if args.json:
        print(json.dumps(metrics, indent=2, allow_nan=False))
    else:
        v = log.versions
        print(f"{args.log}: {log.n_samples} samples, {'complete' if log.complete else 'truncated'} log"
              f" (ftstab_mj {v.get('ftstab_mj', '?')}, MuJoCo {v.get('mujoco', '?')})")
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
        from ftstab_mj.simulation.interrupts import interruption
        from ftstab_mj.scenario.run import verify_log

        try:
            v = verify_log(log)
        except KeyboardInterrupt as exc:  # the re-run was stopped: nothing was compared, nothing differs
            stop = interruption(exc)
            print(f"{args.log}: verify {stop.label}: the re-run of the recorded scenario was stopped before "
                  "it could be compared with the log", file=sys.stderr)
            return stop.exit_code
        if v.ok:
            print(f"verify: re-ran the recorded scenario: all {v.compared} logged values are bit-identical",
                  file=sys.stderr if args.json else sys.stdout)
        else:
            print(f"{args.log}: verify failed: the re-run of the recorded scenario differs from the log:", file=sys.stderr)
            print("\n".join(f"  {p}" for p in v.problems), file=sys.stderr)
            failed = True
    return 1 if failed else 0


def cmd_report(args) -> int:
    from ftstab_mj.figures.run_report import check_out, report_data, write_report

    check_out(args.out)  # a bad file name before the log is read
    rep = report_data(_read_log(args.log))
    write_report(rep, args.out)
    panels = sum(len(p) for p in rep.loops.values())
    print(f"wrote {args.out}: {rep.title.replace(chr(10), ', ')}; {len(rep.loops)} loop(s), {panels} panels")
    return 0


def cmd_check(args) -> int:
    from ftstab_mj.metrics.expectations import (PIN_HEADER, ExpectationError, check_metrics, load_expectations,
                                        pin_expectations, to_toml)

    if args.pin:
        log, metrics = _streamed_metrics(args.log)
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
    log, metrics = _streamed_metrics(args.log)
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
def cmd_list(args) -> int:
    from ftstab_mj.control import LAWS
    from ftstab_mj.plants import PLANTS
    from ftstab_mj.scenario import SCENARIO_DIR, shipped_scenarios
    from ftstab_mj.scenario.plugins import load_entry_points, origin

    load_entry_points()  # installed distributions' laws and plants are listed with the others
    rows = shipped_scenarios()
    width = max((len(name) for name, _, _ in rows), default=0)
    for name, _, description in rows:
        print(f"{name:<{width}}  {description}")
    print(f"\n{len(rows)} scenarios in {SCENARIO_DIR}; run one with: ftstab run NAME [--set key.path=value]")
    print("\nlaws (loops.<name>.controller.law) and their keys:")
    for cls in LAWS.values():
        where = origin(cls.__module__)
        print(f"  {cls.name}: {cls.summary}" + ("" if where == "built in" else f"  [{where}]"))
        for p in cls.all_params():
            default = "" if p.required else f" [default {p.default!r}]"
            print(f"      {p.name}: {p.describe()}{default}")
    print("\nplants (plant.model):")
    for entry in PLANTS.values():
        where = origin(entry.build.__module__)
        print(f"  {entry.name}: {entry.summary}" + ("" if where == "built in" else f"  [{where}]"))
    return 0


def cmd_run(args) -> int:
    from pathlib import Path

    from ftstab_mj.simulation import interrupts

    from ftstab_mj.scenario import find_scenario, load_scenario
    from ftstab_mj.scenario.run import ProgressSink, run_scenario

    path = find_scenario(args.scenario)
    if not path.exists() and not (path.suffix or "/" in args.scenario):  # a name, not a path: the loader says the rest
        raise UsageError(f"run {args.scenario}: expected a scenario file (.toml) or the name of a shipped "
                         "scenario, found neither (`ftstab list` shows the shipped ones)")
    sc = load_scenario(path, args.set)  # every check happens here, before any file
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {args.out}: expected a directory for the logs, found a file")
    from ftstab_mj.logs import McapSink, RerunSink
    from ftstab_mj.logs.files import check_replaceable
    from ftstab_mj.metrics.run_metrics import format_table

    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"--out {args.out}: expected a directory the logs can be written in, found {exc.strerror}") from None
    paths = (out / f"{sc.name}.mcap", out / f"{sc.name}.rrd")
    for path in paths:  # both checked before either is opened: bad input leaves no log behind
        if path.is_dir() or (path.exists() and not os.access(path, os.W_OK)):
            raise UsageError(f"--out {args.out}: expected {path.name} to be a writable file, found "
                             + ("a directory" if path.is_dir() else "a read-only file"))
        check_replaceable(path, args.force)  # a symlink or another program's file: not without --force
    say = (lambda *a, **k: None) if args.json else print  # --json: stdout carries the JSON only
    say(_header(sc.name, sc.description, args.set))
    say(f"  plant {sc.plant.model}, {len(sc.loops)} loop(s) ({', '.join(lp.controller.law for lp in sc.loops)}),"
        f" {sc.sim.duration:g} s, control period {sc.sim.period * 1e3:g} ms,"
        f" physics step {sc.sim.physics_step * 1e3:g} ms ({sc.sim.integrator}), seed {sc.seed}")
    if sc.plant.model.endswith(".xml"):  # what the testbed made of a user's model (a saturation kept, ...)
        from ftstab_mj.plants import make_plant

        for note in make_plant(sc.plant.model, sc.plant.params).notes:
            print(f"note: {note}", file=sys.stderr)
    live = _live_view(args)  # servers started (or refused in one line) before any log exists
    logs = (McapSink(paths[0], force=args.force, live=live.foxglove),
            RerunSink(paths[1], force=args.force, live=live.rerun, grpc_port=args.grpc_port))
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
            say_certificate = _progress_line()  # on a terminal, while a loop's certificate is computed
            try:
                run = run_scenario(sc, (*live.sinks(), *sinks), batch_size=live.batch_size(sc.sim.period),
                                   progress=say_certificate)
            finally:
                _end_progress(say_certificate)
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
            print(f"logs: {paths[0]}  {paths[1]}")
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


def _port(text: str) -> int:
    try:
        port = int(text)
    except ValueError:
        port = -1
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"expected a TCP port 0..65535 (0: any free one), got {text!r}")
    return port


def _live_target(text: str) -> str:
    """--live's value, checked while parsing (logs/live.rerun_target) so that a scenario name taken by
    --live (``--live NAME`` before the scenario) or a typo is one line, before any log exists."""
    from ftstab_mj.logs.live import rerun_target
    try:
        rerun_target(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"{exc} (write --live after the scenario name)") from None
    return text


def _host_port(text: str) -> tuple[str, int]:
    """[HOST:]PORT -> (host, port); HOST defaults to 127.0.0.1 (this machine only)."""
    host, _, port = text.rpartition(":")
    return (host or "127.0.0.1"), _port(port)


def _workers(text: str) -> int:
    if text == "all":
        return os.cpu_count() or 1
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1 or 'all' (every core), got {text!r}")
    return n


def _engine(args) -> str:
    """The sweep engine of --engine, --workers N and --scheduler: dask with --scheduler; else local
    processes when N > 1 (a local Dask cluster costs about twice their CPU on 200 short rows), serial for N = 1."""
    engine = args.engine or ("dask" if args.scheduler else "processes" if args.workers > 1 else "serial")
    if engine == "serial" and (args.workers > 1 or args.scheduler):
        raise UsageError("--engine serial: expected no --workers/--scheduler (one process runs everything)")
    if args.scheduler and engine != "dask":
        raise UsageError(f"--scheduler: expected --engine dask, found --engine {engine}")
    return engine


def cmd_sweep(args) -> int:
    engine = _engine(args)
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
    out = Path(args.out or Path("runs") / sweep.name)
    # a Dask cluster starts while the rows are checked; not for --resume, which may have nothing left to run
    with started_ahead("serial" if args.resume else engine, args.workers, args.scheduler) as ahead:
        # every input check, every row validated, before any run or file
        task, identity = prepare(sweep, rows, args.set, out / "logs" if args.logs else None)
        print(_header(sweep.name, sweep.description, args.set))
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


def _floats(text: str) -> tuple[float, ...]:
    try:
        vals = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers like 1,0.5, got {text!r}") from None
    if not all(math.isfinite(v) and v >= 0 for v in vals):
        raise argparse.ArgumentTypeError(f"expected finite numbers >= 0, got {text!r}")
    return vals


def cmd_montecarlo(args) -> int:
    from pathlib import Path

    from ftstab_mj.studies import montecarlo as mc
    from ftstab_mj.metrics.run_metrics import bound_applies
    from ftstab_mj.scenario import find_scenario, load_scenario
    from ftstab_mj.studies.sweep.table import write_table

    path = find_scenario(args.scenario)
    sc = load_scenario(path, args.set)
    loop = args.loop or sc.loops[0].name
    lp = next((x for x in sc.loops if x.name == loop), None)
    if lp is None:
        raise UsageError(f"--loop: expected a loop of {sc.name} ({', '.join(x.name for x in sc.loops)}), found {loop!r}")
    if not 1 <= args.states <= mc.MAX_STATES:
        raise UsageError(f"--states: expected an integer in [1, {mc.MAX_STATES}] (a work limit), found {args.states}")
    r = len(lp.z0)
    box = args.box or (max(abs(x) for x in lp.z0) or 1.0,) * r
    if len(box) != r:
        raise UsageError(f"--box: expected {r} half-widths (one per z_i of loop {loop}), found {len(box)}")
    if args.on == "chain" and (args.workers > 1 or args.scheduler or args.engine):
        raise UsageError("--on chain: expected no --workers/--engine/--scheduler (the native chain uses both cores itself)")
    if args.on == "chain":
        mc.chain_loop(sc, loop)  # a plant with no exact chain twin is refused before anything is printed
    Z0 = mc.Distribution(args.states, tuple(box), args.seed).draw()
    out = Path(args.out or Path("runs") / f"{sc.name}-montecarlo")
    tty = sys.stderr.isatty()

    def progress(done, total):
        if tty:
            sys.stderr.write(f"\r{done}/{total} states")
            sys.stderr.flush()

    say = (lambda *a, **k: None) if args.json else print
    say(f"{sc.name}: {args.states} initial states uniform in |z_i| <= ({', '.join(f'{b:g}' for b in box)}), "
        f"seed {args.seed}, on the {'ideal chain' if args.on == 'chain' else 'plant ' + sc.plant.model}")
    if args.on == "chain":
        rows, info = mc.run_chain(sc, loop, Z0, progress=progress)
        applies = bound_applies(info)
    else:
        from ftstab_mj.studies.sweep.row import ScenarioTask
        from ftstab_mj.config.tomlfile import read_toml
        from ftstab_mj.scenario.loader import apply_override

        raw = read_toml(path, "scenario file (.toml)")
        for text in args.set:
            apply_override(raw, text, str(path))
        engine = _engine(args)
        rows = mc.run_plant(ScenarioTask(raw, str(path)), loop, Z0, engine, args.workers, args.scheduler, progress)
        applies = bool(rows) and all(rw["bound_applies"] for rw in rows)  # each run's own metric
    if tty:
        sys.stderr.write("\n")
    summary = mc.summarize(rows, applies)
    applies = summary["bound_applies"]  # not where V1(z0) overflows
    out.mkdir(parents=True, exist_ok=True)
    write_table(rows, out / "montecarlo.parquet")
    (out / "montecarlo.json").write_text(mc.json_text(summary) + "\n")
    mc.figure(rows, summary, f"{sc.name}: settle time / T(z0)", out / "montecarlo.png")
    from ftstab_mj.studies.compare import lost_line

    lost = lost_line(rows, "state")  # W4: states lost by dead workers are an error
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
    if summary["worst"]:
        w = summary["worst"]
        print(f"  worst: state {w['row']}, z0 = [{', '.join(f'{x:.17g}' for x in w['z0'])}],"
              f" settle time {w['settle_time']:.6g} s, T(z0) {w['time_bound']:.6g} s")
    print(f"table: {out / 'montecarlo.parquet'}  summary: {out / 'montecarlo.json'}  figure: {out / 'montecarlo.png'}")
    return 1 if lost else 0


def cmd_compare(args) -> int:
    from pathlib import Path

    from ftstab_mj.studies import compare
    from ftstab_mj.studies.sweep.engine import execute
    from ftstab_mj.studies.sweep.table import write_table

    cmp = compare.load_comparison(args.comparison)
    task, items = compare.prepare(cmp, args.set)  # every row validated before any run
    if args.workers > 1 and args.engine == "serial":
        raise UsageError("--engine serial: expected no --workers (one process runs everything)")
    engine = "processes" if args.workers > 1 else "serial"
    out = Path(args.out or Path("runs") / cmp.name)
    out.mkdir(parents=True, exist_ok=True)
    print(_header(cmp.name, cmp.description, args.set))
    print(f"  base {cmp.scenario}, {len(cmp.laws)} laws x {max(1, len(cmp.grid))} -> {len(items)} runs -> {out}")
    results = dict(execute(items, task, engine, args.workers))
    rows, series = [], {}
    for i, p in items:
        res = results.get(i) or {"status": "lost", "error": "the worker running it died", "metrics": {}}
        rows.append({"row": i, **compare.table_row(p, res, task.loops[0], cmp.grid_path)})
        if res.get("series"):
            series[p[0]] = res["series"]
    columns = ["label"] + ([cmp.grid_path] if cmp.grid_path else []) + [
        "status", "settle_time_z1", *[k for k in rows[0] if k.startswith("final_abs_z")], "effort_sq", "u_max_abs",
        "chattering_tv", "chattering_du_dt_var", "chattering_zero_crossings", "chattering_band_rms", "beat_bound"]
    print(compare.format_rows(rows, columns))
    paths = [compare.write_csv(rows, out / f"{cmp.name}.csv"), write_table(rows, out / f"{cmp.name}.parquet")]
    slopes = []
    if cmp.grid_path and len(cmp.grid) >= 2:
        slopes = compare.fit_slopes(rows, cmp.grid_path)
        print(f"log-log slopes of max |z_i| against {cmp.grid_path} ({len(cmp.grid)} values):")
        print(compare.format_rows(slopes, list(slopes[0])))
        paths.append(compare.write_csv(slopes, out / f"{cmp.name}_slopes.csv"))
    paths += compare.draw_figures(cmp, rows, slopes, series, out)
    for path in paths:
        print(f"wrote {path}")
    lost = compare.lost_line(rows)  # W4: rows lost by dead workers are an error, not a quiet 'lost' cell
    if lost:
        print(lost, file=sys.stderr)
    return 1 if lost else 0


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="ftstab", description=(
        "Testbed for the finite-time robust and adaptive controllers of Harmouche, Laghrouche and "
        "Chitour on MuJoCo plants."))
    from ftstab_mj import __version__

    p.add_argument("--version", action="version", version=f"ftstab {__version__}")
    sub = p.add_subparsers(dest="verb", parser_class=_Parser, metavar="VERB")
    c = sub.add_parser("certify", help="sound Lyapunov certificate (c, alpha, c', alpha') of Hong's controller",
                       description="Bound c (dV1/dt <= -c V1^alpha) from below and c' (|dV1/dz_r| <= c' V1^alpha') "
                                   "from above by branch and bound with outward-rounded interval arithmetic over the "
                                   "homogeneous unit sphere; status certified (c_lower > 0), not certified (a witness "
                                   "state with dV1/dt >= 0) or undecided (the budget ran out). Simplified form: a "
                                   "sound check of dV1/dt < 0 on the shell --region.")
    c.add_argument("--r", type=_number_in(1, 8, int), required=True, help="chain length r, 1..8")
    c.add_argument("--k", type=float, required=True, help="homogeneity degree, -1/r < k <= 0 (full form)")
    c.add_argument("--gains", type=_gains, required=True,
                   help=f"l_1,...,l_r (comma-separated, each in [{GAIN_MIN:g}, {GAIN_MAX:g}])")
    c.add_argument("--form", choices=("full", "simplified"), default="full")
    c.add_argument("--budget", type=_number_in(0.01, 86400.0, what=" seconds"), default=None, metavar="SECONDS",
                   help="CPU seconds for the branch and bound (default: until the gap is < 0.2 %%)")
    c.add_argument("--samples", type=_number_in(100, 10_000_000, int), default=20_000,
                   help="states sampled by the witness search before the branch and bound, 100..1e7 (default 20000)")
    c.add_argument("--seed", type=_number_in(0, 2 ** 63 - 1, int), default=0,
                   help="seed of the witness search, 0..2^63-1 (default 0)")
    c.add_argument("--region", type=_region, default=(0.01, 1.0), metavar="R_IN,R_OUT",
                   help="simplified form: the shell R_IN <= |z|_inf <= R_OUT checked (default 0.01,1)")
    c.add_argument("--json", action="store_true",
                   help="print JSON: c (= c_lower), alpha, c_prime (= c_prime_upper), alpha_prime, certified, "
                        "c_lower, c_upper, c_prime_upper, witness, status, gap, ...")
    c.set_defaults(func=cmd_certify)

    dz = sub.add_parser("design", help="gains of Hong's controller with a sound certificate (max c_lower, min T(z0))",
                        description="Search the gains l_1..l_r in [--gain-min, --gain-max] that maximise the "
                                    "guaranteed c_lower for (r, k) (max-c) or minimise the guaranteed T(z0) for the "
                                    "--z0 states (min-time), optionally subject to |u0| <= --u-max on the box "
                                    "--region: a deterministic simplex search over an estimate of c, then the sound "
                                    "certificate of the candidates. Prints the gains, their certificate and a "
                                    "scenario snippet. Exit 0 when certified, 1 when no candidate certified, 2 on "
                                    "bad input.")
    dz.add_argument("--r", type=_number_in(1, 6, int), required=True, help="chain length r, 1..6")
    dz.add_argument("--k", type=float, required=True, help="homogeneity degree, -1/r < k <= 0")
    dz.add_argument("--objective", choices=("max-c", "min-time"), default="max-c",
                    help="what to optimise: max-c (c_lower) or min-time (the guaranteed T(z0) for --z0)")
    dz.add_argument("--z0", type=_numbers(-1e6, 1e6, "finite"), action="append", metavar="Z1,...,ZR",
                    help="min-time: an initial state (repeat for several; T is their largest bound)")
    dz.add_argument("--u-max", type=_number_in(1e-9, 1e12), default=None, metavar="U",
                    help="subject to |u0| <= U on the box --region (exact: u0 is monotone in every z_i)")
    dz.add_argument("--region", type=_numbers(0.0, 1e6, "positive"), default=None, metavar="R[,R2,...]",
                    help="with --u-max: the box |z_i| <= R_i (one R for every i, or r of them)")
    dz.add_argument("--gain-min", type=_number_in(GAIN_MIN, GAIN_MAX), default=0.1, help="smallest gain (default 0.1)")
    dz.add_argument("--gain-max", type=_number_in(GAIN_MIN, GAIN_MAX), default=None,
                    help="largest gain (default 100 for r <= 4, 1000 for r = 5, 1e6 for r = 6: longer chains need "
                         "a larger last gain; without --gain-max the range widens tenfold, at most twice and "
                         "up to 1e6, while every candidate is refuted)")
    dz.add_argument("--budget", type=_number_in(0.01, 86400.0, what=" seconds"), default=None, metavar="SECONDS",
                    help="CPU seconds per candidate's certificate (default: until its gap is < 0.2 %%)")
    dz.add_argument("--max-boxes", type=_number_in(1, 10 ** 10, int), default=None, metavar="N",
                    help="branch-and-bound boxes per candidate's certificate (default 5e6, 2e7 for r = 6; deterministic)")
    dz.add_argument("--json", action="store_true", help="print JSON: gains and certificate")
    dz.set_defaults(func=cmd_design)

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
                    help="re-run the scenario recorded in the log and check that the samples are bit-identical")
    rp.set_defaults(func=cmd_replay)

    ck = sub.add_parser("check", help="compare a log's metrics with pinned values and tolerances",
                        description="Exit 0 when every expectation of EXPECT.toml holds for the metrics "
                                    "recomputed from LOG.mcap, 1 with the failing ones listed otherwise (or when the "
                                    "log has no samples to check them on). Format: "
                                    "see ftstab_mj/metrics/expectations.py.")
    ck.add_argument("log", metavar="LOG.mcap")
    what = ck.add_mutually_exclusive_group(required=True)
    what.add_argument("--expect", metavar="EXPECT.toml", help="the pinned metrics to compare with")
    what.add_argument("--pin", metavar="OUT.toml", help="write OUT.toml: this log's metrics with the default "
                                                       "tolerances (ftstab_mj/metrics/expectations.py), to check later runs")
    ck.set_defaults(func=cmd_check)

    rt = sub.add_parser("report", help="the figures of one run for a paper (PNG or self-contained HTML)",
                        description="Draw from LOG.mcap, per loop: each z_i, u (and u0), V1 on a log axis with the "
                                    "settle level and Theorem 1's envelope and T(z0) (nominal and robust laws with a "
                                    "certificate), phi_hat and gamma_hat with Theorem 3's bounds (adaptive law); "
                                    "axes in their units. FIG.html embeds the PNG (no network needed). What each "
                                    "panel holds: ftstab_mj/figures/run_report.py. Exit 2 on a log that cannot be read.")
    rt.add_argument("log", metavar="LOG.mcap")
    rt.add_argument("--out", required=True, metavar="FIG.png|FIG.html", help="the figure to write")
    rt.set_defaults(func=cmd_report)
    r = sub.add_parser(
        "run", help="run a scenario file, write its logs, print its metrics",
        description="Run SCENARIO (a .toml file, or the name of a shipped scenario: see `ftstab list`), "
                    "write DIR/<name>.mcap (Foxglove) and DIR/<name>.rrd (Rerun), print the metrics. "
                    "Exit 0 when the run completed (converged or not: convergence is a metric), "
                    "1 when it diverged or failed, 130 when interrupted (Ctrl-C), 2 on bad input.",
        epilog="example: ftstab run scenarios/cart_r2_robust.toml --out runs --set sim.duration=2")
    r.add_argument("scenario", help="scenario file (.toml) or shipped scenario name")
    r.add_argument("--out", default="runs", metavar="DIR", help="directory of the logs (default: runs)")
    r.add_argument("--set", action="append", default=[], metavar="KEY.PATH=VALUE",
                   help="override one field, validated like the file (repeatable), e.g. sim.duration=2 "
                        "or loops.cart.controller.gains[1]=3")
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
    view.add_argument("--grpc-port", type=_port, default=9876, metavar="PORT",
                      help="the Rerun viewer's or server's gRPC port (default 9876)")
    view.add_argument("--web-port", type=_port, default=9090, metavar="PORT",
                      help="--live serve: the web viewer's HTTP port (default 9090)")
    view.add_argument("--foxglove", nargs="?", const=("127.0.0.1", 8765), type=_host_port, metavar="[HOST:]PORT",
                      help="serve the run to Foxglove (WebSocket) as it happens, the MCAP log's channels "
                           "and messages (default 127.0.0.1:8765; port 0: any free one, printed)")
    view.add_argument("--realtime", action="store_true",
                      help="pace the run to the wall clock (sim time follows wall time; prints the lag)")
    r.set_defaults(func=cmd_run)

    ls = sub.add_parser("list", help="the shipped scenarios, the control laws and the plants",
                        description="List the scenarios shipped in scenarios/ with their one-line descriptions, "
                                    "then the registered control laws with their scenario keys, then the plants.")
    ls.set_defaults(func=cmd_list)

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
    w.add_argument("--workers", type=_workers, default=1, metavar="N",
                   help="parallel runs (default 1: serial; 'all': one per core); N > 1 starts N local worker "
                        "processes")
    w.add_argument("--engine", choices=("serial", "processes", "dask"),
                   help="serial, processes (a local process pool) or dask (a local Dask cluster of N processes, "
                        "or --scheduler's); default: processes when N > 1, dask with --scheduler")
    w.add_argument("--scheduler", metavar="ADDRESS",
                   help="a running Dask scheduler (tcp://host:8786) instead of local workers (implies --engine dask); "
                        "its workers need ftstab_mj installed")
    w.add_argument("--out", metavar="DIR", help="output directory (default: runs/<sweep name>)")
    w.add_argument("--resume", action="store_true", help="continue the sweep in DIR: run only the rows not in its table")
    w.add_argument("--set", action="append", default=[], metavar="KEY.PATH=VALUE",
                   help="override a field of the base scenario for every run (repeatable), e.g. sim.duration=1")
    w.add_argument("--format", choices=("parquet", "csv"), default="parquet", help="table format (default parquet)")
    w.add_argument("--logs", action="store_true", help="also write each run's logs, DIR/logs/rowNNNNN.mcap and .rrd")
    w.add_argument("--report", action="store_true",
                   help="draw the sweep file's [[report.plot]] figures into DIR/report/ (PNG) and print the fits")
    w.set_defaults(func=cmd_sweep)

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
    mc.add_argument("--box", type=_floats, metavar="A1,...,AR",
                    help="half-widths of the box of z0 (chain units; default: max |z0_i| of the scenario on every axis)")
    mc.add_argument("--seed", type=int, default=0, help="seed of the draw of initial states (default 0)")
    mc.add_argument("--loop", help="the loop whose z0 is drawn (default: the first)")
    mc.add_argument("--on", choices=("chain", "plant"), default="chain",
                    help="chain: the loop on the exact ideal chain (ideal-chain scenarios, carts without friction or damping); "
                         "plant: runs of the scenario itself, like ftstab run")
    mc.add_argument("--workers", type=_workers, default=1, metavar="N", help="plant: parallel runs")
    mc.add_argument("--engine", choices=("serial", "processes", "dask"),
                    help="plant: the sweep engine (default: processes when N > 1, dask with --scheduler)")
    mc.add_argument("--scheduler", metavar="ADDRESS", help="plant: a running Dask scheduler (implies --engine dask)")
    mc.add_argument("--set", action="append", default=[], metavar="KEY.PATH=VALUE", help="override a field (repeatable)")
    mc.add_argument("--out", metavar="DIR", help="output directory (default: runs/<scenario>-montecarlo)")
    mc.add_argument("--json", action="store_true", help="print the summary as JSON")
    mc.set_defaults(func=cmd_montecarlo)

    cp = sub.add_parser(
        "compare", help="several control laws on one base scenario, side by side (table and figures)",
        description="Run every law of COMPARISON (whole controller tables) on its base scenario, at every "
                    "value of its optional grid (control period or disturbance amplitude); print one table "
                    "(laws as rows: settling time, final accuracy per z_i, effort, max |u|, chattering "
                    "indices, bound beaten), write it to DIR/<name>.csv and .parquet, the log-log slopes "
                    "of the accuracy against the period to DIR/<name>_slopes.csv, and the figures "
                    "DIR/<name>_accuracy.png and DIR/<name>_time.png. Exit 0 when every run is in the "
                    "table (a diverged run is a row with its status), 2 on bad input.",
        epilog="example: ftstab compare scenarios/compare/cart_r2.toml --workers 2")
    cp.add_argument("comparison", help="comparison file (.toml)")
    cp.add_argument("--workers", type=_workers, default=1, metavar="N",
                    help="parallel runs on a local process pool (default 1: serial; 'all': one per core)")
    cp.add_argument("--engine", choices=("serial", "processes"), help="serial or processes (default: processes when N > 1)")
    cp.add_argument("--out", metavar="DIR", help="output directory (default: runs/<name>)")
    cp.add_argument("--set", action="append", default=[], metavar="KEY.PATH=VALUE",
                    help="override a field of the base scenario for every run (repeatable), e.g. sim.duration=1")
    cp.set_defaults(func=cmd_compare)
    return p


def main(argv=None) -> int:
    from ftstab_mj.simulation import interrupts

    with interrupts.handling(take_over=True):  # SIGTERM and SIGHUP stop a command like Ctrl-C (exit 128 + signal)
        try:
            parser = build_parser()
            args = parser.parse_args(argv)
            if args.verb is None:  # `ftstab` alone: what it can do
                parser.print_help()
                return 0
            code = args.func(args)
            sys.stdout.flush()  # a closed pipe shows here (stdout is block-buffered into a pipe), not at exit
            return code
        except LogWriteError as exc:  # a log could not be written (disk full): not bad input
            print(f"error: {exc}", file=sys.stderr)
            return 1
        except FtstabError as exc:  # every bad input of ours: one line, exit 2
            print(f"error: {exc}", file=sys.stderr)
            return 2
        except BrokenPipeError:  # `ftstab replay ... | head`: the reader left; say nothing more
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())  # Python's flush at exit would raise again
            return 0
        except KeyboardInterrupt as exc:  # outside a run (a run catches its own and finalizes its logs)
            stop = interrupts.interruption(exc)
            print(f"error: {stop.label}", file=sys.stderr)
            return stop.exit_code
        except ImportError:  # a signal inside a C extension's import comes out as "initialization failed"
            stop = interrupts.last_signal()
            if stop is None:
                raise
            print(f"error: {stop.label}", file=sys.stderr)
            return stop.exit_code


if __name__ == "__main__":
    sys.exit(main())

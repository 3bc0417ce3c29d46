"""``ftstab design``: gains of Hong's controller with a sound certificate (control.design)."""

from __future__ import annotations

import json

from ftstab_mj.cli.common import (
    GAIN_MAX,
    GAIN_MIN,
    UsageError,
    certificate_text,
    end_progress,
    json_safe,
    number_in,
    numbers,
    progress_line,
)

VERB = "design"
ORDER = 20  # its place in `ftstab --help`


def add_parser(sub) -> None:
    dz = sub.add_parser("design", help="gains of Hong's controller with a sound certificate (max c_lower, min T(z0))",
                        description="Search the gains l_1..l_r in [--gain-min, --gain-max] that maximise the "
                                    "guaranteed c_lower for (r, k) (max-c) or minimise the guaranteed T(z0) for the "
                                    "--z0 states (min-time), optionally subject to |u0| <= --u-max on the box "
                                    "--region: a deterministic simplex search over an estimate of c, then the sound "
                                    "certificate of the candidates. Prints the gains, their certificate and a "
                                    "scenario snippet. Exit 0 when certified, 1 when no candidate certified, 2 on "
                                    "bad input.")
    dz.add_argument("--r", type=number_in(1, 6, int), required=True, help="chain length r, 1..6")
    dz.add_argument("--k", type=float, required=True, help="homogeneity degree, -1/r < k <= 0")
    dz.add_argument("--objective", choices=("max-c", "min-time"), default="max-c",
                    help="what to optimise: max-c (c_lower) or min-time (the guaranteed T(z0) for --z0)")
    dz.add_argument("--z0", type=numbers(-1e6, 1e6, "finite"), action="append", metavar="Z1,...,ZR",
                    help="min-time: an initial state (repeat for several; T is their largest bound)")
    dz.add_argument("--u-max", type=number_in(1e-9, 1e12), default=None, metavar="U",
                    help="subject to |u0| <= U on the box --region (exact: u0 is monotone in every z_i)")
    dz.add_argument("--region", type=numbers(0.0, 1e6, "positive"), default=None, metavar="R[,R2,...]",
                    help="with --u-max: the box |z_i| <= R_i (one R for every i, or r of them)")
    dz.add_argument("--gain-min", type=number_in(GAIN_MIN, GAIN_MAX), default=0.1, help="smallest gain (default 0.1)")
    dz.add_argument("--gain-max", type=number_in(GAIN_MIN, GAIN_MAX), default=None,
                    help="largest gain (default 100 for r <= 4, 1000 for r = 5, 1e6 for r = 6: longer chains need "
                         "a larger last gain; without --gain-max the range widens tenfold, at most twice and "
                         "up to 1e6, while every candidate is refuted)")
    dz.add_argument("--budget", type=number_in(0.01, 86400.0, what=" seconds"), default=None, metavar="SECONDS",
                    help="CPU seconds per candidate's certificate (default: until its gap is < 0.2 %%)")
    dz.add_argument("--max-boxes", type=number_in(1, 10 ** 10, int), default=None, metavar="N",
                    help="branch-and-bound boxes per candidate's certificate (default 5e6, 2e7 for r = 6; deterministic)")
    dz.add_argument("--json", action="store_true", help="print JSON: gains and certificate")
    dz.set_defaults(func=handle)


def handle(args) -> int:
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
    say = None if args.json else progress_line()
    if say:
        say(f"designing gains for r = {args.r}, k = {args.k:g} (objective {args.objective}) ...")
    try:
        found = design(args.r, args.k, args.objective, z0=z0, u_max=args.u_max, region=region,
                       gain_min=args.gain_min, gain_max=args.gain_max, budget=args.budget,
                       max_boxes=args.max_boxes, progress=say)
    finally:
        end_progress(say)
    gains, cert = found.gains, found.certificate
    if args.json:
        d = {"objective": args.objective, "gain_min": args.gain_min, "gain_max": found.gain_max,
             "refuted_gain_max": list(found.refuted_gain_max), "gains": None if gains is None else list(gains),
             "certificate": None if cert is None else json_safe({**cert.to_dict(), "gap": cert.gap}),
             "time_bound": json_safe(found.time_bound), "u0_max": found.u0_max,
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
    print(certificate_text(HongController(args.r, args.k, gains), cert))
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

"""``ftstab certify``: a sound Lyapunov certificate of Hong's controller (control.certify)."""

from __future__ import annotations

import json

from ftstab_mj.cli.common import (
    GAIN_MAX,
    GAIN_MIN,
    certificate_text,
    end_progress,
    gains,
    json_safe,
    number_in,
    progress_line,
    region,
)

VERB = "certify"
ORDER = 10  # its place in `ftstab --help`


def add_parser(sub) -> None:
    c = sub.add_parser("certify", help="sound Lyapunov certificate (c, alpha, c', alpha') of Hong's controller",
                       description="Bound c (dV1/dt <= -c V1^alpha) from below and c' (|dV1/dz_r| <= c' V1^alpha') "
                                   "from above by branch and bound with outward-rounded interval arithmetic over the "
                                   "homogeneous unit sphere; status certified (c_lower > 0), not certified (a witness "
                                   "state with dV1/dt >= 0) or undecided (the budget ran out). Simplified form: a "
                                   "sound check of dV1/dt < 0 on the shell --region.")
    c.add_argument("--r", type=number_in(1, 8, int), required=True, help="chain length r, 1..8")
    c.add_argument("--k", type=float, required=True, help="homogeneity degree, -1/r < k <= 0 (full form)")
    c.add_argument("--gains", type=gains, required=True,
                   help=f"l_1,...,l_r (comma-separated, each in [{GAIN_MIN:g}, {GAIN_MAX:g}])")
    c.add_argument("--form", choices=("full", "simplified"), default="full")
    c.add_argument("--budget", type=number_in(0.01, 86400.0, what=" seconds"), default=None, metavar="SECONDS",
                   help="CPU seconds for the branch and bound (default: until the gap is < 0.2 %%)")
    c.add_argument("--samples", type=number_in(100, 10_000_000, int), default=20_000,
                   help="states sampled by the witness search before the branch and bound, 100..1e7 (default 20000)")
    c.add_argument("--seed", type=number_in(0, 2 ** 63 - 1, int), default=0,
                   help="seed of the witness search, 0..2^63-1 (default 0)")
    c.add_argument("--region", type=region, default=(0.01, 1.0), metavar="R_IN,R_OUT",
                   help="simplified form: the shell R_IN <= |z|_inf <= R_OUT checked (default 0.01,1)")
    c.add_argument("--json", action="store_true",
                   help="print JSON: c (= c_lower), alpha, c_prime (= c_prime_upper), alpha_prime, certified, "
                        "c_lower, c_upper, c_prime_upper, witness, status, gap, ...")
    c.set_defaults(func=handle)


def handle(args) -> int:
    from ftstab_mj.control import HongController, certify

    hong = HongController(args.r, args.k, args.gains, form=args.form)
    say = None if args.json else progress_line()
    inner, outer = args.region
    try:
        cert = certify(hong, samples=args.samples, seed=args.seed, budget=args.budget, progress=say,
                       region_radius=outer, region_inner=inner)
    finally:
        end_progress(say)
    if args.json:
        d = cert.to_dict()
        d["gap"] = cert.gap
        print(json.dumps(json_safe(d), indent=2, allow_nan=False))
        return 0
    print(certificate_text(hong, cert))
    return 0

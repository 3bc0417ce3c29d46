"""The ``ftstab`` command. Exit codes: 0 success, 1 a check failed, 2 bad input (one line, no traceback)."""

from __future__ import annotations

import argparse
import json
import sys

from ftstab_mj.errors import FtstabError


class UsageError(FtstabError, ValueError):
    """Bad command-line input; reported as one line with exit code 2."""


class _Parser(argparse.ArgumentParser):
    """argparse that reports errors as one line and exit code 2 (argparse's own code for usage)."""

    def error(self, message):  # noqa: D401 - argparse API
        raise UsageError(f"{self.prog}: {message}")


def _gains(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers like 1,2, got {text!r}") from None


def cmd_certify(args) -> int:
    from ftstab_mj.control import HongController, certify

    hong = HongController(args.r, args.k, args.gains, form=args.form)
    cert = certify(hong, samples=args.samples, seed=args.seed)
    if args.json:
        print(json.dumps(cert.to_dict(), indent=2))
        return 0
    print(f"form {cert.form}, r = {hong.r}, k = {hong.k:g}, gains = {', '.join(f'{g:g}' for g in hong.gains)}")
    if cert.form == "full":
        print(f"  c       = {cert.c:.6g}    alpha  = {cert.alpha:.6g}   (dV1/dt <= -c V1^alpha)")
        print(f"  c'      = {cert.c_prime:.6g}    alpha' = {cert.alpha_prime:.6g}   (|dV1/dz_r| <= c' V1^alpha')")
    else:
        print(f"  max dV1/dt on |z_i| <= {cert.region_radius:g}: {cert.region_max_dV1dt:.6g}"
              f" ({'negative' if cert.region_negative else 'NOT negative'} on the region)")
    print(f"  certified: {'yes' if cert.certified else 'no'}   ({cert.samples} samples, seed {cert.seed})")
    if cert.note:
        print(f"  note: {cert.note}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="ftstab", description=(
        "Testbed for the finite-time robust and adaptive controllers of Harmouche, Laghrouche and "
        "Chitour on MuJoCo plants."))
    sub = p.add_subparsers(dest="verb", required=True, parser_class=_Parser)
    c = sub.add_parser("certify", help="Lyapunov certificate (c, alpha, c', alpha') of Hong's controller",
                       description="Compute c, alpha (dV1/dt <= -c V1^alpha) and c', alpha' "
                                   "(|dV1/dz_r| <= c' V1^alpha') by sampling the unit level set of V1.")
    c.add_argument("--r", type=int, required=True, help="chain length r >= 1")
    c.add_argument("--k", type=float, required=True, help="homogeneity degree k <= 0")
    c.add_argument("--gains", type=_gains, required=True, help="l_1,...,l_r (comma-separated, > 0)")
    c.add_argument("--form", choices=("full", "simplified"), default="full")
    c.add_argument("--samples", type=int, default=200_000, help="samples of the level set (default 200000)")
    c.add_argument("--seed", type=int, default=0, help="seed of the sampling (default 0)")
    c.add_argument("--json", action="store_true", help="print JSON (keys c, alpha, c_prime, alpha_prime, certified, ...)")
    c.set_defaults(func=cmd_certify)
    return p


def main(argv=None) -> int:
    try:
        args = build_parser().parse_args(argv)
        return args.func(args)
    except FtstabError as exc:  # every bad input of ours: one line, exit 2
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())

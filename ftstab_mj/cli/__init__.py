"""The ``ftstab`` command. Exit codes: 0 success, 1 a check failed, 2 bad input (one line, no traceback),
128 + N when stopped by signal N (130: Ctrl-C).

One module per verb in this package, holding its parser and its handler side by side: it declares
``VERB`` (its name), ``ORDER`` (its place in ``ftstab --help``), ``add_parser(sub)`` (adds its
subparser to argparse's subparsers ``sub`` and sets ``func=handle``) and ``handle(args) -> int`` (the
exit code). :func:`build_parser` finds them (the .py files of this package): adding a verb is one new module here, plus its
test. What verbs share (argument types, the header, the progress line) is in :mod:`.common`; the
domain logic is in the layers below (studies, figures, logs, metrics, scenario, control), never here.

Layer 10 (the top, beside api.py): may import every layer below. A verb module imports them inside
its handler, so that ``ftstab --help`` and argument errors stay cheap.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from ftstab_mj.cli.common import GAIN_MAX, GAIN_MIN, Parser, UsageError
from ftstab_mj.config.errors import FtstabError, LogWriteError

__all__ = ["GAIN_MAX", "GAIN_MIN", "UsageError", "build_parser", "main", "verbs"]


def verbs() -> list:
    """The verb modules of this package (those declaring ``VERB``), in their ``ORDER``."""
    found = []  # the .py files of the package's folders (pkgutil.iter_modules would import inspect: 10 ms a command)
    names = {f[:-3] for d in __path__ if os.path.isdir(d) for f in os.listdir(d) if f.endswith(".py") and f[0] != "_"}
    for name in sorted(names):
        module = importlib.import_module(f"{__name__}.{name}")
        if hasattr(module, "VERB"):
            found.append(module)
    return sorted(found, key=lambda m: (m.ORDER, m.VERB))


def build_parser() -> argparse.ArgumentParser:
    p = Parser(prog="ftstab", description=(
        "Testbed for the finite-time robust and adaptive controllers of Harmouche, Laghrouche and "
        "Chitour on MuJoCo plants."))
    from ftstab_mj import __version__

    p.add_argument("--version", action="version", version=f"ftstab {__version__}")
    sub = p.add_subparsers(dest="verb", parser_class=Parser, metavar="VERB")
    for module in verbs():
        module.add_parser(sub)
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

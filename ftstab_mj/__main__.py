"""The ``ftstab`` process: ``python -m ftstab_mj`` and the ``ftstab`` script (pyproject.toml points
it at :func:`main`).

No signal may end the command with a traceback or kill it without a word. So the first thing this
module does, before importing any Python code, is to give SIGINT, SIGTERM and SIGHUP a handler that
only notes them (through ``_signal``, the C module); :func:`main` hands them to ftstab_mj.simulation.interrupts
(a noted signal stops the command there: exit 128 + signal, no log) and, once the exit code is
decided, has them ignored to the end (interrupts.finish). Before this module runs (the
interpreter's start-up, ``site``, the package's ``__init__``) Python's own handling applies.
"""

import _signal

_noted: list[int] = []  # signals that came before ftstab_mj.simulation.interrupts took over


def _note(signum, frame):
    _noted.append(signum)


for _name in ("SIGINT", "SIGTERM", "SIGHUP"):
    _s = getattr(_signal, _name, None)
    if _s is not None and _signal.getsignal(_s) != _signal.SIG_IGN:  # nohup's ignored SIGHUP stays ignored
        _signal.signal(_s, _note)

import sys  # noqa: E402 - after the handlers, on purpose

from ftstab_mj.studies.batch_env import BATCH_VERBS, batch_environment  # noqa: E402 - imports os only


def main() -> int:
    """Run the ``ftstab`` command (sys.argv); its exit code.

    Python's cyclic garbage collector is kept off the start-up of ``ftstab run`` and off every
    command's exit: the imports leave ~10^5 long-lived objects (Rerun, MuJoCo, NumPy) that the
    collector would scan again and again while they are made and once more at the interpreter's
    exit, for nothing (measured on alternated 1-sample ``ftstab run`` processes: 0.07 s at start-up,
    0.2 s at exit, of 0.85 s of CPU). ``run`` is one run per process, and a run leaves the same 48
    unreachable objects whatever its length (no cyclic garbage per batch; also with --foxglove and
    batches of 33 samples), so it runs with the collector off; the other commands (sweeps, Monte Carlo: many runs) keep it on. At the exit the
    objects are frozen (gc.freeze): the operating system frees them, the collector no longer visits them.
    """
    import gc

    if sys.argv[1:2] == ["run"]:
        gc.disable()
    if sys.argv[1:2] and sys.argv[1] in BATCH_VERBS:  # before anything imports NumPy or MuJoCo
        batch_environment()
    try:
        from ftstab_mj.simulation import interrupts

        interrupts.own_process(_noted)
        from ftstab_mj.cli import main as command

        code = command()
    except KeyboardInterrupt as exc:  # before the command could catch it (its imports)
        stop = interrupts.interruption(exc)
        print(f"error: {stop.label}", file=sys.stderr)
        code = stop.exit_code
    except ImportError:  # a signal inside a C extension's import comes out as "initialization failed"
        stop = interrupts.last_signal()
        if stop is None:
            raise
        print(f"error: {stop.label}", file=sys.stderr)
        code = stop.exit_code
    code = interrupts.finish(code)
    gc.freeze()
    return code


if __name__ == "__main__":
    sys.exit(main())

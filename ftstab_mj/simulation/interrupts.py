"""Ctrl-C, SIGTERM and SIGHUP: the one way a run is stopped from outside, and logs that stay consistent.

A signal becomes :class:`Interrupted` (a KeyboardInterrupt, so every ``except KeyboardInterrupt``
treats SIGTERM and SIGHUP like Ctrl-C) carrying the signal, whose exit code is 128 + its number.
:func:`handling` installs that for the ``ftstab`` command (SIGINT, SIGTERM, SIGHUP) and, around a
run, for library callers (SIGINT only, from the main thread), putting the previous handlers back.

Consistency. A run writes its logs only inside :func:`critical` blocks (opening the sinks, handing
one batch to every sink, closing them). A signal that comes inside such a block is held and raised
when the outermost block ends, so a batch is in every log or in none, and a log is never left half
opened or half closed; outside the blocks (setup, computing a batch) it is raised at once, before
any log exists or between two batches. Once a run is being stopped, further signals are held
until it has closed its logs (a second Ctrl-C does not abandon them half written).

The ``ftstab`` process (ftstab_mj/__main__.py) owns its signals from its entry's first line
(:func:`own_process`) to its exit (:func:`finish`); nothing in between puts other handlers back.
Its rule: the exit code is the one of the status the logs record. A signal that comes once the logs
are being closed (or after ``ftstab run`` closed them) changes neither: it is ignored, with a note
on stderr ("completed" stays exit 0, "interrupted" stays 128 + the first signal).
"""

from __future__ import annotations

import signal
import sys
import threading
from contextlib import contextmanager

# Signals that stop a run like Ctrl-C (SIGHUP: the terminal was closed; SIGTERM: kill, timeout, CI).
SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


class Interrupted(KeyboardInterrupt):
    """The run was stopped by a signal. signum: its number; name: "SIGINT" | "SIGTERM" | "SIGHUP"."""

    def __init__(self, signum: int = signal.SIGINT):
        self.signum = int(signum)
        self.name = signal.Signals(self.signum).name
        super().__init__(self.name)

    @property
    def exit_code(self) -> int:
        """128 + the signal number (130 for Ctrl-C, 143 for SIGTERM, 129 for SIGHUP), as shells report it."""
        return 128 + self.signum

    @property
    def label(self) -> str:
        """ "interrupted" for Ctrl-C, "interrupted (SIGTERM)" for the others (the status users read)."""
        return "interrupted" if self.signum == signal.SIGINT else f"interrupted ({self.name})"


def interruption(exc: BaseException) -> Interrupted:
    """The Interrupted for an exception caught as KeyboardInterrupt (a bare one is a Ctrl-C)."""
    return exc if isinstance(exc, Interrupted) else Interrupted(signal.SIGINT)


# State of the main thread (Python delivers signals there only; off it, nothing here applies).
_depth = 0  # nesting of critical() blocks (main thread)
_pending: int | None = None  # a signal held by critical()
_stopping = False  # an Interrupted was raised: hold any further signal until the run ends
_last: int | None = None  # the signal last raised as Interrupted (the one that stopped the run)


def _handler(signum, frame):
    global _pending, _stopping, _last
    if _depth or _stopping:
        _pending = signum if _pending is None else _pending
        return
    _stopping, _last = True, signum
    raise Interrupted(signum)


def last_signal() -> Interrupted | None:
    """The signal last raised as Interrupted while :func:`handling` was in force (the one that
    stopped the run; a signal that came while the logs were being closed is not it), or None."""
    return None if _last is None else Interrupted(_last)


def hold() -> None:
    """The run is finishing (its last batch is in, or it is failing): from now until the end of
    :func:`run_scope` a signal is noted, never raised, so the logs are closed whole."""
    global _stopping
    if threading.current_thread() is threading.main_thread():
        _stopping = True


@contextmanager
def critical():
    """A block that a signal does not cut: one received inside is raised when the outermost block
    ends (unless the run is already being stopped, then it is only noted)."""
    global _depth, _pending, _stopping, _last
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _depth += 1
    try:
        yield
    finally:
        _depth -= 1
        if _depth == 0 and _pending is not None and not _stopping:
            signum, _pending = _pending, None
            _stopping, _last = True, signum
            raise Interrupted(signum)


@contextmanager
def handling(signals=SIGNALS, take_over: bool = False):
    """Signals of ``signals`` raise Interrupted (held inside :func:`critical`) for the block; the
    previous handlers are put back. Off the main thread (where Python delivers no signal) nothing
    is changed; an ignored signal (nohup, a background job) stays ignored; and, unless
    ``take_over`` (the ``ftstab`` command owns its process), so does a signal whose handler is not
    Python's default (a library caller's own)."""
    global _pending, _stopping, _last
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {}
    for s in signals:
        current = signal.getsignal(s)
        if current is _handler:
            continue  # already ours (the CLI's, around a run)
        if current is signal.SIG_IGN:
            continue  # ignored on purpose (nohup, a background job): stays ignored
        default = signal.default_int_handler if s == signal.SIGINT else signal.SIG_DFL
        if current is not default and not take_over:
            continue  # a library caller's own handler: theirs to keep
        previous[s] = signal.signal(s, _handler)
    if previous:
        _last = None  # a new command or run: no signal received yet
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
        if previous:  # the outermost: nothing of this command or run is left held
            _pending, _stopping = None, False


_scopes = 0  # nesting of run_scope() (main thread)


@contextmanager
def run_scope(final: bool = False):
    """Around one run: signals handled (see :func:`handling`; SIGINT for library callers), and,
    when the outermost scope ends, the "being stopped" state reset so that the next run starts
    afresh. A command that reports on its run wraps both in one scope, so that a signal coming
    once the run is over waits until the report is out (the exit code then is the run's).
    final: the command's last run (``ftstab run``): nothing is reset, signals stay held until the
    command ends (:func:`finish` in the ``ftstab`` process, the end of :func:`handling` in process),
    so that no signal after the logs are closed turns their status into another exit code."""
    global _pending, _stopping, _scopes
    main = threading.current_thread() is threading.main_thread()
    with handling((signal.SIGINT,)):
        _scopes += main
        try:
            yield
        finally:
            _scopes -= main
            if main and _scopes == 0 and not final:
                _pending, _stopping = None, False


def own_process(noted=()) -> None:
    """The ``ftstab`` command owns its process: from here until :func:`finish`, SIGINT, SIGTERM and
    SIGHUP raise Interrupted (held inside :func:`critical`), with no context to leave, so that
    nothing (not a collected generator, not the interpreter's shutdown) puts other handlers back.
    A signal ignored on purpose (nohup) stays ignored. noted: the signals that came before (the
    entry's first handler only notes them); the first is raised now."""
    global _stopping, _last
    for s in SIGNALS:
        if signal.getsignal(s) is not signal.SIG_IGN:
            signal.signal(s, _handler)
    if noted:
        _stopping, _last = True, int(noted[0])
        raise Interrupted(noted[0])


def finish(code: int) -> int:
    """The ``ftstab`` process has its exit code ``code``: from here a signal is ignored by the OS
    (Python's shutdown resets its own handlers to the default, which would kill the process with
    no word), and one held since the logs were being closed is noted on stderr. Returns code."""
    global _stopping
    _stopping = True  # a signal from here to the next line is held, not raised
    for s in SIGNALS:
        if signal.getsignal(s) is _handler:
            signal.signal(s, signal.SIG_IGN)
    if _pending is not None:
        try:
            print(f"note: {signal.Signals(_pending).name} came while the command was finishing: ignored "
                  f"(exit {code} stands)", file=sys.stderr)
        except (OSError, ValueError):  # the terminal is gone (SIGHUP) or stderr closed: nothing to tell
            pass
    return code

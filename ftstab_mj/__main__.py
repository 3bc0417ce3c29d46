"""``python -m ftstab_mj`` = the ``ftstab`` command."""

import signal
import sys

from ftstab_mj import interrupts

# The process's own: a signal stops the command like Ctrl-C from the start (the imports included),
# and once the command has returned its exit code a signal is only noted (the logs are closed and
# say how the run ended; the exit code stays the one of that status).
_signals = interrupts.handling(take_over=True)  # kept: a collected generator would put the handlers back
_signals.__enter__()
try:
    from ftstab_mj.cli import main

    code = main()
except KeyboardInterrupt as exc:
    print(f"error: {interrupts.interruption(exc).label}", file=sys.stderr)
    code = interrupts.interruption(exc).exit_code
for s in interrupts.SIGNALS:  # ignored at the OS level: Python's finalization resets its own handlers
    signal.signal(s, signal.SIG_IGN)
sys.exit(code)

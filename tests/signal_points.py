"""Send a signal to this process at one chosen point of a real ``ftstab`` process: deterministic
timing for the interruption tests (no sleep race). Imported by a ``sitecustomize.py`` the test puts
on the child's PYTHONPATH; ``FTSTAB_TEST_SIGNAL = "SIGNAME@POINT"`` chooses, POINT being

- ``import:MODULE``: as the import of MODULE starts (the audit event "import");
- ``after:MODULE:QUALNAME``: right after the function MODULE.QUALNAME returns (wrapped as MODULE
  is loaded), e.g. ``after:ftstab_mj.cli:main``;
- ``late-handler``: once the interpreter is exiting (atexit), right after any handler other than
  "ignore" is set for SIGNAME (what arrives then meets that handler).

Each sent signal is reported on stderr as ``[signal_points: sent SIGNAME at POINT]``.
"""

import atexit
import importlib.abc
import importlib.util
import os
import signal
import sys

SIG, _, POINT = os.environ["FTSTAB_TEST_SIGNAL"].partition("@")
SIGNUM = signal.Signals[SIG]


def send(where: str) -> None:
    os.write(2, f"[signal_points: sent {SIG} at {where}]\n".encode())
    os.kill(os.getpid(), SIGNUM)


if POINT.startswith("import:"):
    module = POINT.removeprefix("import:")
    fired = []

    def at_import(event, args):
        if event == "import" and args[0] == module and not fired:
            fired.append(True)
            send(POINT)

    sys.addaudithook(at_import)

elif POINT.startswith("after:"):
    module, qualname = POINT.removeprefix("after:").split(":")

    def wrap(mod):
        *owner_path, name = qualname.split(".")
        owner = mod
        for part in owner_path:
            owner = getattr(owner, part)
        real = getattr(owner, name)

        def wrapper(*args, **kwargs):
            result = real(*args, **kwargs)
            send(POINT)
            return result

        setattr(owner, name, wrapper)

    class AfterLoad(importlib.abc.MetaPathFinder):
        """Wraps the function once its module has run (the other finders find the module)."""

        def find_spec(self, name, path, target=None):
            if name != module:
                return None
            sys.meta_path.remove(self)
            spec = importlib.util.find_spec(name)
            real_exec = spec.loader.exec_module

            def exec_module(mod):
                real_exec(mod)
                wrap(mod)

            spec.loader.exec_module = exec_module
            return spec

    sys.meta_path.insert(0, AfterLoad())

elif POINT == "late-handler":
    real_signal = signal.signal
    exiting = []

    def watched(signum, handler):
        previous = real_signal(signum, handler)
        if exiting and signum == SIGNUM and handler is not signal.SIG_IGN:
            send(f"{POINT} ({handler!r} set at exit)")
        return previous

    signal.signal = watched
    atexit.register(exiting.append, True)  # registered first: runs after every other atexit function

else:
    raise SystemExit(f"signal_points: unknown point {POINT!r}")

"""Error hierarchy. Every user-facing error subclasses a builtin so callers can catch broadly.

Messages name the parameter (or key path), what is allowed, and what was given.
"""


class FtstabError(Exception):
    """Base of all ftstab_mj errors."""


class ParameterError(FtstabError, ValueError):
    """A controller or certificate parameter is out of its allowed range."""

    def __init__(self, name: str, allowed: str, given: object):
        self.name, self.allowed, self.given = name, allowed, given
        super().__init__(f"{name}: expected {allowed}, got {given!r}")


class ScenarioError(FtstabError, ValueError):
    """A scenario file (or a --set override) is malformed: one line with file, key path, expectation, finding."""

    def __init__(self, source: str, path: str, expected: str, found: str):
        self.source, self.path, self.expected, self.found = source, path, expected, found
        super().__init__(f"{source}: {path}: expected {expected}, found {found}")


class LogError(FtstabError, ValueError):
    """A run log cannot be written, or a file given as a log is not one (or is damaged beyond recovery)."""


class CallbackError(FtstabError, RuntimeError):
    """An exception raised inside the MuJoCo control callback (the controller), re-raised with the
    simulation time; the original exception is its __cause__."""


class SweepError(ScenarioError):
    """A sweep file (or a sweep output directory) is unusable: same one-line format as ScenarioError."""


class EngineError(FtstabError, RuntimeError):
    """The execution engine of a sweep cannot be started or reached (e.g. no Dask scheduler at an address)."""


class LogWriteError(FtstabError, RuntimeError):
    """A log could not be written during a run (disk full, quota, I/O error): not bad input (exit 1).
    path: the log file; cause: what went wrong, e.g. "cannot write the MCAP log: No space left on device"."""

    def __init__(self, path, cause: str):
        self.path, self.cause = str(path), cause
        super().__init__(f"{self.path}: {cause}")

"""Error hierarchy. Every user-facing error subclasses a builtin so callers can catch broadly.

Messages name the parameter (or key path), what is allowed, and what was given (:func:`describe`
shows a found value the way the user wrote it).
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


class UsageError(FtstabError, ValueError):
    """Bad input to a command or a study (an option, a combination of options): one line, exit 2."""


class LogError(FtstabError, ValueError):
    """A run log cannot be written, or a file given as a log is not one (or is damaged beyond recovery)."""


class CallbackError(FtstabError, RuntimeError):
    """An exception raised inside the MuJoCo control callback (the controller), re-raised with the
    simulation time; the original exception is its __cause__."""


class SweepError(ScenarioError):
    """A sweep file (or a sweep output directory) is unusable: same one-line format as ScenarioError."""


class EngineError(FtstabError, RuntimeError):
    """The execution engine of a sweep cannot be started or reached (e.g. no Dask scheduler at an address)."""


class PluginError(FtstabError, ValueError):
    """An installed plugin (entry point) that cannot be imported; a scenario's plugins raise ScenarioError."""


class LogWriteError(FtstabError, RuntimeError):
    """A log could not be written during a run (disk full, quota, I/O error): not bad input (exit 1).
    path: the log file; cause: what went wrong, e.g. "cannot write the MCAP log: No space left on device"."""

    def __init__(self, path, cause: str):
        self.path, self.cause = str(path), cause
        super().__init__(f"{self.path}: {cause}")


def counted(n: int, noun: str) -> str:
    """``n`` items in words, the noun singular for one: ``counted(1, "number")`` is "1 number"."""
    return f"{n} {noun}{'' if n == 1 else 's'}"


def describe(value) -> str:
    """A found value as the user wrote it, with its TOML type: ``1.5 (a float)``, ``'1.5' (a string)``;
    a string that reads as nothing else is shown in its quotes alone (``'abc'``)."""
    kind = {bool: "a boolean", int: "an integer", float: "a float", str: "a string", list: "an array",
            tuple: "an array", dict: "a table"}.get(type(value), type(value).__name__)
    if isinstance(value, (list, tuple, dict)):
        text = f"{len(value)} item(s)" if len(value) > 8 else _short(value)
    elif isinstance(value, bool):
        text = str(value).lower()
    elif isinstance(value, int) and abs(value) > 10 ** 30:  # its repr is as long as its digits (or refused)
        text = f"{'-' if value < 0 else ''}~2^{abs(value).bit_length() - 1}"
    else:
        text = repr(value)
    if len(text) > 60:
        text = text[:57] + "..."
    if isinstance(value, str) and not _reads_as_scalar(value):  # the quotes already say it is a string
        return text
    return f"{text} ({kind})"


def _reads_as_scalar(text: str) -> bool:
    """Whether a string reads as a number or a boolean ('1.0', 'inf', 'true'): its type is then the point."""
    if text.strip().lower() in ("true", "false"):
        return True
    try:
        float(text)
    except ValueError:
        return False
    return True


def _short(value) -> str:
    try:
        return repr(value)  # small containers only; depth is bounded before anything is described
    except RecursionError:  # pragma: no cover - check_structure refuses such data first
        return "(deeply nested)"

"""Creating a run's log files safely, and the one-line error of a log that cannot be written.

A log is created as a new file of a random name in its directory (``O_CREAT | O_EXCL``: never an
existing file, never through a symlink) and renamed onto its path (``os.replace`` replaces a
symlink planted there instead of writing through it). What is at the path before is replaced only
when it is one of our logs (an MCAP file written by ftstab_mj, a Rerun recording of the ftstab
application), an empty file, or with ``force``; anything else (another program's file, a
symlink, a directory) is refused with a one-line :class:`~ftstab_mj.config.errors.LogError` naming it.
"""

from __future__ import annotations

import errno
import functools
import io
import os
import secrets
import select
import stat
import struct
import threading
import time

from ftstab_mj.config.errors import LogError, LogWriteError

MCAP_MAGIC = b"\x89MCAP0\r\n"
RRD_MAGIC = b"RRF2"
LIBRARY = "ftstab_mj"  # the MCAP header's library field starts with it in our logs
RRD_APPLICATION = b"ftstab"  # the application id of our Rerun recordings (in their first bytes)


def _is_our_mcap(head: bytes) -> bool:
    """An MCAP whose Header record (opcode 1, right after the magic) names ftstab_mj as its library."""
    if not head.startswith(MCAP_MAGIC) or len(head) < 9 + 8 + 4 or head[8] != 0x01:
        return False
    at = 9 + 8
    (n,) = struct.unpack_from("<I", head, at)  # the profile string
    at += 4 + n
    if len(head) < at + 4:
        return False
    (n,) = struct.unpack_from("<I", head, at)  # the library string
    return head[at + 4:at + 4 + n].decode("utf-8", "replace").startswith(LIBRARY)


def existing(path) -> str | None:
    """What is at ``path`` that a new log must not replace without ``force``, as words ("a symbolic
    link to ...", "a directory", "a file that is not an ftstab log (N bytes)"), or None when nothing
    is there, or one of our logs, or an empty file."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return None
    if stat.S_ISLNK(st.st_mode):
        return f"a symbolic link (to {os.readlink(path)})"
    if stat.S_ISDIR(st.st_mode):
        return "a directory"
    if not stat.S_ISREG(st.st_mode):
        return "a special file (not a regular file)"
    if st.st_size == 0:
        return None
    try:
        with open(path, "rb") as f:
            head = f.read(4096)
    except OSError as exc:
        return f"a file that cannot be read ({exc.strerror})"
    if _is_our_mcap(head) or (head.startswith(RRD_MAGIC) and RRD_APPLICATION in head):
        return None
    return f"a file that is not an ftstab log ({st.st_size} bytes)"


def check_replaceable(path, force: bool = False, option: str = "--force") -> None:
    """LogError (one line) when creating a log at ``path`` would replace what must not be replaced."""
    found = existing(path)
    if found is None or (force and found != "a directory"):
        return
    hint = "" if found == "a directory" else f" ({option} replaces it)"
    raise LogError(f"{path}: expected no file or an ftstab log there, found {found}; not overwritten{hint}")


class LogFile(io.FileIO):
    """An unbuffered log file whose writes are whole (a short write, as a filling disk gives, is
    continued, so an error is always raised, never a silently cut record) and whose flush checks
    that the file is still in its directory (a log removed under the run is an error, not a run
    writing into a file nobody will see)."""

    def write(self, data) -> int:
        view = memoryview(data).cast("B")
        while view:
            view = view[super().write(view):]
        return len(data)

    def flush(self) -> None:
        super().flush()
        if os.fstat(self.fileno()).st_nlink == 0:
            raise OSError(errno.ENOENT, "the file was removed during the run")


def create_log(path, force: bool = False, what: str = "log") -> LogFile:
    """A new binary file at ``path``, opened for writing, created as the module docstring says."""
    path = os.fspath(path)
    check_replaceable(path, force)
    folder, name = os.path.split(os.path.abspath(path))
    tmp = os.path.join(folder, f".{name}.{secrets.token_hex(4)}.tmp")
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
    except OSError as exc:
        raise LogError(f"{path}: cannot write the {what} ({exc.strerror})") from None
    try:
        os.replace(tmp, path)
    except OSError as exc:
        os.close(fd)
        os.unlink(tmp)
        raise LogError(f"{path}: cannot write the {what} ({exc.strerror})") from None
    return LogFile(fd, "wb")


def discard(path) -> None:
    """Remove a log this process has just created and could not open whole (no half-opened log)."""
    try:
        os.unlink(path)
    except OSError:
        pass  # already gone, or the directory went: nothing of ours is left to remove


def write_error(path, what: str, exc: OSError) -> LogWriteError:
    """The error of a log that could not be written (disk full, quota, I/O error)."""
    return LogWriteError(path, f"cannot write the {what}: {exc.strerror or exc}")


def write_errors(what: str):
    """Decorator of a sink method: an OSError while writing becomes the one-line LogWriteError
    naming the sink's ``path`` and the cause."""

    def decorate(method):
        @functools.wraps(method)
        def wrapper(self, *args, **kwargs):
            try:
                return method(self, *args, **kwargs)
            except OSError as exc:
                raise write_error(self.path, what, exc) from None

        return wrapper

    return decorate


class Pump:
    """A pipe whose bytes a thread copies into ``file`` (a LogFile), for a writer that must never
    meet a write error itself: Rerun's file writer (rerun-sdk 0.41) stops at one (disk full) and
    then every later flush of the recording, and the exit of the process, waits for ever (measured
    on a full tmpfs). Here the error is kept in :attr:`error` for the sink to raise, and the pipe
    keeps being drained (the rest discarded), so the writer never blocks.

    ``target``: the path the writer opens (/proc/self/fd/N of the pipe's write end; call
    :meth:`writer_opened` once it has). :meth:`sync`: wait until every byte written so far is in
    the file. POSIX with /proc (Linux) only: see :func:`can_pump`.
    """

    def __init__(self, file):
        self.file = file
        self.error: OSError | None = None
        self._r, self._w = os.pipe()
        self.target = f"/proc/self/fd/{self._w}"
        self._lock = threading.Lock()  # held while bytes are out of the pipe but not yet in the file
        self._thread = threading.Thread(target=self._copy, name=f"log pump {file.name}", daemon=True)
        self._thread.start()

    def writer_opened(self) -> None:
        """The writer has its own descriptor of the pipe: ours goes (so its close ends the copy)."""
        os.close(self._w)
        self._w = None

    def _copy(self) -> None:
        while True:
            select.select([self._r], [], [])
            with self._lock:
                data = os.read(self._r, 1 << 20)
                if not data:
                    return  # the writer closed its end
                if self.error is None:
                    try:
                        self.file.write(data)
                    except OSError as exc:
                        self.error = exc

    def _unread(self) -> int:
        import array
        import fcntl
        import termios

        buf = array.array("i", [0])
        fcntl.ioctl(self._r, termios.FIONREAD, buf)
        return buf[0]

    def sync(self) -> OSError | None:
        """Wait until the bytes the writer has written are in the file (and the file still in its
        directory); the first write error, or None."""
        while True:
            with self._lock:
                if not self._thread.is_alive() or self._unread() == 0:
                    if self.error is None:
                        try:
                            self.file.flush()
                        except OSError as exc:
                            self.error = exc
                    return self.error
            time.sleep(0.0005)

    def close(self) -> OSError | None:
        """After the writer closed its end: the copy ends, the file is closed; the first error."""
        if self._w is not None:
            os.close(self._w)
        self._thread.join()
        os.close(self._r)
        try:
            self.file.close()
        except OSError as exc:
            self.error = self.error or exc
        return self.error


def can_pump() -> bool:
    """Whether :class:`Pump` works here (a /proc/self/fd to reopen a pipe by path, FIONREAD)."""
    try:
        import fcntl  # noqa: F401
        import termios

        return hasattr(termios, "FIONREAD") and os.path.isdir("/proc/self/fd")
    except ImportError:
        return False


RESERVE_BYTES = 64 * 1024  # room kept for a log's closing records (its /metrics status and summary)


class Reserve:
    """A hidden file of RESERVE_BYTES beside a log, taken at its opening and given back just before
    it is closed: on a disk that filled up during the run, the log can still record how the run
    ended ("failed: cannot write ...: No space left on device")."""

    def __init__(self, log_path):
        folder, name = os.path.split(os.path.abspath(os.fspath(log_path)))
        self.path = os.path.join(folder, f".{name}.{secrets.token_hex(4)}.reserve.tmp")
        fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o600)
        try:
            if hasattr(os, "posix_fallocate"):
                os.posix_fallocate(fd, 0, RESERVE_BYTES)
            else:
                os.write(fd, bytes(RESERVE_BYTES))
        except OSError:
            pass  # no room even for it: the log goes on without a reserve
        finally:
            os.close(fd)

    def release(self) -> None:
        try:
            os.unlink(self.path)
        except FileNotFoundError:
            pass

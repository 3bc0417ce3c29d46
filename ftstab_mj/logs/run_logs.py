"""The logs of one run (``<name>.mcap`` for Foxglove and replay, and, when asked, ``<name>.rrd`` for
Rerun) in an output directory: the one place their paths are made and checked, and their sinks built.

``ftstab run``, :func:`ftstab_mj.run` and a sweep row write the MCAP log only unless asked (``--rrd``,
``rrd=True``; importing rerun-sdk and writing the recording cost more CPU than the physics:
docs/performance.md); ``ftstab view LOG`` makes the same ``.rrd`` from the MCAP log when the user wants to look.

``ftstab run``, :func:`ftstab_mj.run` (api.py) and a sweep row's logs (studies/sweep/row.py) all call
:func:`open_run_logs`. Every check happens there, before any file is written and before any live
viewer starts (the caller builds the sinks with :meth:`RunLogs.sinks` once its live view is up): the
directory is one (or is made), and each log path is a writable file or nothing, and holds nothing that
must not be replaced (files.check_replaceable: another program's file, a symbolic link; not without
``force``). Each refusal is one :class:`~ftstab_mj.config.errors.LogError` line (bad input, exit 2).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from ftstab_mj.config.errors import LogError
from ftstab_mj.config.validate import identifier
from ftstab_mj.logs.files import check_replaceable


@dataclass
class RunLogs:
    """The checked paths of a run's logs (``mcap``; ``rrd``, None when not asked) and, once :meth:`sinks`
    built them, their sinks (:attr:`built`: McapSink[, RerunSink], in the order of :attr:`paths`, then a
    RerunSink streaming to the live viewer only when there is no ``.rrd``)."""

    mcap: Path
    rrd: Path | None
    force: bool = False
    built: tuple = field(default=(), repr=False)

    @property
    def paths(self) -> tuple[Path, ...]:
        return (self.mcap,) if self.rrd is None else (self.mcap, self.rrd)

    def sinks(self, live=None, grpc_port: int = 9876) -> tuple:
        """McapSink and RerunSink writing :attr:`paths` (rerun-sdk imported only when a RerunSink is
        built). ``live``: a logs.live.LiveView whose Foxglove server and Rerun target the sinks also
        stream to (None: the logs only); ``grpc_port``: the port of a Rerun viewer the RerunSink
        spawns. Built once; later calls return the same sinks."""
        if not self.built:
            from ftstab_mj.logs.mcap_sink import McapSink

            foxglove, rerun = (live.foxglove, live.rerun) if live is not None else (None, None)
            built = [McapSink(self.mcap, force=self.force, live=foxglove)]
            if self.rrd is not None or rerun is not None:
                from ftstab_mj.logs.rerun_sink import RerunSink

                built.append(RerunSink(self.rrd, force=self.force, live=rerun, grpc_port=grpc_port))
            self.built = tuple(built)
        return self.built


def open_run_logs(out_dir, name: str, *, force: bool = False, what: str | None = None, rrd: bool = False) -> RunLogs:
    """The logs ``out_dir/<name>.mcap`` and (``rrd``) ``.rrd`` of one run, checked; ``out_dir`` is made if absent.

    Raises LogError (one line, prefixed by ``what``, by default the directory's path; ``ftstab run``
    passes "--out DIR") when ``name`` is not a file name (``../escape``: a Scenario built by hand skips the
    loader's check, and a log must never be written outside ``out_dir``), when ``out_dir`` is a file or cannot be made, when a log path is a directory
    or a read-only file, and (files.check_replaceable) when it holds what must not be replaced unless
    ``force``. Both paths are checked before either is written: bad input leaves no log behind.
    """
    out = Path(out_dir)
    what = str(out_dir) if what is None else what
    bad = identifier(name) if isinstance(name, str) else "a string"
    if bad:
        raise LogError(f"{what}: the scenario name: expected {bad}, found {str(name)[:80]!r}")
    if out.exists() and not out.is_dir():
        raise LogError(f"{what}: expected a directory for the logs, found a file")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise LogError(f"{what}: expected a directory the logs can be written in, found {exc.strerror}") from None
    logs = RunLogs(out / f"{name}.mcap", out / f"{name}.rrd" if rrd else None, force)
    for path in logs.paths:
        if path.is_dir() or (path.exists() and not os.access(path, os.W_OK)):
            raise LogError(f"{what}: expected {path.name} to be a writable file, found "
                           + ("a directory" if path.is_dir() else "a read-only file"))
        check_replaceable(path, force)  # a symlink or another program's file: not without force
    return logs

"""The two logs of one run (``<name>.mcap`` for Foxglove, ``<name>.rrd`` for Rerun) in an output
directory: the one place their paths are made and checked, and their sinks built.

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
from ftstab_mj.logs.files import check_replaceable


@dataclass
class RunLogs:
    """The checked paths of a run's logs (``mcap``, ``rrd``) and, once :meth:`sinks` built them, their
    sinks (:attr:`built`: McapSink, RerunSink, in the order of :attr:`paths`)."""

    mcap: Path
    rrd: Path
    force: bool = False
    built: tuple = field(default=(), repr=False)

    @property
    def paths(self) -> tuple[Path, Path]:
        return self.mcap, self.rrd

    def sinks(self, live=None, grpc_port: int = 9876) -> tuple:
        """(McapSink, RerunSink) writing :attr:`paths`. ``live``: a logs.live.LiveView whose Foxglove
        server and Rerun target the sinks also stream to (None: the logs only); ``grpc_port``: the
        port of a Rerun viewer the RerunSink spawns. Built once; later calls return the same sinks."""
        if not self.built:
            from ftstab_mj.logs.mcap_sink import McapSink
            from ftstab_mj.logs.rerun_sink import RerunSink

            foxglove, rerun = (live.foxglove, live.rerun) if live is not None else (None, None)
            self.built = (McapSink(self.mcap, force=self.force, live=foxglove),
                          RerunSink(self.rrd, force=self.force, live=rerun, grpc_port=grpc_port))
        return self.built


def open_run_logs(out_dir, name: str, *, force: bool = False, what: str | None = None) -> RunLogs:
    """The logs ``out_dir/<name>.mcap`` and ``.rrd`` of one run, checked; ``out_dir`` is made if absent.

    Raises LogError (one line, prefixed by ``what``, by default the directory's path; ``ftstab run``
    passes "--out DIR") when ``out_dir`` is a file or cannot be made, when a log path is a directory
    or a read-only file, and (files.check_replaceable) when it holds what must not be replaced unless
    ``force``. Both paths are checked before either is written: bad input leaves no log behind.
    """
    out = Path(out_dir)
    what = str(out_dir) if what is None else what
    if out.exists() and not out.is_dir():
        raise LogError(f"{what}: expected a directory for the logs, found a file")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise LogError(f"{what}: expected a directory the logs can be written in, found {exc.strerror}") from None
    logs = RunLogs(out / f"{name}.mcap", out / f"{name}.rrd", force)
    for path in logs.paths:
        if path.is_dir() or (path.exists() and not os.access(path, os.W_OK)):
            raise LogError(f"{what}: expected {path.name} to be a writable file, found "
                           + ("a directory" if path.is_dir() else "a read-only file"))
        check_replaceable(path, force)  # a symlink or another program's file: not without force
    return logs

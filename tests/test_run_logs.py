"""logs.run_logs.open_run_logs: the one place a run's log paths are made and checked (ftstab run,
ftstab_mj.run, a sweep row's logs)."""

import os

import pytest

from ftstab_mj.config.errors import LogError
from ftstab_mj.logs import McapSink, RerunSink
from ftstab_mj.logs.run_logs import open_run_logs


def test_paths_and_sinks(tmp_path):
    only = open_run_logs(tmp_path / "a" / "b", "demo")  # the directory is made; the MCAP log unless asked
    assert only.paths == (tmp_path / "a" / "b" / "demo.mcap",) and only.rrd is None
    assert [type(s) for s in only.sinks()] == [McapSink]
    logs = open_run_logs(tmp_path / "a" / "b", "demo", rrd=True)
    assert logs.paths == (tmp_path / "a" / "b" / "demo.mcap", tmp_path / "a" / "b" / "demo.rrd")
    assert (tmp_path / "a" / "b").is_dir() and not logs.mcap.exists() and not logs.rrd.exists()
    mcap, rrd = logs.sinks()
    assert isinstance(mcap, McapSink) and isinstance(rrd, RerunSink)
    assert (mcap.path, rrd.path) == (str(logs.mcap), str(logs.rrd)) and not mcap.force and mcap.live is None
    assert logs.sinks() == (mcap, rrd)  # built once


def test_live_targets_and_force_reach_the_sinks(tmp_path):
    class View:
        foxglove, rerun = object(), "rerun+http://127.0.0.1:1/proxy"

    view = View()
    mcap, rrd = open_run_logs(tmp_path, "demo", force=True).sinks(view, grpc_port=1234)
    assert mcap.live is view.foxglove and rrd.live == view.rerun and rrd.grpc_port == 1234
    assert mcap.force and rrd.force


def test_a_file_as_directory(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(LogError, match=r"^--out f: expected a directory for the logs, found a file$"):
        open_run_logs(tmp_path / "f", "demo", what="--out f")
    with pytest.raises(LogError, match=r"^.*/f: expected a directory for the logs, found a file$"):
        open_run_logs(tmp_path / "f", "demo")  # named by its path by default


def test_a_directory_cannot_be_made(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(LogError, match="expected a directory the logs can be written in, found Not a directory"):
        open_run_logs(tmp_path / "f" / "sub", "demo")


def test_log_paths_refused_before_either_is_written(tmp_path):
    (tmp_path / "demo.rrd").mkdir()
    assert open_run_logs(tmp_path, "demo").rrd is None  # not asked for: not looked at
    with pytest.raises(LogError, match=r": expected demo.rrd to be a writable file, found a directory$"):
        open_run_logs(tmp_path, "demo", rrd=True)
    assert not (tmp_path / "demo.mcap").exists()
    os.rmdir(tmp_path / "demo.rrd")
    (tmp_path / "demo.mcap").write_text("not a log")
    with pytest.raises(LogError, match=r"found a file that is not an ftstab log .*--force replaces it"):
        open_run_logs(tmp_path, "demo")
    assert open_run_logs(tmp_path, "demo", force=True).force  # force: replaced when the run opens it
    if os.geteuid() != 0:  # root writes a read-only file anyway
        os.chmod(tmp_path / "demo.mcap", 0o444)
        with pytest.raises(LogError, match=r"expected demo.mcap to be a writable file, found a read-only file"):
            open_run_logs(tmp_path, "demo", force=True)

"""Faults at the edges of a run: a callback of the caller's, a planted symlink, a log without samples."""

import os

import mujoco
import numpy as np
import pytest

from conftest import ROOT, run_cli
from test_interruptions import _rrd_rows
from ftstab_mj.logs import McapSink, RerunSink
from ftstab_mj.logs.reader import read_log
from ftstab_mj.logs.rerun_sink import write_rrd
from ftstab_mj.logs.scene import model_shapes
from ftstab_mj.scenario.run import verify_log
from ftstab_mj.metrics.run_metrics import compute_metrics
from ftstab_mj.plants import make_plant
from ftstab_mj.simulation.records import COMPLETED
from ftstab_mj.scenario import load_scenario
from ftstab_mj.scenario.run import run_scenario
from synthetic_runs import synthetic_run, write_run


class CallersCallback:
    """A Python control callback of the caller's, installed before calling us; it raises if MuJoCo
    ever calls it (a compile under it fails with "engine error: Python exception raised")."""

    def __init__(self):
        self.calls = 0

    def __call__(self, m, d):
        self.calls += 1
        raise RuntimeError("the caller's callback was called")


@pytest.fixture
def callers_callback():
    cb = CallersCallback()
    mujoco.set_mjcb_control(cb)
    try:
        yield cb
    finally:
        mujoco.set_mjcb_control(None)


def test_every_entry_point_that_compiles_a_model_does_it_with_the_callback_cleared(tmp_path, callers_callback):
    info, loops, pos, quat = synthetic_run("robust", params={"phibar": 0.5, "gamma_m": 0.8}, duration=0.2)
    metrics = compute_metrics(info, loops, COMPLETED)
    assert model_shapes(info.model_xml, info.body_names)  # the viewers' shapes (both sinks)
    assert mujoco.get_mjcb_control() is callers_callback
    for sink, name in ((McapSink(tmp_path / "a.mcap"), "sink"), (RerunSink(tmp_path / "a.rrd"), "sink")):
        write_run(sink, info, loops, pos, quat, COMPLETED, metrics, batch=100)
    write_rrd(tmp_path / "b.rrd", info, loops, (np.empty(0), pos[:0], quat[:0]), COMPLETED, metrics)  # replay --rrd
    make_plant("arm").compile(0.001)
    sc = load_scenario(ROOT / "scenarios" / "cart_r2_robust.toml", ["sim.duration=0.05"])
    run_scenario(sc, (McapSink(tmp_path / "c.mcap"), RerunSink(tmp_path / "c.rrd")))  # ftstab run
    assert verify_log(read_log(tmp_path / "c.mcap")).ok  # replay --verify
    assert mujoco.get_mjcb_control() is callers_callback and callers_callback.calls == 0


def test_every_model_compile_in_the_package_is_inside_a_cleared_callback_block():
    """The same rule, for the code to come: every MjModel.from_xml_* / MjSpec.compile() / to_xml()
    call of the package sits lexically inside ``with control_callback(None):``."""
    import ast

    compiling = {"from_xml_string", "from_xml_path", "from_binary_path", "to_xml"}
    bare = []
    for path in sorted((ROOT / "ftstab_mj").rglob("*.py")):
        tree = ast.parse(path.read_text(), str(path))

        def visit(node, cleared):
            if isinstance(node, ast.With):
                cleared = cleared or any(
                    isinstance(it.context_expr, ast.Call) and getattr(it.context_expr.func, "id", "") == "control_callback"
                    and len(it.context_expr.args) == 1 and isinstance(it.context_expr.args[0], ast.Constant)
                    and it.context_expr.args[0].value is None for it in node.items)
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and not cleared:
                name = node.func.attr
                if name in compiling or (name == "compile" and not node.args and not node.keywords):
                    bare.append(f"{path.relative_to(ROOT)}:{node.lineno} {name}")
            for child in ast.iter_child_nodes(node):
                visit(child, cleared)

        visit(tree, False)
    assert bare == []


def test_check_on_a_log_without_samples_says_so_and_exits_1(tmp_path):
    """A run interrupted before its first sample leaves a valid log of 0 samples: `check` says the
    log has no samples (exit 1: the expectations cannot hold), not that the expectation file is bad."""
    info, loops, pos, quat = synthetic_run("robust", params={"phibar": 0.5, "gamma_m": 0.8}, duration=0.2)
    empty = {k: {f: a[:0] for f, a in v.items()} for k, v in loops.items()}
    path = tmp_path / "empty.mcap"
    write_run(McapSink(path), info, empty, pos[:0], quat[:0], "interrupted",
              compute_metrics(info, empty, "interrupted"), batch=100)
    res = run_cli("check", path, "--expect", ROOT / "tests" / "expected" / "cart_r2_robust.toml")
    assert res.returncode == 1 and res.stderr == ""
    assert res.stdout == (f"{path}: the log has no samples (run interrupted: no message), so loops.cart.z0 of "
                          f"{ROOT / 'tests' / 'expected' / 'cart_r2_robust.toml'} cannot be checked; "
                          "1 loop(s), 0 samples each\n")
    # a file pinning only what a run without samples has still passes (tests/test_check.py)
    (tmp_path / "count.toml").write_text('status = "interrupted"\nn_samples = 0\n')
    assert run_cli("check", path, "--expect", tmp_path / "count.toml").returncode == 0
    # and a malformed expectation file is still bad input
    (tmp_path / "bad.toml").write_text("n_samples = {valu = 0}\n")
    assert run_cli("check", path, "--expect", tmp_path / "bad.toml").returncode == 2


# -- 18.2: a planted symlink, a file that is not a log ---------------------------------------------
def test_a_symlink_planted_at_the_log_path_is_never_followed(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    target = tmp_path / "precious.txt"
    target.write_text("not yours\n")
    (out / "cart_r2_robust.mcap").symlink_to(target)
    res = run_cli("run", "cart_r2_robust", "--out", out, "--set", "sim.duration=0.2", "--rrd")
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and "Traceback" not in res.stderr
    assert (f"error: {out / 'cart_r2_robust.mcap'}: expected no file or an ftstab log there, found a symbolic link "
            f"(to {target}); not overwritten (--force replaces it)") == res.stderr.strip()
    assert not (out / "cart_r2_robust.rrd").exists()  # nothing written for a refused run
    res = run_cli("run", "cart_r2_robust", "--out", out, "--set", "sim.duration=0.2", "--force")
    assert res.returncode == 0, res.stderr
    log = out / "cart_r2_robust.mcap"
    assert not log.is_symlink() and read_log(log).n_samples == 200  # the link replaced, not written through
    assert target.read_text() == "not yours\n"


def test_a_file_that_is_not_a_log_is_not_overwritten_without_force_and_our_logs_are(tmp_path):
    (tmp_path / "cart_r2_robust.rrd").write_text("my notes\n")
    res = run_cli("run", "cart_r2_robust", "--out", tmp_path, "--set", "sim.duration=0.2", "--rrd")
    assert res.returncode == 2 and "found a file that is not an ftstab log (9 bytes)" in res.stderr
    assert (tmp_path / "cart_r2_robust.rrd").read_text() == "my notes\n"
    assert not (tmp_path / "cart_r2_robust.mcap").exists()
    assert run_cli("run", "cart_r2_robust", "--out", tmp_path, "--set", "sim.duration=0.2", "--force",
                   "--rrd").returncode == 0
    # our own logs of an earlier run are replaced without --force (a run again in the same DIR)
    again = run_cli("run", "cart_r2_robust", "--out", tmp_path, "--set", "sim.duration=0.3", "--rrd")
    assert again.returncode == 0, again.stderr
    assert read_log(tmp_path / "cart_r2_robust.mcap").n_samples == 300
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cart_r2_robust.mcap", "cart_r2_robust.rrd"]  # no temp left


# -- 18.1: a write error (disk full) ------------------------------------------------------------------
@pytest.fixture
def small_disk(tmp_path):
    """A 400 KiB tmpfs the test mounts (root; skipped where mounting is not allowed: the fake-disk
    test below covers the same paths everywhere)."""
    import subprocess

    mnt = tmp_path / "disk"
    mnt.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=400k", "tmpfs", str(mnt)], capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs here (not root?)")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def _check_full_disk_outcome(code, stderr, out, name="cart_r2_robust"):
    """One line naming the file and the cause, exit 1; what it says of the logs is what they hold."""
    assert code == 1 and stderr.count("\n") == 1 and "Traceback" not in stderr, stderr
    assert stderr.startswith(f"error: run failed: {out}/{name}.") and "No space left on device" in stderr, stderr
    mcap = out / f"{name}.mcap"
    if not mcap.exists():  # the disk was full before the log was opened: no half-opened log
        assert f"{mcap} was not written" in stderr, stderr
        return None
    log = read_log(mcap)  # readable up to its last complete batch whatever happened
    if f"logs closed with status failed: {mcap}" in stderr:
        assert log.recorded["status"] == "failed" and "No space left on device" in log.recorded["message"]
    else:
        assert log.recorded is None and f"{mcap} ends at its last complete batch, without a status" in stderr
    return log


def test_a_full_disk_ends_the_run_with_one_line_and_logs_that_say_what_they_hold(small_disk):
    res = run_cli("run", "cart_r2_robust", "--out", small_disk, "--set", "sim.duration=60", timeout=120)
    log = _check_full_disk_outcome(res.returncode, res.stderr.replace("\r", ""), small_disk)
    assert 0 < log.n_samples < 60_000


@pytest.mark.parametrize("limit", [3_000, 40_000, 150_000, 260_000])
def test_a_disk_that_fills_at_a_chosen_byte(tmp_path, capsys, monkeypatch, limit):
    """The same through a fake: every log write past ``limit`` bytes (both logs together) fails with
    ENOSPC, as a full disk does, and frees nothing."""
    import errno

    from ftstab_mj.cli import main
    from ftstab_mj.logs import files

    written = [0]
    real_write = files.LogFile.write

    def write(self, data):
        if written[0] + len(data) > limit:
            raise OSError(errno.ENOSPC, "No space left on device")
        written[0] += len(data)
        return real_write(self, data)

    monkeypatch.setattr(files.LogFile, "write", write)
    monkeypatch.setattr(files, "RESERVE_BYTES", 0)  # the fake counts log bytes only
    code = main(["run", "cart_r2_robust", "--out", str(tmp_path), "--set", "sim.duration=20"])
    _check_full_disk_outcome(code, capsys.readouterr().err, tmp_path)


class FullDisk:
    """A disk of ``free`` bytes holding the MCAP log and its reserve (the .rrd is elsewhere): a write
    past the room writes what fits and fails with ENOSPC, as a full disk does; cutting the file back
    and deleting the reserve give their bytes back. sizes: the log's size after each complete flush."""

    def __init__(self, monkeypatch, free):
        import errno

        from ftstab_mj.logs import files, mcap_sink

        disk = self
        self.free, self.sizes = free, []

        class OnDisk(files.LogFile):
            def write(self, data):
                view = memoryview(data).cast("B")
                grow = max(0, self.tell() + len(view) - os.fstat(self.fileno()).st_size)
                if grow > disk.free:
                    fit = len(view) - (grow - disk.free)
                    super().write(view[:fit])
                    disk.free -= grow - (len(view) - fit)
                    raise OSError(errno.ENOSPC, "No space left on device")
                disk.free -= grow
                return super().write(view)

            def truncate(self, size=None):
                disk.free += max(0, os.fstat(self.fileno()).st_size - size)
                return super().truncate(size)

            def flush(self):
                super().flush()
                disk.sizes.append(os.fstat(self.fileno()).st_size)

        class Reserve:
            def __init__(self, log_path):
                self.held = min(files.RESERVE_BYTES, disk.free)
                disk.free -= self.held

            def release(self):
                disk.free, self.held = disk.free + self.held, 0

        def create_log(path, force=False, what="log"):
            f = files.create_log(path, force, what)
            f.__class__ = OnDisk
            return f

        monkeypatch.setattr(mcap_sink, "create_log", create_log)
        monkeypatch.setattr(mcap_sink, "Reserve", Reserve)


def test_an_mcap_batch_that_fills_the_disk_is_cut_back_and_the_log_records_failed(tmp_path, capsys, monkeypatch):
    """The disk fills in the middle of a batch (the first, the third, the fifth and last): the batch
    is cut back, and the room of the reserve lets the log record "failed" and the cause after its
    last complete batch, with a summary that indexes what it holds; the .rrd holds the same samples
    and is closed "failed" too. A disk the last batch fills: the reserve holds the closing records."""
    from collections import Counter

    from mcap.reader import make_reader

    from ftstab_mj.cli import main

    argv = ["run", "cart_r2_robust", "--set", "sim.duration=5", "--rrd"]  # 5 batches of 1000 samples
    ref = FullDisk(monkeypatch, 1 << 40)
    assert main([*argv, "--out", str(tmp_path / "ref")]) == 0
    capsys.readouterr()
    opened, batches = ref.sizes[1], ref.sizes[2:7]  # after the metadata, the opening, each batch
    reserve = 64 * 1024
    cases = [(reserve + (opened + batches[0]) // 2, 0), (reserve + (batches[1] + batches[2]) // 2, 2000),
             (reserve + (batches[3] + batches[4]) // 2, 4000),
             (reserve + batches[4] + 10, None)]  # the last batch fills the disk: the reserve holds the closing
    static = _rrd_rows(tmp_path / "ref" / "cart_r2_robust.rrd", "/loop/cart/V1/log10_V1") - 5000
    for k, (free, kept) in enumerate(cases):
        out = tmp_path / f"full{k}"
        FullDisk(monkeypatch, free)
        code = main([*argv, "--out", str(out)])
        err = capsys.readouterr().err
        mcap, rrd = out / "cart_r2_robust.mcap", out / "cart_r2_robust.rrd"
        log = read_log(mcap)
        assert log.complete and _rrd_rows(rrd, "/loop/cart/V1/log10_V1") - static == log.n_samples, k
        if kept is None:
            assert code == 0 and log.recorded["status"] == "completed" and log.n_samples == 5000, err
            continue
        assert code == 1 and err.count("\n") == 1 and "Traceback" not in err, err
        assert err == (f"error: run failed: {mcap}: cannot write the MCAP log: No space left on device "
                       f"(logs closed with status failed: {mcap}, {rrd})\n")
        assert log.recorded["status"] == "failed" and log.n_samples == kept, (k, log.recorded, log.n_samples)
        assert log.recorded["message"] == f"{mcap}: cannot write the MCAP log: No space left on device"
        with open(mcap, "rb") as f:  # its summary (chunk indexes, statistics) is the one of what it holds
            reader = make_reader(f)
            counts = reader.get_summary().statistics.channel_message_counts
            seen = Counter(channel.topic for _, channel, _ in reader.iter_messages())
        assert seen["/loop/cart"] == kept and sum(seen.values()) == sum(counts.values()), (seen, counts)

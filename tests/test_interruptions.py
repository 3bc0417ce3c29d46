"""Interruptions through the real CLI: SIGTERM and SIGHUP finish a run like Ctrl-C (logs closed,
status interrupted, exit 128 + signal), and an interrupted ``replay --verify`` says "interrupted",
never that the log differs."""

import signal
import threading
import time

import numpy as np
import pytest

from conftest import ROOT, run_cli, start_cli
from ftstab_mj.cli import main
from ftstab_mj.logs.reader import read_log


def wait_for_samples(log, size=200_000, timeout=120):
    deadline = time.monotonic() + timeout
    while (not log.exists() or log.stat().st_size < size) and time.monotonic() < deadline:
        time.sleep(0.05)  # until samples are being written (the run has started)


@pytest.mark.parametrize("sig, code", [(signal.SIGTERM, 143), (signal.SIGHUP, 129)])
def test_sigterm_and_sighup_finish_the_run_like_ctrl_c(tmp_path, sig, code):
    proc = start_cli("run", "cart_r2_robust", "--out", tmp_path, "--set", "sim.duration=3600")
    log = tmp_path / "cart_r2_robust.mcap"
    wait_for_samples(log)
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=120)
    name = signal.Signals(sig).name
    assert proc.returncode == code, err
    assert f"error: run interrupted ({name})" in err and "Traceback" not in err
    data = read_log(log)
    assert data.complete and data.recorded["status"] == "interrupted" and data.recorded["metrics"]
    assert 0 < data.n_samples < 3_600_000
    replay = run_cli("replay", log)
    assert replay.returncode == 0 and "recorded metrics: identical" in replay.stdout


def main_with_ctrl_c_at(delay, argv):
    """main(argv) with a SIGINT sent to this process ``delay`` s after the start (from a thread),
    Python's own SIGINT handler in force as for any program; (exit code, or "late" when the signal
    came after main returned)."""
    import os

    saved = signal.signal(signal.SIGINT, signal.default_int_handler)
    timer = threading.Timer(delay, os.kill, (os.getpid(), signal.SIGINT))
    code = "late"
    try:
        try:
            timer.start()
            code = main(argv)
            timer.join()
            time.sleep(0.05)  # a signal sent just now is handled here
        except KeyboardInterrupt:
            if code != "late":
                code = "late"
            else:
                raise
    finally:
        timer.join()
        signal.signal(signal.SIGINT, saved)
    return code


def test_an_interrupted_replay_verify_says_interrupted_never_differs(tmp_path, capsys):
    """Ctrl-C at seeded moments over the whole `replay --verify` (reading the log, the re-run, the
    comparison): exit 130 with "verify interrupted", or exit 0 when it finished first; never 1."""
    assert threading.current_thread() is threading.main_thread()  # signals reach this thread
    log = tmp_path / "cart_r2_robust.mcap"
    assert run_cli("run", "cart_r2_robust", "--out", tmp_path, "--set", "sim.duration=20").returncode == 0
    whole = []
    for _ in range(2):  # the second, warm, is what the tries take
        t0 = time.perf_counter()
        assert main(["replay", str(log), "--verify"]) == 0
        whole.append(time.perf_counter() - t0)
    capsys.readouterr()
    outcomes = {0: 0, 130: 0, "late": 0}
    for delay in np.random.default_rng(18).uniform(0.0, min(whole), 8):
        code = main_with_ctrl_c_at(delay, ["replay", str(log), "--verify"])
        out, err = capsys.readouterr()
        assert code in outcomes, (delay, code, out, err)
        assert "differs" not in out + err and "Traceback" not in err
        if code == 130:
            assert err.strip().splitlines()[-1] in (
                f"{log}: verify interrupted: the re-run of the recorded scenario was stopped before it could be "
                "compared with the log", "error: interrupted")
        outcomes[code] += 1
    assert outcomes[130] >= 4, outcomes  # most moments fall inside the command

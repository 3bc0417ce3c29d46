"""A signal at the edges of a real ``ftstab`` process, at points chosen exactly (tests/signal_points.py
sends it; no sleep race): during the command's imports it stops the command without a traceback
(exit 128 + signal, no log); once the logs are closed as completed the exit code stays 0, and no
handler is put back as the process exits (a SIGHUP then killed it: exit -1, the logs saying completed)."""

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import ROOT, _terminal_signals
from ftstab_mj.logs.reader import read_log


def run_with_signal(tmp_path, spec, *args, script=False):
    """``python -m ftstab_mj ARGS`` (script: the installed ``ftstab`` script) with the signal of
    ``spec`` ("SIGNAME@POINT", see tests/signal_points.py) sent at its point."""
    site = tmp_path / "site"
    site.mkdir(exist_ok=True)
    (site / "sitecustomize.py").write_text("import signal_points\n")
    env = dict(os.environ, FTSTAB_TEST_SIGNAL=spec,
               PYTHONPATH=os.pathsep.join([str(site), str(ROOT / "tests"), str(ROOT), os.environ.get("PYTHONPATH", "")]))
    if script:
        ftstab = Path(sys.executable).parent / "ftstab"
        if not ftstab.exists():
            pytest.skip(f"no ftstab script next to {sys.executable} (the package is not installed here)")
        cmd = [str(ftstab)]
    else:
        cmd = [sys.executable, "-m", "ftstab_mj"]
    return subprocess.run(cmd + [str(a) for a in args], capture_output=True, text=True, env=env, cwd=ROOT,
                          timeout=300, preexec_fn=_terminal_signals)


def label(sig):
    return "interrupted" if sig == signal.SIGINT else f"interrupted ({sig.name})"


@pytest.mark.parametrize("entry, spec", [
    ("script", "SIGINT@import:ftstab_mj.cli"),  # the script imported the CLI before any handler of ours
    ("module", "SIGINT@import:ftstab_mj.simulation.interrupts"),  # the entry's first import
    ("module", "SIGTERM@import:numpy"),  # inside a C extension's import
    ("script", "SIGHUP@import:mujoco"),
])
def test_a_signal_during_the_commands_imports_stops_it_without_a_traceback(tmp_path, entry, spec):
    sig = signal.Signals[spec.split("@")[0]]
    out = tmp_path / "o"
    res = run_with_signal(tmp_path, spec, "run", "cart_r2_robust", "--out", out, "--set", "sim.duration=0.2",
                          script=entry == "script")
    assert f"[signal_points: sent {sig.name} at " in res.stderr  # the signal did come at that point
    assert "Traceback" not in res.stderr, res.stderr
    assert res.returncode == 128 + sig, res.stderr
    assert res.stderr.strip().splitlines()[-1] == f"error: {label(sig)}"
    assert not out.exists() or not any(out.iterdir())  # no log: none was opened


@pytest.mark.parametrize("entry, spec", [
    ("script", "SIGHUP@after:ftstab_mj.cli:main"),  # the script's handlers ended with the CLI's main
    ("module", "SIGTERM@after:ftstab_mj.cli:main"),
    ("module", "SIGHUP@late-handler"),  # a handler put back at exit (a collected context manager did)
    ("module", "SIGINT@late-handler"),
])
def test_a_signal_once_the_logs_are_closed_completed_leaves_exit_0(tmp_path, entry, spec):
    """The rule: once the logs are closed, the exit code is the one of their status (completed: 0);
    a signal then is ignored, with a note when it came before the exit was under way."""
    sig = signal.Signals[spec.split("@")[0]]
    out = tmp_path / "o"
    res = run_with_signal(tmp_path, spec, "run", "cart_r2_robust", "--out", out, "--set", "sim.duration=0.2",
                          script=entry == "script")
    assert "Traceback" not in res.stderr and "Exception ignored" not in res.stderr, res.stderr
    assert res.returncode == 0, res.stderr
    log = read_log(out / "cart_r2_robust.mcap")
    assert log.complete and log.recorded["status"] == "completed" and log.n_samples == 200
    if "after:" in spec:  # sent after the command returned its code: held, then said
        assert f"[signal_points: sent {sig.name} at " in res.stderr
        assert res.stderr.strip().splitlines()[-1] == f"note: {sig.name} came while the command was finishing: " \
                                                      "ignored (exit 0 stands)"
    else:  # nothing puts a handler back at exit
        assert "[signal_points: sent" not in res.stderr, res.stderr

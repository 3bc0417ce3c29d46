"""`ftstab run` and `ftstab list` as a user meets them: help, listing, outcomes other than success."""

import io
import json
import signal
import time

import numpy as np
from conftest import run_cli, start_cli

from ftstab_mj.logs.reader import read_log
from ftstab_mj.simulation.records import SampleBatch
from ftstab_mj.scenario import shipped_scenarios
from ftstab_mj.scenario.run import ProgressSink


def test_list_shows_every_shipped_scenario_with_its_description():
    proc = run_cli("list")
    assert proc.returncode == 0, proc.stderr
    rows = shipped_scenarios()
    assert len(rows) >= 10
    for name, _, description in rows:
        assert any(line.startswith(name + " ") and line.endswith(description) for line in proc.stdout.splitlines())


def test_help_of_the_command_and_of_each_verb_stands_on_its_own():
    top = run_cli("--help")
    assert top.returncode == 0 and all(v in top.stdout for v in ("run", "list", "certify"))
    run = run_cli("run", "--help")
    assert run.returncode == 0
    text = " ".join(run.stdout.split())  # argparse wraps lines
    for word in ("--out DIR", "--set KEY.PATH=VALUE", "--json", "Exit 0 when the run completed", "ftstab list"):
        assert word in text, word
    assert run_cli("list", "--help").returncode == 0


def test_out_that_is_a_file_is_bad_input(tmp_path):
    target = tmp_path / "taken"
    target.write_text("")
    proc = run_cli("run", "cart_r2_robust", "--out", target)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1
    assert f"--out {target}" in proc.stderr and "Traceback" not in proc.stderr


def test_diverged_run_exits_1_and_its_log_says_so(tmp_path):
    """|z_1(0)| = 1 is beyond a divergence limit of 0.5: the run stops at its first sample."""
    proc = run_cli("run", "cart_r2_robust", "--out", tmp_path, "--set", "sim.divergence_limit=0.5")
    assert proc.returncode == 1
    assert "error: run diverged" in proc.stderr and "Traceback" not in proc.stderr
    log = read_log(tmp_path / "cart_r2_robust.mcap")
    assert log.complete and log.recorded["status"] == "diverged" and log.recorded["message"]


def test_ctrl_c_exits_130_and_leaves_a_complete_log_saying_interrupted(tmp_path):
    """SIGINT while running: the run loop stops at the current sample, the sinks are finalized."""
    proc = start_cli("run", "cart_r2_robust", "--out", tmp_path, "--set", "sim.duration=3600")
    log = tmp_path / "cart_r2_robust.mcap"
    deadline = time.monotonic() + 120
    while (not log.exists() or log.stat().st_size < 200_000) and time.monotonic() < deadline:
        time.sleep(0.05)  # wait until samples are being written (the run has started)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "error: run interrupted" in err and "Traceback" not in err
    data = read_log(log)
    assert data.complete and data.recorded["status"] == "interrupted"
    assert 0 < data.n_samples < 3_600_000
    assert json.loads(json.dumps(data.recorded["metrics"]))["status"] == "interrupted"


class _Tty(io.StringIO):
    def isatty(self):
        return True


def _batch(t_end):
    t = np.array([t_end])
    return SampleBatch(loops={"cart": {"t": t}}, body_pos=np.zeros((1, 0, 3)), body_quat=np.zeros((1, 0, 4)))


def test_progress_shows_on_a_terminal_only_once_the_run_lasts():
    quick = ProgressSink("demo", 10.0, stream=_Tty(), after=3600)
    quick.open(None)
    quick.write(_batch(5.0))
    quick.close("completed", {})
    assert quick.stream.getvalue() == ""  # a run shorter than `after` shows nothing
    slow = ProgressSink("demo", 10.0, stream=_Tty(), after=0.0)
    slow.open(None)
    slow._last -= 1.0  # the last refresh was a second ago
    slow.write(_batch(2.5))
    slow.close("completed", {})
    assert slow.stream.getvalue() == "\rdemo: t = 2.50 / 10.00 s ( 25%)\n"
    piped = ProgressSink("demo", 10.0, stream=io.StringIO(), after=0.0)
    piped.open(None)
    piped._last -= 1.0
    piped.write(_batch(2.5))
    assert piped.stream.getvalue() == ""  # not a terminal: logs and pipes stay clean


def test_unusable_out_is_bad_input_and_leaves_no_log(tmp_path):
    """--out that cannot hold the logs: exit 2, one line, and neither log is written (the .mcap is
    not opened while the .rrd is unusable)."""
    blocked = tmp_path / "a"
    (blocked / "cart_r2_robust.rrd").mkdir(parents=True)
    res = run_cli("run", "cart_r2_robust", "--out", blocked, "--set", "sim.duration=0.1", "--rrd")
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1 and "Traceback" not in res.stderr
    assert not (blocked / "cart_r2_robust.mcap").exists()
    res = run_cli("run", "cart_r2_robust", "--out", "/proc/no/such/dir", "--set", "sim.duration=0.1")
    assert res.returncode == 2 and "--out" in res.stderr and "Traceback" not in res.stderr


def test_damped_cart_claims_no_bound(tmp_path):
    """Damping adds -b x'/m to phi, unbounded without a speed limit: the robust law's guarantee must
    not be reported as applying, and "computed" bounds are refused (a review found both claimed)."""
    res = run_cli("run", "cart_r2_robust", "--out", tmp_path, "--json", "--set", "plant.damping=2",
                  "--set", "sim.duration=0.5")
    assert res.returncode == 0, res.stderr
    loop = json.loads(res.stdout)["loops"]["cart"]
    assert loop["bound_applies"] is False
    res = run_cli("run", "cart_r2_robust", "--out", tmp_path / "x", "--set", "plant.damping=2",
                  "--set", 'loops.cart.controller.phibar="computed"')
    assert res.returncode == 2 and "loops.cart.controller.phibar" in res.stderr and "Traceback" not in res.stderr
    assert not (tmp_path / "x").exists()

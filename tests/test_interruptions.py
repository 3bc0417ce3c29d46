"""Interruptions through the real CLI: SIGTERM and SIGHUP finish a run like Ctrl-C (logs closed,
status interrupted, exit 128 + signal), and an interrupted ``replay --verify`` says "interrupted",
never that the log differs."""

import json
import signal
import threading
import time

import numpy as np
import pytest

from conftest import run_cli, start_cli, wait_for_samples
from ftstab_mj.cli import main
from ftstab_mj.logs.reader import read_log


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


def test_a_sighup_ignored_by_the_starter_stays_ignored(tmp_path):
    """Under `nohup` (SIGHUP ignored, inherited by the command) the run goes on through a SIGHUP;
    a SIGTERM after it still stops it like Ctrl-C."""
    def nohup():
        signal.signal(signal.SIGHUP, signal.SIG_IGN)

    proc = start_cli("run", "cart_r2_robust", "--out", tmp_path, "--set", "sim.duration=3600", preexec_fn=nohup)
    log = tmp_path / "cart_r2_robust.mcap"
    wait_for_samples(log)
    proc.send_signal(signal.SIGHUP)
    time.sleep(0.5)
    alive = proc.poll() is None
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=120)
    assert alive and proc.returncode == 143 and "error: run interrupted (SIGTERM)" in err, err
    assert "SIGHUP" not in err


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


def _rrd_rows(path, entity):
    """Rows of ``entity`` in a complete .rrd (Rerun's strict reader)."""
    from rerun.chunk import RrdReader

    return sum(chunk.num_rows for chunk in RrdReader(str(path)).stream() if chunk.entity_path == entity)


class Moments:
    """The moments a run reports, as seen in this process: "open" (every log opened), "write" (a batch
    written to every log), "close" (every log closed), each with its time (s) since ``start``. They
    are read on the ProgressSink, the command's last sink, so each comes once all the logs are done,
    still inside the run's critical block. ``arm(index, delay, sig)``: send ``sig`` to this process
    ``delay`` s after moment ``index`` (0: the start of the command, i: the i-th reported moment),
    and no later than moment index + 1: a run faster than the delay waits there for the signal (as a
    slower machine would have), so the signal comes between the same two moments whatever the load."""

    def __init__(self, monkeypatch):
        from ftstab_mj.scenario.run import ProgressSink

        self.seen, self._armed, self._sent = [], None, None
        for name in ("open", "write", "close"):
            monkeypatch.setattr(ProgressSink, name, self._reporting(name, getattr(ProgressSink, name)))

    def _reporting(self, name, method):
        def reported(sink, *args):
            method(sink, *args)
            self.seen.append((name, time.perf_counter() - self.t0))
            if self._sent is not None and self._sent[0] + 1 == len(self.seen):
                self._sent[1].join()  # the next moment: the signal is sent before the run goes past it
            if self._armed is not None and self._armed[0] == len(self.seen):
                self._fire()
        return reported

    def start(self):
        self.seen, self._sent, self.t0 = [], None, time.perf_counter()
        if self._armed is not None and self._armed[0] == 0:
            self._fire()

    def arm(self, index, delay, sig):
        self._armed = (index, delay, sig)

    def _fire(self):
        import os

        index, delay, sig = self._armed
        self._armed = None
        self._sent = (index, threading.Timer(delay, os.kill, (os.getpid(), sig)))
        self._sent[1].start()

    def join(self):
        if self._sent is not None:
            self._sent[1].join()


def main_with_signal_at(moments, index, delay, sig, argv):
    """main(argv) with ``sig`` sent to this process ``delay`` s after moment ``index`` of ``moments``;
    (exit code or "late" when it came after main returned, absorbed by a handler of the test's)."""
    late = []
    saved = {s: signal.signal(s, lambda signum, frame: late.append(signum)) for s in (signal.SIGINT, signal.SIGTERM)}
    moments.arm(index, delay, sig)
    try:
        moments.start()
        code = main(argv)
        moments.join()
        time.sleep(0.02)  # a signal sent just now is handled here
    finally:
        moments.join()
        for s, h in saved.items():
            signal.signal(s, h)
    return "late" if late else code


@pytest.mark.parametrize("scenario", ["cart_r2_robust", "arm_robust"])
def test_a_signal_at_any_moment_leaves_logs_whose_metrics_are_the_replayed_ones(tmp_path, capsys, monkeypatch, scenario):
    """Ctrl-C or SIGTERM (alternately) at seeded moments spread over a whole `ftstab run` (loading,
    setup, opening the logs, every batch, closing): either no log at all (stopped before the logs
    were opened), or two complete logs holding the same samples, saying "interrupted" exactly when
    the exit code is 128 + signal, with recorded metrics equal to the ones replayed from the samples.

    The moments are placed by what the run reports, not by a wall-clock guess of its length (a
    duration measured on a quiet machine put 9 of 12 moments before the logs at load 8): a warm run
    gives the times of its moments (start, logs opened, each batch, logs closed); each try takes a
    seeded time in one of three spans of it (before the logs, the batches, closing and exit: one
    try in three each, both signals in each), and sends the signal that long after the last moment
    before it, once the try has reported that moment, and before the try goes past the next one (a
    faster try waits there). So a signal falls between the same two moments whatever the load: the
    tries in the batches' span are interrupted by construction."""
    from ftstab_mj.metrics.run_metrics import compute_metrics

    moments = Moments(monkeypatch)
    argv = ["run", scenario, "--out", str(tmp_path / "o"), "--set", "sim.duration=1.5", "--json", "--rrd"]
    warm = []
    for _ in range(2):  # the second, warm, is what the tries take
        moments.start()
        assert main(argv) == 0
        warm.append([("start", 0.0)] + moments.seen + [("end", time.perf_counter() - moments.t0)])
    capsys.readouterr()
    names = [name for name, _ in warm[0]]
    assert [name for name, _ in warm[1]] == names and names[1] == "open" and names[-2] == "close", warm
    assert names[2:-2] == ["write"] * (len(names) - 4) and len(names) > 4, names
    clock = np.array([t for _, t in min(warm, key=lambda m: m[-1][1])])
    times = clock[:-1]  # a moment's time; the end is no moment to wait for
    spans = [(0.0, clock[1]), (clock[1], clock[-3]), (clock[-3], clock[-1])]
    ref = read_log(tmp_path / "o" / f"{scenario}.mcap")  # the style rows Rerun's series hold beside samples
    static = {name: _rrd_rows(tmp_path / "o" / f"{scenario}.rrd", f"/loop/{name}/V1/log10_V1") - ref.n_samples
              for name in ref.loops}
    rng = np.random.default_rng({"cart_r2_robust": 10, "arm_robust": 6}[scenario])
    outcomes = {"completed": 0, "interrupted": 0, "no log": 0, "late": 0}
    tries = 12
    for k, fraction in enumerate(rng.uniform(0.0, 1.0, tries)):
        sig = (signal.SIGINT, signal.SIGTERM)[k % 2]
        span = spans[k % 3]
        at = span[0] + fraction * (span[1] - span[0])  # in the warm run's time
        index = int(np.searchsorted(times, at, side="right")) - 1  # the last moment before it
        delay = at - times[index]
        out = tmp_path / f"try{k}"
        code = main_with_signal_at(moments, index, delay, sig, ["run", scenario, "--out", str(out), "--set", "sim.duration=1.5",
                                                                  "--rrd"])
        stdout, stderr = capsys.readouterr()
        where = (f"try {k}: {signal.Signals(sig).name} {delay:.3f} s after {names[index]} (moment {index}, "
                 f"{at:.3f} s of the warm run's {clock[-1]:.3f}): exit {code}: {stderr!r}")
        assert "Traceback" not in stderr, where
        if code == "late":
            outcomes["late"] += 1
            continue
        mcap, rrd = out / f"{scenario}.mcap", out / f"{scenario}.rrd"
        if not mcap.exists():  # stopped before the logs were opened: neither exists, and it says so
            assert code == 128 + sig and not rrd.exists(), where
            assert stderr.strip().splitlines()[-1] == f"error: {interruption_label(sig)}", where
            outcomes["no log"] += 1
            continue
        log = read_log(mcap)
        assert log.complete and log.recorded is not None, where
        status = log.recorded["status"]
        assert (status == "interrupted") == (code == 128 + sig) and (status == "completed") == (code == 0), where
        replayed = compute_metrics(log.info, log.loops, status)
        assert json.loads(json.dumps(replayed)) == log.recorded["metrics"], where
        for name in log.loops:  # the Rerun recording holds the same samples
            assert _rrd_rows(rrd, f"/loop/{name}/V1/log10_V1") - static[name] == log.n_samples, where
        if status == "interrupted":
            assert log.recorded["message"].startswith(interruption_label(sig) + " at t = "), where
            assert f"error: run {interruption_label(sig)}: " in stderr and "the logs say so" in stderr, where
        outcomes[status] += 1
    print(scenario, outcomes)
    assert outcomes["interrupted"] >= tries // 3, outcomes


def interruption_label(sig):
    return "interrupted" if sig == signal.SIGINT else f"interrupted ({signal.Signals(sig).name})"

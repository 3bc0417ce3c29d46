"""Regression tests on logged metrics: every shipped scenario, shortened, logged, read back, pinned.

For each scenario: ``ftstab run NAME --set sim.duration=DURATION`` writes its logs, ``ftstab check``
compares the metrics recomputed from the MCAP log with tests/expected/NAME.toml, and
``ftstab replay --verify`` re-runs the scenario recorded in the log and finds it bit-identical.
The tolerances of the pinned files are the default ones of ftstab_mj/metrics/expectations.py (timings in
control periods, phi_hat from the adaptation rate, rtol for chattering amplitudes: see each file's
header). The CLI is called in-process (``ftstab_mj.cli.main``) to spare a Python start per call.

Re-pin after an intended change of behaviour: ``python tests/test_logged_regression.py``.
"""

import sys
from pathlib import Path

import pytest

from ftstab_mj.cli import main
from ftstab_mj.scenario import shipped_scenarios

EXPECTED = Path(__file__).resolve().parent / "expected"
DURATION = 5.0  # s: every shipped scenario has settled (or shown it does not) and has a final window


def _run(name, out) -> Path:
    assert main(["run", name, "--set", f"sim.duration={DURATION}", "--out", str(out), "--json"]) == 0
    return out / f"{name}.mcap"


def test_every_shipped_scenario_is_pinned():
    assert sorted(p.stem for p in EXPECTED.glob("*.toml")) == sorted(n for n, _, _ in shipped_scenarios())


@pytest.mark.parametrize("name", sorted(n for n, _, _ in shipped_scenarios()))
def test_logged_metrics_match_the_pinned_ones_and_the_log_replays_bit_identical(name, tmp_path, capsys):
    log = _run(name, tmp_path)
    capsys.readouterr()
    code = main(["check", str(log), "--expect", str(EXPECTED / f"{name}.toml")])
    out = capsys.readouterr()
    assert code == 0, out.out + out.err
    assert main(["replay", str(log), "--verify"]) == 0, capsys.readouterr().err
    assert "bit-identical" in capsys.readouterr().out


def test_verify_fails_when_a_logged_sample_is_altered(tmp_path, capsys):
    # Rewrite a shipped scenario's log with one value of one sample changed by one ulp (metrics
    # recomputed so that only --verify can tell): the re-run must disagree at that sample.
    import numpy as np

    from ftstab_mj.logs import McapSink
    from ftstab_mj.logs.reader import read_log
    from ftstab_mj.metrics.run_metrics import compute_metrics
    from ftstab_mj.simulation.records import SampleBatch

    name = "cart_r2_adaptive"
    assert main(["run", name, "--set", "sim.duration=0.5", "--out", str(tmp_path), "--json"]) == 0
    log = read_log(tmp_path / f"{name}.mcap")
    loops = {k: {f: a.copy() for f, a in v.items()} for k, v in log.loops.items()}
    loops["cart"]["u"][123] = np.nextafter(loops["cart"]["u"][123], np.inf)
    altered = tmp_path / "altered.mcap"
    sink = McapSink(altered)
    sink.open(log.info)
    n = log.n_samples
    sink.write(SampleBatch(loops, np.zeros((n, 0, 3)), np.zeros((n, 0, 4))))
    sink.close(log.recorded["status"], compute_metrics(log.info, loops, log.recorded["status"]))
    capsys.readouterr()
    assert main(["replay", str(tmp_path / f"{name}.mcap"), "--verify"]) == 0
    capsys.readouterr()
    assert main(["replay", str(altered), "--verify"]) == 1
    err = capsys.readouterr().err
    assert "verify failed" in err and "/loop/cart u differs first at sample 123 (t = 0.123 s)" in err


def repin():
    """Rewrite tests/expected/*.toml from fresh shortened runs (only after an intended change)."""
    import tempfile

    EXPECTED.mkdir(exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        for name, _, _ in shipped_scenarios():
            log = _run(name, Path(tmp))
            assert main(["check", str(log), "--pin", str(EXPECTED / f"{name}.toml")]) == 0


if __name__ == "__main__":
    sys.exit(repin())

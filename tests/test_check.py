"""``ftstab check``: pinned metrics with tolerances, readable diff, exit codes 0 / 1 / 2."""

import pytest

from conftest import run_cli
from ftstab_mj.metrics.expectations import ExpectationError, check_metrics
from ftstab_mj.logs import McapSink
from ftstab_mj.metrics.run_metrics import compute_metrics
from ftstab_mj.simulation.records import COMPLETED
from synthetic_runs import synthetic_run, write_run

METRICS = {"status": "completed", "n_samples": 10,
           "loops": {"a": {"settle_time": 1.25, "final_abs_z_max": [1e-3, 2e-2], "time_bound": None,
                           "theorem3": {"Delta_held": True}}}}


def _check(expected):
    return {o.path: o for o in check_metrics(METRICS, expected, source="e.toml")}


def test_tolerances_bounds_and_exact_values():
    out = _check({"status": "completed", "n_samples": 10, "loops": {"a": {
        "settle_time": {"value": 1.2, "atol": 0.06},
        "final_abs_z_max": {"max": [2e-3, 2e-2]},
        "time_bound": {"null": True},
        "theorem3": {"Delta_held": True}}}})
    assert all(o.ok for o in out.values()) and len(out) == 6
    out = _check({"status": "diverged", "loops": {"a": {
        "settle_time": {"value": 1.2, "atol": 0.04, "rtol": 0.0},
        "final_abs_z_max": {"value": 1e-3, "rtol": 0.5},  # one reference for every component
        "time_bound": {"value": 1.0}}}})
    assert not out["status"].ok and out["status"].line == "status: expected 'diverged', got 'completed'"
    st = out["loops.a.settle_time"]
    assert not st.ok and "off by +0.05 (allowed 0.04)" in st.line
    fz = out["loops.a.final_abs_z_max"]
    assert not fz.ok and "[1] off by +0.019" in fz.line and "[0]" not in fz.line
    assert not out["loops.a.time_bound"].ok and "is null" in out["loops.a.time_bound"].line
    assert _check({"loops": {"a": {"settle_time": {"value": 1.25 + 1e-12, "rtol": 1e-9}}}})["loops.a.settle_time"].ok


@pytest.mark.parametrize("expected, where", [
    ({"loops": {"a": {"settle_tme": 1.0}}}, "loops.a.settle_tme"),
    ({"loops": {"a": {"settle_time": {"value": 1.0, "tol": 0.1}}}}, "loops.a.settle_time.tol"),
    ({"loops": {"a": {"settle_time": {"value": "fast"}}}}, "loops.a.settle_time.value"),
    ({"loops": {"a": {"settle_time": {"atol": 0.1}}}}, "loops.a.settle_time"),
    ({"loops": {"a": {"theorem3": {"Delta_held": {"value": 1.0}}}}}, "loops.a.theorem3.Delta_held"),
    ({"loops": {"a": {"settle_time": {"value": 1.0, "atol": -0.1}}}}, "loops.a.settle_time.atol"),
    ({"loops": {"a": {"settle_time": {"value": []}}}}, "loops.a.settle_time.value"),
    ({"loops": {"a": {"final_abs_z_max": {"max": [1.0, "x"]}}}}, "loops.a.final_abs_z_max.max[1]"),
    ({"loops": {"a": {"settle_time": {"null": False}}}}, "loops.a.settle_time.null"),
    ({"loops": {"a": {"settle_time": {"null": True, "max": 1.0}}}}, "loops.a.settle_time.null"),
])
def test_malformed_expectations_name_the_key_path(expected, where):
    with pytest.raises(ExpectationError) as exc:
        check_metrics(METRICS, expected, source="e.toml")
    assert str(exc.value).startswith(f"e.toml: {where}: expected ")
    assert str(exc.value).count(": expected ") == 1 and ", found " in str(exc.value)  # file, key path, expected, found


def test_an_expectation_table_is_read_by_the_configuration_layer():
    """The same words as every input file of the testbed (ftstab_mj.config.validate.Reader)."""
    cases = {
        "tol": ({"value": 1.0, "tol": 0.1}, "e.toml: loops.a.settle_time.tol: expected one of the keys value, atol, "
                                            "rtol, min, max, null, found unknown key 'tol'"),
        "fast": ({"value": "fast"}, "e.toml: loops.a.settle_time.value: expected a number, found 'fast'"),
        # a number written as a string: the type is the point, so it is named
        "quoted": ({"value": "1.0"}, "e.toml: loops.a.settle_time.value: expected a number, found '1.0' (a string)"),
        "nan": ({"value": float("nan")}, "e.toml: loops.a.settle_time.value: expected a finite number, found nan (a float)"),
        "atol": ({"value": 1.0, "atol": -0.1}, "e.toml: loops.a.settle_time.atol: expected a number >= 0, found -0.1 (a float)"),
    }
    for name, (spec, message) in cases.items():
        with pytest.raises(ExpectationError) as exc:
            check_metrics(METRICS, {"loops": {"a": {"settle_time": spec}}}, source="e.toml")
        assert str(exc.value) == message, name


def test_check_cli_exit_codes_and_diff(tmp_path):
    info, loops, pos, quat = synthetic_run("nominal", z0=(1.0, 0.0), duration=6.0, period=2e-3, with_model=False)
    metrics = compute_metrics(info, loops, COMPLETED)
    log = tmp_path / "run.mcap"
    write_run(McapSink(log), info, loops, pos, quat, COMPLETED, metrics)
    m = metrics["loops"]["cart"]
    good = tmp_path / "good.toml"
    good.write_text(f'status = "completed"\n[loops.cart]\nsettle_time = {{ value = {m["settle_time"]}, atol = 0.004 }}\n'
                    f'beat_bound = true\n')
    res = run_cli("check", log, "--expect", good)
    assert res.returncode == 0 and "all 3 expectations" in res.stdout, res.stdout + res.stderr
    bad = tmp_path / "bad.toml"
    bad.write_text(f'[loops.cart]\nsettle_time = {{ value = {m["settle_time"] + 0.1}, atol = 0.004 }}\n'
                   'effort_abs = { max = 0.0 }\n')
    res = run_cli("check", log, "--expect", bad)
    assert res.returncode == 1
    lines = res.stdout.splitlines()
    assert "2 of 2 expectations" in lines[0]
    assert lines[1].startswith("  loops.cart.settle_time: expected") and "off by -0.1" in lines[1]
    assert lines[2].startswith("  loops.cart.effort_abs: expected max 0") and "above max by" in lines[2]
    for text, where in (("[loops.cart]\nsettle = 1\n", "loops.cart.settle"), ("x = [", "(TOML syntax)")):
        broken = tmp_path / "broken.toml"
        broken.write_text(text)
        res = run_cli("check", log, "--expect", broken)
        assert res.returncode == 2 and res.stdout == ""
        assert res.stderr.startswith(f"error: {broken}: {where}: expected") and len(res.stderr.splitlines()) == 1


def test_pin_then_check_same_log_passes_and_another_run_fails(tmp_path):
    from ftstab_mj.cli import main

    logs = {}
    for z0 in (1.0, 1.2):
        info, loops, pos, quat = synthetic_run("adaptive", z0=(z0, 0.0), duration=3.0, period=2e-3, with_model=False)
        logs[z0] = tmp_path / f"run{z0}.mcap"
        write_run(McapSink(logs[z0]), info, loops, pos, quat, COMPLETED, compute_metrics(info, loops, COMPLETED))
    pinned = tmp_path / "pinned.toml"
    assert main(["check", str(logs[1.0]), "--pin", str(pinned)]) == 0
    text = pinned.read_text()
    assert "settle_time = { " in text and "atol = 0.004" in text  # two periods of 2 ms
    assert main(["check", str(logs[1.0]), "--expect", str(pinned)]) == 0
    assert main(["check", str(logs[1.2]), "--expect", str(pinned)]) == 1


def test_pin_of_a_run_without_samples_pins_only_its_count():
    from ftstab_mj.metrics.expectations import pin_expectations

    info, loops, _, _ = synthetic_run("nominal", duration=0.1, with_model=False)
    empty = {k: {f: a[:0] for f, a in v.items()} for k, v in loops.items()}
    m = compute_metrics(info, empty, "failed")
    pinned = pin_expectations(m, info)
    assert pinned == {"status": "failed", "n_samples": 0, "loops": {"cart": {"law": "nominal", "n_samples": 0}}}
    assert all(o.ok for o in check_metrics(m, pinned))

"""Strict loader errors for every key of [loops.<name>.sensor], [.observer] and [.actuator]:
exit 2, one line naming the file, the key path, what was expected and what was found, no log.

Called in-process (ftstab_mj.cli.main, as tests/test_logged_regression.py does) to spare a Python
start per case; tests/test_scenario_loader.py runs the same error path through a fresh process.
"""

import pytest

from ftstab_mj.cli import main
from ftstab_mj.scenario import SCENARIO_DIR

ROBUST = SCENARIO_DIR / "cart_r2_robust.toml"
R3 = SCENARIO_DIR / "cart_r3_robust.toml"
OF = SCENARIO_DIR / "cart_r2_output_feedback.toml"
S, O, A = "loops.cart.sensor", "loops.cart.observer", "loops.cart.actuator"

# (id, scenario, --set overrides, key path named by the error)
CASES = [
    ("sensor-unknown-key", ROBUST, [f"{S}.nois=1e-3"], f"{S}.nois"),
    ("sensor-not-a-table", ROBUST, [f"{S}=3"], S),
    ("measured-wrong-value", ROBUST, [f"{S}.measured=velocity"], f"{S}.measured"),
    ("measured-wrong-type", ROBUST, [f"{S}.measured=1"], f"{S}.measured"),
    ("noise-negative", ROBUST, [f"{S}.noise=-1e-3"], f"{S}.noise"),
    ("noise-wrong-type", ROBUST, [f'{S}.noise="loud"'], f"{S}.noise"),
    ("noise-array-item-wrong-type", ROBUST, [f'{S}.noise=[1e-3, "x"]'], f"{S}.noise[1]"),
    ("noise-channels", ROBUST, [f"{S}.noise=[1e-3, 1e-3, 1e-3]"], f"{S}.noise"),
    ("noise-channels-position", OF, [f"{S}.noise=[1e-3, 1e-3]"], f"{S}.noise"),
    ("noise-kind", ROBUST, [f"{S}.noise_kind=pink"], f"{S}.noise_kind"),
    ("quantum-negative", ROBUST, [f"{S}.quantum=-1"], f"{S}.quantum"),
    ("quantum-channels", R3, [f"{S}.quantum=[1e-3, 0]"], f"{S}.quantum"),
    ("delay-not-whole", ROBUST, [f"{S}.delay=1.5"], f"{S}.delay"),
    ("delay-negative", ROBUST, [f"{S}.delay=-1"], f"{S}.delay"),
    ("delay-wrong-type", ROBUST, [f'{S}.delay="2 ms"'], f"{S}.delay"),
    ("sensor-seed-is-derived", ROBUST, [f"{S}.seed=3"], f"{S}.seed"),
    ("position-without-observer", ROBUST, [f"{S}.measured=position"], O),
    ("observer-with-full-state", ROBUST, [f"{O}.kind=levant", f"{O}.L=5"], f"{S}.measured"),
    ("observer-unknown-key", OF, [f"{O}.lambda=1.1"], f"{O}.lambda"),
    ("observer-kind", OF, [f"{O}.kind=kalman"], f"{O}.kind"),
    ("observer-L-missing", ROBUST, [f"{S}.measured=position", f"{O}.kind=levant"], f"{O}.L"),
    ("observer-L-not-positive", OF, [f"{O}.L=0"], f"{O}.L"),
    ("observer-L-wrong-type", OF, [f"{O}.L=[5]"], f"{O}.L"),
    ("observer-order-below-r-1", R3.with_name("cart_r3_output_feedback.toml"), [f"{O}.order=1"], f"{O}.order"),
    ("observer-order-wrong-type", OF, [f"{O}.order=1.5"], f"{O}.order"),
    ("observer-order-too-high", OF, [f"{O}.order=6"], f"{O}.order"),
    ("observer-filter-order-with-levant", OF, [f"{O}.filter_order=1"], f"{O}.filter_order"),
    ("observer-filter-order-zero", OF, [f"{O}.kind=levant_filtering", f"{O}.filter_order=0"], f"{O}.filter_order"),
    ("observer-total-order", OF, [f"{O}.kind=levant_filtering", f"{O}.order=4", f"{O}.filter_order=2"],
     f"{O}.order"),
    ("actuator-unknown-key", ROBUST, [f"{A}.umax=3"], f"{A}.umax"),
    ("u_max-not-positive", ROBUST, [f"{A}.u_max=0"], f"{A}.u_max"),
    ("u_max-infinite", ROBUST, [f"{A}.u_max=inf"], f"{A}.u_max"),
    ("u_max-wrong-type", ROBUST, [f"{A}.u_max=true"], f"{A}.u_max"),
    ("rate_max-negative", ROBUST, [f"{A}.rate_max=-5"], f"{A}.rate_max"),
    ("tau-negative", ROBUST, [f"{A}.tau=-0.01"], f"{A}.tau"),
    ("tau-wrong-type", ROBUST, [f'{A}.tau="10 ms"'], f"{A}.tau"),
    ("dead_zone-negative", ROBUST, [f"{A}.dead_zone=-0.1"], f"{A}.dead_zone"),
    ("lag_order-out-of-range", ROBUST, [f"{A}.tau=0.01", f"{A}.lag_order=3"], f"{A}.lag_order"),
    ("lag_order-without-lag", ROBUST, [f"{A}.lag_order=2"], f"{A}.lag_order"),
]


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_bad_stage_key_exit_2_one_line_key_path_no_log(case, tmp_path, capsys):
    _, path, sets, key_path = case
    out = tmp_path / "out"
    args = ["run", str(path), "--out", str(out)]
    for s in sets:
        args += ["--set", s]
    assert main(args) == 2
    cap = capsys.readouterr()
    lines = cap.err.strip().splitlines()
    assert len(lines) == 1 and cap.out == "" and "Traceback" not in cap.err, cap.err
    assert lines[0].startswith(f"error: {path}") and f": {key_path}: expected " in lines[0], lines[0]
    assert " found " in lines[0]
    assert not out.exists()


def test_delay_error_says_whole_control_periods(capsys):
    assert main(["run", str(ROBUST), "--out", "/nonexistent/x", "--set", f"{S}.delay=0.5"]) == 2
    err = capsys.readouterr().err
    assert "a whole number of control periods" in err and "0.5" in err

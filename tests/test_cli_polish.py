"""Command-line polish, through the real command: --version, the bare command, a closed pipe, a
scenario name that does not exist, the stale-description mark, units in the metrics table, a step
down, and the sweep report (titles that fit, medians said, slopes only through power laws)."""

import json
import re
import subprocess
import sys

import pytest

from conftest import ROOT, run_cli
from ftstab_mj import __version__
from ftstab_mj.logs.reader import read_log
from ftstab_mj.simulation.records import METRIC_UNITS, UNITS_LEGEND


def test_version_and_bare_command_print_the_version_and_the_verbs():
    res = run_cli("--version")
    assert res.returncode == 0 and res.stdout.strip() == f"ftstab {__version__}"
    res = run_cli()
    assert res.returncode == 0 and res.stderr == ""
    for verb in ("run", "list", "replay", "check", "certify", "sweep"):
        assert verb in res.stdout


def test_run_of_an_unknown_name_suggests_ftstab_list():
    res = run_cli("run", "nonexistent")
    assert res.returncode == 2 and res.stdout == ""
    (line,) = res.stderr.strip().splitlines()
    assert "nonexistent" in line and "ftstab list" in line and "Traceback" not in res.stderr


def test_output_into_a_closed_pipe_ends_quietly():
    # `ftstab list | true`: the reader is gone before the first line (as `| head` after its lines);
    # without the handling this ends in a BrokenPipeError traceback (checked on the code before it)
    proc = subprocess.run(f"{sys.executable} -m ftstab_mj list | true", shell=True, capture_output=True,
                          text=True, cwd=ROOT, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert "Traceback" not in proc.stderr and "BrokenPipe" not in proc.stderr, proc.stderr


def test_the_run_header_marks_a_description_that_set_may_have_made_stale(tmp_path):
    res = run_cli("run", "cart_r2_robust", "--out", tmp_path, "--set", "sim.duration=0.1",
                  "--set", "loops.cart.disturbance.amplitude=0.5")
    assert res.returncode == 0, res.stderr
    head = res.stdout.splitlines()
    assert head[0].startswith("cart_r2_robust: Robust law")  # the file's description, "(Theorem 1: 6.85 s)"...
    assert head[1] == ("  (description possibly stale: written for the file, before --set sim.duration, "
                       "loops.cart.disturbance.amplitude)")
    plain = tmp_path / "short.toml"  # the same run from a file that says so itself: no mark
    plain.write_text((ROOT / "scenarios" / "cart_r2_robust.toml").read_text().replace("duration = 10.0", "duration = 0.1"))
    res = run_cli("run", plain, "--out", tmp_path)
    assert res.returncode == 0 and "stale" not in res.stdout and res.stdout.splitlines()[1].startswith("  plant cart")


TABLE_LINE = re.compile(r"^ {2,4}(\w+) +(.*)$")


@pytest.mark.parametrize("scenario, law", [("cart_r2_adaptive", "adaptive"),  # Theorem 3's block
                                           ("cart_r3_output_feedback", "robust")])  # the loop stages' metrics
def test_the_metrics_table_shows_every_value_with_its_unit(tmp_path, scenario, law):
    res = run_cli("run", scenario, "--out", tmp_path, "--set", "sim.duration=0.2")
    assert res.returncode == 0, res.stderr
    lines = res.stdout.splitlines()
    assert UNITS_LEGEND in lines
    seen = {}
    for line in lines[lines.index(f"loop cart ({law})") + 1:]:
        m = TABLE_LINE.match(line)
        if m and not line.endswith(":"):  # (not the "theorem 3 (true bounds):" heading)
            seen[m.group(1)] = m.group(2)
    recorded = json.loads(run_cli("run", scenario, "--out", tmp_path / "json", "--set", "sim.duration=0.2",
                                  "--json").stdout)["loops"]["cart"]
    blocks = {"law", "theorem3"}  # the law is in the heading; Theorem 3 (adaptive only) is its own block
    shown = {k for k, v in recorded.items() if not isinstance(v, dict) and k not in blocks}
    shown |= set(recorded.get("theorem3") or ())  # the certificate, a table, is one line
    assert shown <= set(seen), f"metrics the table leaves out: {sorted(shown - set(seen))}"
    for key, text in seen.items():
        assert key in METRIC_UNITS, f"{key}: no unit declared"
        unit = {"chain": "chain units"}.get(METRIC_UNITS[key], METRIC_UNITS[key])
        if unit and re.match(r"^[-\d\[]", text) and text != "-":  # a number or a list of them
            assert text.endswith(" " + unit), (key, text)
    assert re.fullmatch(r"\d+(\.\d+)? s", seen["time_bound"]) and seen["u_max_abs"].endswith(" u")


def test_a_step_signal_may_step_down_an_actuator_losing_half_its_gain(tmp_path):
    res = run_cli("run", "cart_r2_robust", "--out", tmp_path, "--set", "sim.duration=0.5",
                  "--set", 'loops.cart.gain={kind="step", offset=1.0, amplitude=-0.5, t_step=0.25}',
                  "--set", "loops.cart.controller.gamma_m=0.4")
    assert res.returncode == 0, res.stderr
    a = read_log(tmp_path / "cart_r2_robust.mcap").loops["cart"]
    assert set(a["gamma"][a["t"] < 0.25]) == {1.0} and set(a["gamma"][a["t"] >= 0.25]) == {0.5}


def test_the_sweep_report_fits_slopes_only_through_power_laws_and_its_titles_fit(tmp_path):
    """V1 is homogeneous: along z0 = (x, 0) it is the power law V1(1, 0) x^d with d = k / (alpha - 1)
    (dV1/dt <= -c V1^alpha, alpha = (d + k) / d), 2 + k = 1.8 for k = -0.2; along z0 = (x, 1) it is
    not one (the velocity's share dominates at small x): no slope there, r^2 said."""
    from ftstab_mj.studies.sweep import load_sweep
    from ftstab_mj.figures.sweep_report import MIN_R2, draw_plot
    from ftstab_mj.studies.sweep.table import read_table

    sweep = tmp_path / "shapes.toml"
    title = ("V1 at the initial state against its position component, for two velocities: a power law only "
             "along the homogeneous ray")
    sweep.write_text(f'''name = "shapes"
description = "V1(z0) along z0 = (x, 0) and (x, 1)"
scenario = "{ROOT / "scenarios" / "cart_r2_robust.toml"}"
samples = 2
[set]
"sim.duration" = 0.01
[grid]
"loops.cart.z0[0]" = [0.1, 0.3, 1.0, 3.0]
"loops.cart.z0[1]" = [0.0, 1.0]
[draw]
"loops.cart.disturbance.phase" = {{uniform = [0.0, 1.0]}}
[[report.plot]]
x = "loops.cart.z0[0]"
y = "metrics.loops.cart.V1_initial"
by = "loops.cart.z0[1]"
logx = true
logy = true
fit = true
title = "{title}"
''')
    res = run_cli("sweep", sweep, "--out", tmp_path / "o", "--report")
    assert res.returncode == 0, res.stderr
    slope = re.search(r"log-log slope in \S+, loops.cart.z0\[1\] = 0.0: (\S+) \(4 points, r\^2 = 1.0000\)", res.stdout)
    assert slope and float(slope.group(1)) == pytest.approx(2 - 0.2, abs=5e-4)  # printed to 3 decimals
    no = re.search(r"no log-log slope in \S+, loops.cart.z0\[1\] = 1.0: not a power law: r\^2 = (\S+) < 0.99", res.stdout)
    assert no and float(no.group(1)) < MIN_R2
    # the figure the command drew, rebuilt from its table: the fits, the legend, the title inside the figure
    sw = load_sweep(sweep)
    fig, fits = draw_plot(sw.plots[0], read_table(tmp_path / "o" / "shapes.parquet"), sw, "report.plot[0]", "f.png")
    ray, off = fits
    assert ray.power_law and ray.slope == pytest.approx(1.8, rel=1e-9) and ray.r2 == pytest.approx(1.0, abs=1e-12)
    assert not off.power_law and off.slope is None and off.r2 < MIN_R2
    ax = fig.axes[0]
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels == ["loops.cart.z0[1] = 0.0, median: slope 1.80", "loops.cart.z0[1] = 1.0, median: no slope (r$^2$ = 0.95)"]
    assert len([ln for ln in ax.get_lines() if ln.get_linestyle() == "--"]) == 1  # the one fitted line
    box = ax.title.get_window_extent(fig.canvas.get_renderer())
    assert 0 <= box.x0 and box.x1 <= fig.bbox.width and "\n" in ax.get_title()
    assert ax.get_title().replace("\n", " ") == title

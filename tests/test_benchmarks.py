"""The benchmarks run through their entry point: every one is listed and answers --help, and the cheap ones
run with --quick (its settings: benchmarks/__main__.QUICK) and print every row. No timing is asserted (speed
lives in the benchmarks, not in the tests), only that the scripts the docs show work."""

import subprocess
import sys

import pytest

from ftstab_mj.simulation import native
from conftest import ROOT


HELP_ALL = """
import contextlib, io, json, runpy, sys
from benchmarks.__main__ import benchmarks
helps = {}
for name in benchmarks():
    sys.argv = [name, "--help"]
    out = io.StringIO()
    try:
        with contextlib.redirect_stdout(out):
            runpy.run_module("benchmarks." + name, run_name="__main__")
        code = "no exit"
    except SystemExit as e:
        code = e.code
    helps[name] = [code, out.getvalue()]
print(json.dumps(helps))
"""


def test_every_benchmark_is_listed_and_answers_help():
    """`python -m benchmarks` lists every module of benchmarks/ (one line each, a summary from its docstring);
    each imports and its --help exits 0 with a usage line naming every option of its --quick settings; an
    unknown name is one line and exit 2."""
    import json

    from benchmarks.__main__ import QUICK

    modules = sorted(p.stem for p in (ROOT / "benchmarks").glob("*.py") if not p.stem.startswith("_"))
    listed = subprocess.run([sys.executable, "-m", "benchmarks"], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert listed.returncode == 0, listed.stderr
    lines = listed.stdout.splitlines()[1:]
    assert [line.split()[0] for line in lines] == modules, listed.stdout
    assert all(len(line.split()) > 3 for line in lines), listed.stdout  # a summary on every line
    out = subprocess.run([sys.executable, "-c", HELP_ALL], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    helps = json.loads(out.stdout.strip().splitlines()[-1])
    assert sorted(helps) == modules
    for name, (code, text) in helps.items():
        assert code == 0 and text.startswith("usage:"), (name, code, text)
        for option in (a for a in QUICK.get(name, ()) if a.startswith("--")):
            assert option in text.split(), (name, option)
    assert set(QUICK) <= set(modules), set(QUICK) - set(modules)
    unknown = subprocess.run([sys.executable, "-m", "benchmarks", "nope"], capture_output=True, text=True, timeout=60,
                             cwd=ROOT)
    assert unknown.returncode == 2 and len(unknown.stderr.strip().splitlines()) == 1, unknown.stderr


@pytest.mark.skipif(not native.available(), reason=f"native kernel: {native.UNAVAILABLE_REASON}")
def test_speed_benchmark_prints_every_ratio():
    out = subprocess.run([sys.executable, "-m", "benchmarks", "speed", "--quick"],
                         capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    for row in ("callback robust r=2", "callback adaptive r=3", "ideal chain r=2, 1000 initial states"):
        assert row in out.stdout, out.stdout


def test_law_costs_benchmark_prints_every_law_on_the_cart_and_the_arm():
    out = subprocess.run([sys.executable, "-m", "benchmarks", "law_costs", "--quick"],
                         capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    rows = [line.split() for line in out.stdout.splitlines()[2:]]
    from ftstab_mj.control.law import LAWS

    shipped = {name for name, cls in LAWS.items() if cls.__module__.startswith("ftstab_mj.") and name != "nominal"}
    assert shipped <= {row[0] for row in rows}, out.stdout  # every law but the nominal one (no disturbance)
    for law in shipped:
        paths = {(row[1], row[2]) for row in rows if row[0] == law}
        want = {(plant, path) for plant in ("cart", "arm") for path in ("python",) + (("native",) if native.available() else ())}
        assert want <= paths, (law, paths)
    # the Python path against a user's loop with the same law: a ratio on every Python row (r = 2)
    assert "x hand" in out.stdout.splitlines()[1]
    python_rows = [row for row in rows if "python" in row]
    assert python_rows and all(float(row[row.index("python") + 4]) > 0 for row in python_rows), out.stdout


def test_live_costs_benchmark_prints_every_case():
    out = subprocess.run([sys.executable, "-m", "benchmarks", "live_costs", "--quick"],
                         capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    for row in ("plain ", "--foxglove, no client", "--foxglove, one client subscribed"):
        assert row in out.stdout, out.stdout
    int(out.stdout.split("received per run: [")[1].split("]")[0])  # how many depends on when the client got in


def test_run_speed_benchmark_prints_the_process_and_in_process_ratios():
    out = subprocess.run([sys.executable, "-m", "benchmarks", "run_speed", "--quick"],
                         capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    for row in ("process: `ftstab run` / plain mujoco", "process: `ftstab run --rrd` / plain mujoco",
                "in process: run, MCAP / bare", "in process: run, MCAP + Rerun / bare", "in process: run, no logs / bare",
                "load average"):
        assert row in out.stdout, out.stdout


def test_certificate_budget_benchmark_prints_a_row_per_population():
    """Every drawn problem gets one of the three answers (the counts add up), one row per population."""
    out = subprocess.run([sys.executable, "-m", "benchmarks", "certificate_budget", "--quick"],
                         capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    rows = [line.split("|")[1:-1] for line in out.stdout.splitlines() if line.startswith("| 2 |")]
    assert [row[1].strip() for row in rows] == ["domain", "near certified"], out.stdout
    for row in rows:
        assert sum(int(row[i]) for i in (3, 4, 5)) == 2, out.stdout


def test_row_cost_benchmark_prints_the_fixed_cost_of_a_sweep_row():
    out = subprocess.run([sys.executable, "-m", "benchmarks", "row_cost", "--quick"],
                         capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    for part in ("validation", "run", "bare mj_step", "fixed cost (validation + run - bare)"):
        assert part in out.stdout, out.stdout

"""Sweeps without MuJoCo: the sweep file loader, the expansion, the engines, failures, resume.

The runs are the ideal chain under the robust law (tests/sweep_chain.py), 1 s of simulated time.
"""

import io
import json
import math

import numpy as np
import pytest

from ftstab_mj.config.errors import SweepError
from ftstab_mj.studies.sweep.expand import draw_value, expand, grid_values
from ftstab_mj.studies.sweep.run import Progress, run_sweep
from ftstab_mj.studies.sweep.spec import Draw, GridParam, load_sweep
from ftstab_mj.studies.sweep.table import VARYING_COLUMNS, read_journal, read_table
from tests.sweep_chain import ChainTask


def write_sweep(tmp_path, body: str, name="s"):
    (tmp_path / "base.toml").write_text("# the loader only checks that the base scenario exists\n")
    path = tmp_path / f"{name}.toml"
    path.write_text(f'name = "{name}"\ndescription = "test sweep"\nscenario = "base.toml"\n' + body)
    return path


def results(table: dict) -> dict:
    """The table without its wall-time columns (the only ones allowed to differ between engines)."""
    return {k: v for k, v in table.items() if k not in VARYING_COLUMNS}


# -- grid values and expansion ---------------------------------------------------------------------
def test_grid_values_range_includes_stop_and_reads_clean():
    assert grid_values(GridParam("x", "range", (0.1, 0.5, 0.1))) == (0.1, 0.2, 0.3, 0.4, 0.5)
    assert grid_values(GridParam("x", "range", (3, 0, -1.5))) == (3.0, 1.5, 0.0)
    assert grid_values(GridParam("x", "linspace", (-0.3, -0.1), 3)) == (-0.3, -0.2, -0.1)


def test_grid_values_logspace_is_geometric_with_exact_ends():
    v = np.array(grid_values(GridParam("x", "logspace", (1e-4, 1e-2), 5)))
    assert v[0] == 1e-4 and v[-1] == 1e-2
    np.testing.assert_allclose(v[1:] / v[:-1], 10 ** 0.5, rtol=1e-11)


def test_product_and_zip_and_groups(tmp_path):
    body = '[grid]\na = [1, 2, 3]\nb = {linspace = [0, 1], num = 2}\n[grid.g]\n"c.x" = [10, 20]\n"c.y" = ["u", "v"]\n'
    rows = expand(load_sweep(write_sweep(tmp_path, body)))
    assert len(rows) == 3 * 2 * 2
    assert [r.index for r in rows] == list(range(12))
    assert rows[0].params == (("a", 1), ("b", 0.0), ("c.x", 10), ("c.y", "u"))
    assert rows[1].params == (("a", 1), ("b", 0.0), ("c.x", 20), ("c.y", "v"))  # the group moves together
    assert rows[-1].params == (("a", 3), ("b", 1.0), ("c.x", 20), ("c.y", "v"))  # first axis slowest
    zipped = expand(load_sweep(write_sweep(tmp_path, 'combine = "zip"\n[grid]\na = [1, 2]\nb = [5, 6]\n')))
    assert [r.params for r in zipped] == [(("a", 1), ("b", 5)), (("a", 2), ("b", 6))]


def test_zip_of_unequal_axes_is_one_line_error(tmp_path):
    sw = load_sweep(write_sweep(tmp_path, 'combine = "zip"\n[grid]\na = [1, 2]\nb = [5, 6, 7]\n'))
    with pytest.raises(SweepError, match=r"s\.toml: grid: expected axes with the same number of values .*a: 2, b: 3"):
        expand(sw)


def test_draws_are_seeded_by_sweep_seed_draw_index_and_path_only(tmp_path):
    body = 'seed = 7\nsamples = 50\n[grid]\na = [1, 2]\n[draw]\nx = {uniform = [-1, 1]}\nn = {integers = [0, 3]}\n'
    rows = expand(load_sweep(write_sweep(tmp_path, body)))
    x = np.array([dict(r.params)["x"] for r in rows]).reshape(2, 50)
    np.testing.assert_array_equal(x[0], x[1])  # common random numbers across the grid
    assert len(set(x[0])) == 50 and x.min() >= -1 and x.max() <= 1
    assert {dict(r.params)["n"] for r in rows} == {0, 1, 2, 3}  # both ends included
    # a parameter's draws do not move when another drawn parameter is added
    only_x = expand(load_sweep(write_sweep(tmp_path, 'seed = 7\nsamples = 50\n[draw]\nx = {uniform = [-1, 1]}\n', "t")))
    np.testing.assert_array_equal([dict(r.params)["x"] for r in only_x], x[0])
    assert draw_value(Draw("x", "uniform", (-1, 1)), 8, 0) != x[0, 0]  # another seed, another draw


def test_loguniform_and_normal_draws_have_their_laws():
    lu = np.log10([draw_value(Draw("p", "loguniform", (1e-3, 1e1)), 0, j) for j in range(4000)])
    assert lu.min() >= -3 and lu.max() <= 1
    assert abs(lu.mean() - (-1.0)) < 4 * (4 / math.sqrt(12)) / math.sqrt(4000)  # uniform in log10, 4 sigma
    nv = np.array([draw_value(Draw("p", "normal", (2.0, 0.5)), 0, j) for j in range(4000)])
    assert abs(nv.mean() - 2.0) < 4 * 0.5 / math.sqrt(4000) and abs(nv.std() - 0.5) < 0.05


# -- the loader's errors: one line, file, key path, expectation, finding ---------------------------
@pytest.mark.parametrize("body, message", [
    ("colour = 1\n", r"s\.toml: colour: expected one of the keys name, .* found unknown key 'colour'"),
    ('combine = "cross"\n', r"s\.toml: combine: expected one of 'product', 'zip', found 'cross'$"),
    ('[grid]\n"sim.period" = {logspace = [0, 1e-2], num = 5}\n',
     r's\.toml: grid\."sim\.period"\.logspace: expected two end values > 0'),
    ('[grid]\n"sim.period" = {range = [1, 2, -1]}\n',
     r's\.toml: grid\."sim\.period"\.range: expected a step that goes from start towards stop'),
    ('[grid]\n"sim.period" = []\n', r's\.toml: grid\."sim\.period": expected a non-empty array of values'),
    ('[grid]\n"sim..period" = [1]\n', r's\.toml: grid\."sim\.\.period": expected a scenario key path'),
    ('[draw]\nx = {gauss = [0, 1]}\n', r"s\.toml: draw\.x: expected a table with one of uniform = \[\.\.\.\]"),
    ('[draw]\nx = {loguniform = [0, 1]}\n', r"s\.toml: draw\.x\.loguniform\[0\]: expected a number > 0"),
    ("samples = 3\n", r"s\.toml: samples: expected 1 when there is no \[draw\] table"),
    ('[grid]\nx = [1]\n[draw]\nx = {uniform = [0, 1]}\n', r"s\.toml: draw\.x: expected each key path varied once"),
    ('[[report.plot]]\nx = "a"\ny = "b"\nfit = true\n', r"s\.toml: report\.plot\[0\]\.fit: expected logx = true"),
])
def test_bad_sweep_files_are_one_line_errors(tmp_path, body, message):
    with pytest.raises(SweepError, match=message) as info:
        load_sweep(write_sweep(tmp_path, body))
    assert "\n" not in str(info.value)


def test_missing_base_scenario_is_named(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text('name = "s"\ndescription = "d"\nscenario = "nope.toml"\n')
    with pytest.raises(SweepError, match=r"s\.toml: scenario: expected an existing scenario file.*'nope\.toml'"):
        load_sweep(path)


# -- engines, failures, resume ---------------------------------------------------------------------
CHAIN_SWEEP = """
[grid]
r = [2, 3]
period = {logspace = [0.01, 0.1], num = 3}
[grid.bad]                 # k = 0.5 is outside (-1/r, 0]: HongController rejects it, the run fails
k = [-0.1, 0.5]
"""


def test_same_table_serially_on_two_processes_and_on_a_two_worker_dask_cluster(tmp_path):
    """The table depends on the sweep only: serial, 2 spawned processes, a 2-worker dask LocalCluster."""
    rows = expand(load_sweep(write_sweep(tmp_path, CHAIN_SWEEP)))
    tables = {}
    for engine, workers in (("serial", 1), ("processes", 2), ("dask", 2)):
        out = run_sweep("s", rows, ChainTask(), tmp_path / engine, {"base": "chain"}, engine=engine,
                        workers=workers, progress=None)
        assert (out.total, out.done, out.ran, out.failed, out.lost) == (12, 12, 12, 6, [])
        tables[engine] = results(read_table(out.table))
    assert tables["processes"] == tables["serial"]
    assert tables["dask"] == tables["serial"]
    t = tables["serial"]
    assert t["row"] == list(range(12))
    ok = [i for i, s in enumerate(t["status"]) if s == "completed"]
    assert [t["k"][i] for i in ok] == [-0.1] * 6
    # a value computed independently: row 0 alone, in this process
    direct = ChainTask()(0, rows[0].params)["metrics"]["final_abs_z1"]
    assert t["metrics.final_abs_z1"][0] == direct


def test_a_failing_combination_is_a_failed_row_and_the_sweep_finishes(tmp_path):
    rows = expand(load_sweep(write_sweep(tmp_path, CHAIN_SWEEP)))
    out = run_sweep("s", rows, ChainTask(), tmp_path / "o", {}, progress=None)
    t = read_table(out.table)
    for i in range(12):
        if t["k"][i] == 0.5:
            assert t["status"][i] == "failed"
            assert t["error"][i].startswith("ParameterError: k: expected -1/r")
            assert t["metrics.final_abs_z1"][i] is None
        else:
            assert t["status"][i] == "completed" and t["error"][i] == ""
            assert t["metrics.final_abs_z1"][i] > 0
    assert out.done == 12 and not out.interrupted
    # the sweep's own wall: from the first run's start to the table written, within the call; serial runs
    # follow one another inside it (2 ms: the two clocks, time.time and perf_counter, read apart)
    assert sum(t["elapsed_s"]) <= out.rows_wall_s <= out.elapsed_s + 2e-3
    again = run_sweep("s", rows, ChainTask(), tmp_path / "o", {}, resume=True, progress=None)
    assert again.ran == 0 and again.rows_wall_s == 0.0  # nothing ran: no first run


class InterruptAt:
    """Runs ``task`` but raises KeyboardInterrupt (Ctrl-C) on the run whose params include ``at``."""

    def __init__(self, task, at):
        self.task, self.at, self.calls = task, at, []

    def __call__(self, index, params):
        if self.at in params:
            raise KeyboardInterrupt
        self.calls.append(params)
        return self.task(index, params)


def test_resume_after_an_interruption_runs_only_the_missing_rows(tmp_path):
    rows = expand(load_sweep(write_sweep(tmp_path, CHAIN_SWEEP)))
    first = InterruptAt(ChainTask(), ("period", 0.1))  # Ctrl-C at row 4, the first with period 0.1 s
    out = run_sweep("s", rows, first, tmp_path / "o", {"base": 1}, progress=None)
    assert out.interrupted and out.done == 4 and [p for p in first.calls] == [r.params for r in rows[:4]]
    assert read_table(out.table)["row"] == [0, 1, 2, 3]  # the partial table is written
    # the journal may end with a line cut by a kill: it is dropped, not fatal
    journal = tmp_path / "o" / "s.jsonl"
    journal.write_bytes(journal.read_bytes() + b'{"row": 5, "sam')
    with pytest.raises(SweepError, match=r"o: s: expected an output directory without this sweep \(or --resume"):
        run_sweep("s", rows, ChainTask(), tmp_path / "o", {"base": 1}, progress=None)
    with pytest.raises(SweepError, match=r"s\.sweep\.json: fingerprint: expected the sweep being resumed"):
        run_sweep("s", rows, ChainTask(), tmp_path / "o", {"base": 2}, resume=True, progress=None)
    second = InterruptAt(ChainTask(), ("never", 0))
    out = run_sweep("s", rows, second, tmp_path / "o", {"base": 1}, resume=True, progress=None)
    assert not out.interrupted and (out.done, out.ran) == (12, 8)
    assert second.calls == [r.params for r in rows[4:]]  # finished rows, failed ones included, not redone
    full = run_sweep("s", rows, ChainTask(), tmp_path / "full", {"base": 1}, progress=None)
    assert results(read_table(out.table)) == results(read_table(full.table))
    assert sorted(read_journal(journal)) == list(range(12))
    assert all(json.loads(line) for line in journal.read_text().splitlines())


# -- report ------------------------------------------------------------------------------------------
def test_report_fits_the_log_log_slope_of_each_series_from_completed_runs_only(tmp_path):
    from ftstab_mj.figures.sweep_report import make_report
    from ftstab_mj.studies.sweep.table import write_table

    body = ('[[report.plot]]\nx = "h"\ny = "metrics.acc"\nby = "r"\nlogx = true\nlogy = true\nfit = true\n'
            '[[report.plot]]\nx = "h"\ny = "metrics.other"\n')
    sw = load_sweep(write_sweep(tmp_path, body))
    rows, i = [], 0
    for r, (c, p) in {2: (2.0, 1.5), 3: (0.5, 3.0)}.items():
        for h in (1e-4, 1e-3, 1e-2):
            for sample, spread in enumerate((1 / 1.1, 1.0, 1.3)):  # 3 runs per point: the fit goes through the median
                acc = c * h ** p * spread
                rows.append({"row": i, "sample": sample, "h": h, "r": r, "status": "completed", "error": "",
                             "elapsed_s": 0.1, "metrics.acc": acc, "metrics.other": 1.0})
                i += 1
    rows.append({"row": i, "sample": 0, "h": 1e-2, "r": 2, "status": "diverged", "error": "|z| > 1e3",
                 "elapsed_s": 0.1, "metrics.acc": 1e6, "metrics.other": 1.0})  # not a result to fit
    table = write_table(rows, tmp_path / "s.parquet")
    paths, fits = make_report(sw, table, tmp_path / "report")
    assert [p.read_bytes()[:4] for p in paths] == [b"\x89PNG"] * 2
    assert [(f.series, f.points) for f in fits] == [("r = 2", 3), ("r = 3", 3)]
    assert fits[0].slope == pytest.approx(1.5, abs=1e-9) and fits[1].slope == pytest.approx(3.0, abs=1e-9)
    assert 10 ** fits[0].intercept == pytest.approx(2.0, rel=1e-9)


def test_report_names_a_missing_column(tmp_path):
    from ftstab_mj.figures.sweep_report import make_report
    from ftstab_mj.studies.sweep.table import write_table

    sw = load_sweep(write_sweep(tmp_path, '[[report.plot]]\nx = "h"\ny = "metrics.acc"\n'))
    table = write_table([{"row": 0, "sample": 0, "h": 1.0, "status": "completed", "metrics.acc_z": 1.0}],
                        tmp_path / "s.csv")
    with pytest.raises(SweepError, match=r"s\.toml: report\.plot\[0\]\.y: expected a column of the sweep's table, "
                                         r"found 'metrics\.acc' \(did you mean 'metrics\.acc_z'\?\)"):
        make_report(sw, table, tmp_path / "report")


class _Tty:
    def __init__(self):
        self.text = ""

    def isatty(self):
        return True

    def write(self, text):
        self.text += text

    def flush(self):
        pass


def test_progress_is_one_rewritten_status_line_on_a_terminal_and_one_line_per_row_elsewhere():
    """Terminal: the status ([done/total], rate, ETA, failures) rewritten at most every 0.5 s, a failed row's line
    kept above it; a log: each row's own line, nothing rewritten. 5 rows, 2 done earlier, a clock in s."""
    now = [0.0]
    tty = _Tty()
    shown = Progress(tty, 5, before=2, clock=lambda: now[0])
    for t, failed in ((1.0, False), (1.2, True), (1.3, False)):
        now[0] = t
        shown.step(failed, f"row at {t} {'failed' if failed else 'completed'}")
    shown.close()
    # at 1.0: 1 row/s, 2 left; at 1.2 the failure's line, then the status; at 1.3 the last row (shown though < 0.5 s)
    assert tty.text == ("\r[3/5] 1 rows/s, ~2 s left"
                        "\r" + " " * 25 + "\rrow at 1.2 failed\n"  # the status wiped, the line kept
                        "\r[4/5] 1.67 rows/s, ~1 s left, 1 failed"
                        "\r[5/5] 2.31 rows/s, 1 failed" + " " * 11  # the longer status before it wiped
                        + "\r[5/5] 2.31 rows/s, 1 failed\n")
    assert all(len(line) < 80 for line in tty.text.split("\r"))
    log = io.StringIO()
    shown = Progress(log, 3)
    for i in range(3):
        shown.step(i == 1, f"row {i}")
    shown.note("row 9: lost")
    shown.close()
    assert log.getvalue() == "row 0\nrow 1\nrow 2\nrow 9: lost\n"

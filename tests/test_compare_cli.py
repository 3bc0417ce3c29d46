"""`ftstab compare` end to end through the real CLI (shortened runs), its table, slopes and figures,
its bad-input errors, and law switching inside an ordinary sweep (whole controller tables)."""

import csv

import pyarrow.parquet as pq
import pytest

from conftest import ROOT, run_cli
from ftstab_mj.studies.compare import format_rows

SHIPPED = sorted((ROOT / "scenarios" / "compare").glob("*.toml"))
COLUMNS = ("label", "law", "discretization", "sim.period", "status", "settle_time_z1", "final_abs_z1", "effort_sq",
           "u_max_abs", "chattering_tv", "chattering_du_dt_var", "chattering_zero_crossings", "chattering_band_rms",
           "bound_applies", "beat_bound")


def _read_csv(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.stem)
def test_shipped_comparison_runs_through_the_cli(path, tmp_path):
    """Each shipped comparison by its name (as `sweep` takes shipped names), shortened to 0.3 s: one
    completed row per law and period, in CSV, Parquet and Markdown alike, the slopes table with one row per
    law, both figures written as PNG, the printed table no wider than a terminal's 100 columns."""
    res = run_cli("compare", path.stem, "--set", "sim.duration=0.3", "--out", tmp_path, "--workers", "2")
    assert res.returncode == 0, res.stderr[-2000:]
    name = path.stem
    rows = _read_csv(tmp_path / f"{name}.csv")
    labels = list(dict.fromkeys(r["label"] for r in rows))
    periods = sorted({float(r["sim.period"]) for r in rows})
    assert len(rows) == len(labels) * len(periods) == len(labels) * 4
    assert all(r["status"] == "completed" for r in rows), [(r["label"], r["error"]) for r in rows]
    r = int(path.stem[-1])  # cart_r2, cart_r3
    for col in COLUMNS + tuple(f"final_abs_z{i}" for i in range(1, r + 1)):
        assert col in rows[0], col
    table = pq.read_table(tmp_path / f"{name}.parquet").to_pydict()
    assert table["label"] == [row["label"] for row in rows]
    assert table["final_abs_z1"] == pytest.approx([float(row["final_abs_z1"]) for row in rows], rel=1e-15)
    slopes = _read_csv(tmp_path / f"{name}_slopes.csv")
    assert [s["label"] for s in slopes] == labels and f"slope_z{r}" in slopes[0]
    for fig in (f"{name}_accuracy.png", f"{name}_time.png"):
        assert (tmp_path / fig).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "log-log slopes" in res.stdout and "levant_qc" in res.stdout
    printed = res.stdout.split("\n", 3)[3]  # after the header (name: description, its base, its runs)
    assert max(len(line) for line in printed.splitlines() if not line.startswith("wrote ")) <= 100  # paths: the user's
    md = [line for line in (tmp_path / f"{name}.md").read_text().splitlines() if line.startswith("| ")]
    assert len(md) == 1 + len(rows) + 1 + len(labels)  # runs (header + rows), slopes (header + one per law)
    assert [line.split(" | ")[0][2:] for line in md[1:1 + len(rows)]] == [row["label"] for row in rows]


def test_the_printed_table_wraps_to_the_width_and_repeats_the_label():
    """format_rows with a width: every line fits, every cell is printed once, each block starts with the label."""
    rows = [{"label": f"law {i}", **{f"column_{j}": 10.0 ** (i - j) for j in range(12)}} for i in range(3)]
    columns = list(rows[0])
    text = format_rows(rows, columns, width=60)
    blocks = text.split("\n\n")
    assert len(blocks) > 1 and max(map(len, text.splitlines())) <= 60
    assert all(b.splitlines()[0].startswith("label") for b in blocks)
    headers = [h for b in blocks for h in b.splitlines()[0].split()]
    assert headers.count("label") == len(blocks) and sorted(set(headers) - {"label"}) == sorted(columns[1:])
    assert [line.split()[:2] for line in blocks[-1].splitlines()[1:]] == [["law", str(i)] for i in range(3)]


def _write(tmp_path, text):
    p = tmp_path / "c.toml"
    p.write_text(f'name = "c"\ndescription = "d"\nscenario = "{ROOT / "scenarios" / "cart_r2_robust.toml"}"\n' + text)
    return p


@pytest.mark.parametrize("text,where", [
    ('[[laws]]\nlabel = "a"\ncontroller = { law = "levant_qc", alpha = -1.0 }\n', "laws[0].controller"),
    ('[[laws]]\nlabel = "a"\ncontroller = { law = "levant_qc", alpha = 1.0, k = -0.2 }\n', "laws[0].controller"),
    ('[[laws]]\nlabel = "a"\ncontroller = { law = "no_such_law" }\n', "laws[0].controller"),
    ('[[laws]]\nlabel = "a"\ncontroller = { law = "linear", poles = [-1.0, -2.0] }\n'
     '[[laws]]\nlabel = "a"\ncontroller = { law = "linear", poles = [-1.0, -2.0] }\n', "laws[1].label"),
    ('colour = 1\n[[laws]]\nlabel = "a"\ncontroller = { law = "linear", poles = [-1.0, -2.0] }\n', "colour"),
    ('[grid]\n"sim.period" = [0.001, -1]\n[[laws]]\nlabel = "a"\ncontroller = { law = "linear", poles = [-1.0, -2.0] }\n',
     'grid."sim.period"'),
])
def test_bad_comparison_file_is_one_line_naming_the_key(tmp_path, text, where):
    res = run_cli("compare", _write(tmp_path, text), "--out", tmp_path / "out")
    assert res.returncode == 2, res.stderr
    assert len(res.stderr.strip().splitlines()) == 1 and "Traceback" not in res.stderr
    assert where in res.stderr
    assert not (tmp_path / "out").exists()  # nothing written before the input is valid


def test_a_sweep_can_switch_laws_with_whole_controller_tables(tmp_path):
    """A sweep grid over loops.cart.controller with whole tables runs every law (no parameter of another
    law left behind)."""
    sweep = tmp_path / "s.toml"
    sweep.write_text(f'name = "s"\ndescription = "d"\nscenario = "{ROOT / "scenarios" / "cart_r2_robust.toml"}"\n'
                     '[set]\n"sim.duration" = 0.2\n[grid]\n"loops.cart.controller" = [\n'
                     '  { law = "robust", k = -0.2, gains = [1.0, 2.0], phibar = 1.0, gamma_m = 0.5 },\n'
                     '  { law = "levant_qc", alpha = 5.0 },\n  { law = "super_twisting", surface = [3.0], L = 8.0 },\n]\n')
    res = run_cli("sweep", sweep, "--out", tmp_path / "out", "--format", "csv")
    assert res.returncode == 0, res.stderr
    rows = _read_csv(tmp_path / "out" / "s.csv")
    assert [r["status"] for r in rows] == ["completed"] * 3
    assert [r["metrics.loops.cart.law"] for r in rows] == ["robust", "levant_qc", "super_twisting"]

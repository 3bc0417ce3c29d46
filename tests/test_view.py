"""`ftstab view`: the Rerun recording of a run made from its MCAP log (`ftstab run` writes the .rrd only
with --rrd): Rerun's own readers find the plots, the plant in 3D and the blueprint in it."""

import subprocess
import sys
from pathlib import Path

from conftest import run_cli
from ftstab_mj.logs.reader import read_log


def test_view_makes_the_rrd_of_a_run_from_its_log(tmp_path):
    from rerun.chunk import RrdReader

    run = run_cli("run", "cart_r2_robust", "--out", tmp_path, "--set", "sim.duration=0.5")
    assert run.returncode == 0, run.stderr
    log = tmp_path / "cart_r2_robust.mcap"
    assert sorted(p.name for p in tmp_path.iterdir()) == [log.name]  # no .rrd unless asked
    assert f"look: ftstab view {log}" in run.stdout
    res = run_cli("view", log, "--open", "none")
    assert res.returncode == 0, res.stderr
    rrd = tmp_path / "cart_r2_robust.rrd"
    assert res.stdout.startswith(f"wrote {rrd}: 500 samples of cart")
    rows = {}
    for chunk in RrdReader(str(rrd)).stream():
        rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
    data = read_log(log)
    n = data.n_samples
    for plot in ("z", "control", "V1/log10_V1", "adaptation"):  # each sample, + the series' style row
        assert rows[f"/loop/cart/{plot}"] == n + 1, plot
    assert rows["/world/cart"] == len(data.pose_t) > 0  # the cart's poses, at the log's display rate
    assert rows["/world/cart/cart"] == 1 and rows["/world/world/rail"] == 1  # its geoms, static
    assert rows["/run/status"] >= 1 and rows["/run/scenario"] == 1 and rows["/loop/cart/V1/envelope"] > 2
    printed = subprocess.run([str(Path(sys.executable).parent / "rerun"), "rrd", "print", str(rrd)],
                             capture_output=True, text=True, timeout=120).stdout
    assert "Blueprint" in printed and printed.count("ViewBlueprint:class_identifier") >= 5  # 3D + 4 plots


def test_view_of_a_file_that_is_not_a_log_is_one_line_and_writes_nothing(tmp_path):
    bad = tmp_path / "notes.mcap"
    bad.write_bytes(b"my notes, not a log\n" * 10)
    res = run_cli("view", bad, "--open", "none")
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1 and "Traceback" not in res.stderr
    assert str(bad) in res.stderr and not (tmp_path / "notes.rrd").exists()


def test_view_of_standard_input_needs_a_name_for_its_recording():
    res = run_cli("view", "-", "--open", "none")
    assert res.returncode == 2 and res.stderr.strip() == (
        "error: view -: expected --rrd OUT.rrd for a log read from standard input, found none")

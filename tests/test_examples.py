"""The examples gallery (examples/, docs/examples.md): each script runs in a temporary folder as a user
would run it, writes the figure it shows (a real image, not an empty canvas), and one property of the
run it made is checked here, from its own files, not from what the script prints. The notebook is
executed with nbclient and must draw its figure inline."""

import base64
import csv
import io
import os
import subprocess
import sys

import numpy as np
import pytest
from conftest import ROOT, run_cli

import ftstab_mj

EXAMPLES = ROOT / "examples"


def run_example(name, tmp_path, *args, timeout=300):
    env = dict(os.environ, MPLBACKEND="Agg")
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH", "")) if p)
    proc = subprocess.run([sys.executable, str(EXAMPLES / name), "--out", str(tmp_path / "out"), *args],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return tmp_path / "out", proc.stdout


def assert_figure(png):
    """A PNG of at least 400 x 300 pixels with a drawing on it: many colours, and a good share of the
    pixels away from the background (an empty axes box has a handful of colours and ~1 % ink)."""
    import matplotlib.image

    data = png.read_bytes() if hasattr(png, "read_bytes") else png
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    img = matplotlib.image.imread(io.BytesIO(data), format="png")[..., :3]
    h, w = img.shape[:2]
    assert w >= 400 and h >= 300, (w, h)
    colours = np.unique((img * 255).astype(np.uint8).reshape(-1, 3), axis=0)
    assert len(colours) >= 50, len(colours)
    background = np.median(img.reshape(-1, 3), axis=0)
    ink = np.mean(np.abs(img - background).max(axis=-1) > 0.1)
    assert ink >= 0.03, ink


def test_every_example_is_in_the_gallery_and_tested():
    """Each script and notebook of examples/ is run here and listed on docs/examples.md."""
    here = (ROOT / "tests" / "test_examples.py").read_text()
    page = (ROOT / "docs" / "examples.md").read_text()
    scripts = {p.name for p in EXAMPLES.glob("*.py")} - {"my_laws.py"}  # the plugin, run by my_law.py
    notebooks = {p.name for p in EXAMPLES.glob("*.ipynb")}
    assert len(scripts) >= 5 and notebooks
    for name in scripts | notebooks:
        assert f'"{name}"' in here, f"{name} is not run by tests/test_examples.py"
        assert f"examples/{name}" in page, f"{name} is not on docs/examples.md"


def test_quick_start_replays_bit_for_bit_and_settles_before_theorem_1s_bound(tmp_path):
    out, stdout = run_example("quick_start.py", tmp_path)
    assert_figure(out / "quick_start.png")
    assert "replayed samples identical: True; metrics identical: True" in stdout
    log = ftstab_mj.replay(out / "cart_r2_robust.mcap")
    m = log.metrics["loops"]["cart"]
    assert log.status == "completed" and m["bound_applies"]
    assert m["settle_time"] is not None and m["settle_time"] < m["time_bound"]
    assert log.samples["cart"]["V1"][-1] < m["settle_level"]
    # and the log re-runs to the same values, bit for bit
    proc = run_cli("replay", out / "cart_r2_robust.mcap", "--verify")
    assert proc.returncode == 0 and "bit-identical" in proc.stdout, proc.stdout + proc.stderr


def test_your_robot_keeps_within_the_computed_bounds_and_beats_the_time_bound(tmp_path):
    """gymnasium's reacher: the true phi and gamma MuJoCo recorded at every sample stay within the
    phibar and gamma_m computed from the model (a grid maximum over the workspace: gamma_m is met with
    equality at the start pose, hence the 1e-12 relative slack), nothing left the workspace, and both
    loops settle before Theorem 1's T(z0)."""
    out, _ = run_example("your_robot.py", tmp_path)
    assert_figure(out / "your_robot.png")
    log = ftstab_mj.replay(out / "reacher.mcap")
    assert log.status == "completed"
    assert set(log.samples) == {"shoulder", "elbow"}
    for name, s in log.samples.items():
        law, m = log.scenario["loops"][name]["controller"], log.metrics["loops"][name]
        assert np.abs(s["phi"]).max() <= law["phibar"], name
        assert s["gamma"].min() >= law["gamma_m"] * (1 - 1e-12), name
        assert m["workspace_left"] == "" and m["bound_applies"], name
        assert m["settle_time"] is not None and m["settle_time"] < m["time_bound"], name


def test_my_law_plugin_reaches_the_sampling_floor_and_its_log_verifies(tmp_path):
    """The plugin law drives |z1| below 1e-6 m and keeps it there over the last second (the linear law
    of the figure is still at ~1e-4 m); the log pins the plugin file, and `replay --verify` re-runs it
    bit for bit from that file."""
    out, stdout = run_example("my_law.py", tmp_path)
    assert_figure(out / "my_law.png")
    log = ftstab_mj.replay(out / "my_law.mcap")
    s = log.samples["cart"]
    assert log.status == "completed" and log.scenario["loops"]["cart"]["controller"]["law"] == "bhat_bernstein"
    last = s["t"] >= s["t"][-1] - 1.0
    assert np.abs(s["z"][last, 0]).max() < 1e-6
    proc = run_cli("replay", out / "my_law.mcap", "--verify", cwd=tmp_path)
    assert proc.returncode == 0 and "bit-identical" in proc.stdout, proc.stdout + proc.stderr


def test_compare_laws_shows_levants_second_order_accuracy(tmp_path):
    """Levant's quasi-continuous controller (r = 2): final |z1| = O(h^2) in the control period h
    (Levant 2005), fitted by the command over three periods; the robust law beat Theorem 1's bound at
    each of them."""
    out, _ = run_example("compare_laws.py", tmp_path)
    for png in ("compare_laws_time.png", "compare_laws_accuracy.png"):
        assert_figure(out / png)
    with open(out / "compare_laws_slopes.csv", newline="") as f:
        slopes = {row["label"]: float(row["slope_z1"]) for row in csv.DictReader(f)}
    assert 1.6 <= slopes["levant_qc"] <= 2.4, slopes
    with open(out / "compare_laws.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    robust = [row for row in rows if row["label"] == "robust"]
    assert len(robust) == 3 and all(row["status"] == "completed" and row["beat_bound"] == "True" for row in robust)


def test_sweep_report_finds_the_robust_laws_accuracy_linear_in_the_period(tmp_path):
    """The band the robust law settles into is O(h): fitted here on the sweep's own table (slope in
    [0.8, 1.4], r^2 >= 0.98 on log-log axes), and drawn by the report."""
    out, _ = run_example("sweep_report.py", tmp_path)
    pngs = sorted((out / "report").glob("*.png"))
    assert len(pngs) == 1
    assert_figure(pngs[0])
    with open(out / "sweep_period.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 5 and all(row["status"] == "completed" for row in rows)
    x = np.log([float(row["sim.period"]) for row in rows])
    y = np.log([float(row["metrics.loops.cart.final_abs_z_max[0]"]) for row in rows])
    slope, intercept = np.polyfit(x, y, 1)
    r2 = 1 - np.sum((y - (slope * x + intercept)) ** 2) / np.sum((y - y.mean()) ** 2)
    assert 0.8 <= slope <= 1.4 and r2 >= 0.98, (slope, r2)


def test_the_tutorial_notebook_executes_and_draws_inline(tmp_path, monkeypatch):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")
    # the kernel is a new process: it imports the checkout under test, and draws with the inline backend
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH", "")) if p))
    monkeypatch.delenv("MPLBACKEND", raising=False)
    nb = nbformat.read(EXAMPLES / "tutorial.ipynb", as_version=4)
    nbclient.NotebookClient(nb, timeout=300, kernel_name="python3",
                            resources={"metadata": {"path": str(tmp_path)}}).execute()
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    images = [o["data"]["image/png"] for o in outputs if "image/png" in o.get("data", {})]
    assert len(images) == 1
    assert_figure(base64.b64decode(images[0]))
    text = "".join(o.get("text", "") for o in outputs if o.output_type == "stream")
    assert "identical samples: True" in text and "identical metrics: True" in text
    import re

    settled = re.findall(r"^settled \(V1 < 0\.0001\) at ([0-9.]+) s; Theorem 1's bound T\(z0\) = ([0-9.]+) s$", text, re.M)
    assert len(settled) == 1 and float(settled[0][0]) < float(settled[0][1]), text
    assert (tmp_path / "runs" / "cart_r2_robust.mcap").stat().st_size > 0

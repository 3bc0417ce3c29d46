"""A built wheel works on its own: models and shipped scenarios travel inside the package.

Builds the wheel from this checkout (no network: no build isolation, no dependencies), unpacks it
in an empty folder, and runs the command from there with the source tree out of sys.path.
"""

import os
import subprocess
import sys
import zipfile

from conftest import ROOT


def test_wheel_carries_models_and_scenarios_and_runs_without_the_source_tree(tmp_path):
    build = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(tmp_path), str(ROOT)],
        capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert build.returncode == 0, build.stderr[-2000:]
    (wheel,) = tmp_path.glob("ftstab_mj-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    for model in sorted(p.name for p in (ROOT / "models").glob("*.xml")):
        assert f"ftstab_mj/_data/models/{model}" in names
    assert "ftstab_mj/_data/scenarios/cart_r2_robust.toml" in names
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["PYTHONPATH"] = str(site)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    res = subprocess.run([sys.executable, "-m", "ftstab_mj", "run", "cart_r2_robust", "--set", "sim.duration=0.5",
                          "--out", str(elsewhere / "runs")], capture_output=True, text=True, cwd=elsewhere, env=env,
                         timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    assert (elsewhere / "runs" / "cart_r2_robust.mcap").stat().st_size > 0
    # The command ran from the unpacked wheel, not from the checkout.
    probe = subprocess.run([sys.executable, "-c", "import ftstab_mj.resources as r; print(r.data_dir('models'))"],
                           capture_output=True, text=True, cwd=elsewhere, env=env)
    assert probe.stdout.strip().startswith(str(site))

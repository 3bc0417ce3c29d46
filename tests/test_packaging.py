"""A built wheel works on its own: models and shipped scenarios travel inside the package.

Builds the wheel from this checkout (no network: no build isolation, no dependencies), unpacks it
in an empty folder, and runs the command from there with the source tree out of sys.path.
"""

import ast
import importlib.metadata
import os
import re
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

from conftest import ROOT


def _tracked_copy(dest: Path) -> Path:
    """The checkout's tracked files copied to ``dest``: a build there leaves the checkout untouched
    (setuptools writes build/ and *.egg-info/ beside the sources it builds)."""
    files = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    for name in filter(None, files.decode().split("\0")):
        target = dest / name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / name, target)
    return dest


def test_wheel_carries_models_and_scenarios_and_runs_without_the_source_tree(tmp_path):
    source = _tracked_copy(tmp_path / "source")
    build = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-v", "-w", str(tmp_path), str(source)],
        capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert build.returncode == 0, build.stderr[-2000:]
    # the metadata is in a form setuptools keeps accepting (the license table stops on 2027-02-18)
    assert "SetuptoolsDeprecationWarning" not in build.stdout + build.stderr, build.stdout[-3000:]
    (wheel,) = tmp_path.glob("ftstab_mj-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    for model in sorted(p.name for p in (ROOT / "models").glob("*.xml")):
        assert f"ftstab_mj/_data/models/{model}" in names
    assert "ftstab_mj/_data/scenarios/cart_r2_robust.toml" in names
    for layout in sorted(p.name for p in (ROOT / "ftstab_mj" / "logs" / "layouts").glob("*.json")):
        assert f"ftstab_mj/logs/layouts/{layout}" in names  # the shipped Foxglove layouts
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
    probe = subprocess.run([sys.executable, "-c", "import ftstab_mj.config.resources as r; print(r.data_dir('models'))"],
                           capture_output=True, text=True, cwd=elsewhere, env=env)
    assert probe.stdout.strip().startswith(str(site))


def _requirement_name(req: str) -> str:
    return re.sub(r"[-_.]+", "-", re.match(r"[A-Za-z0-9._-]+", req).group(0)).lower()


def test_every_imported_package_is_declared_and_the_license_is_an_spdx_expression():
    """Each third-party module that ftstab_mj imports (anywhere, lazily too) comes from a distribution
    listed in pyproject's dependencies, not only from another dependency's requirements."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert isinstance(project["project"]["license"], str)  # PEP 639 SPDX expression
    assert "setuptools>=77" in project["build-system"]["requires"]  # the first setuptools that reads it
    declared = {_requirement_name(r) for r in project["project"]["dependencies"]}
    imported = set()
    for path in (ROOT / "ftstab_mj").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                imported.update(a.name.split(".")[0] for a in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                imported.add(node.module.split(".")[0])
    third_party = sorted(m for m in imported if m not in sys.stdlib_module_names and m != "ftstab_mj")
    assert "numpy" in third_party and "pyarrow" in third_party  # the walk sees lazy imports too
    dists = importlib.metadata.packages_distributions()
    missing = {m: dists.get(m) for m in third_party
               if not {_requirement_name(d) for d in dists.get(m, [m])} & declared}
    assert not missing, f"imported but not in pyproject's dependencies (module: distributions): {missing}"


def test_the_version_is_written_once_and_the_changelog_names_it():
    """pyproject reads the version from ftstab_mj.__version__; the CHANGELOG's newest entry is that
    version (a format change bumps both), as is CITATION.cff's; the LICENSE is the license the metadata declares."""
    import ftstab_mj

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert "version" not in project["project"] and "version" in project["project"]["dynamic"]
    assert project["tool"]["setuptools"]["dynamic"]["version"] == {"attr": "ftstab_mj.__version__"}
    first = next(line for line in (ROOT / "CHANGELOG.md").read_text().splitlines() if line.startswith("## "))
    assert first.split()[1] == ftstab_mj.__version__
    cited = [line.split(":", 1)[1].strip() for line in (ROOT / "CITATION.cff").read_text().splitlines()
             if line.startswith("version:")]
    assert cited == [ftstab_mj.__version__]  # a citation names the version it used (it said 0.1.0 at 0.3.0)
    assert project["project"]["license"] == "MIT" and (ROOT / "LICENSE").read_text().startswith("MIT License")

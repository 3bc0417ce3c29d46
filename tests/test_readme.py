"""The README's quick start: exactly two commands; CI runs the test one verbatim; the run one works."""

import re
import shlex
import subprocess
from pathlib import Path

from conftest import ROOT, run_cli

INSTALL = "python -m pip install -e ."


def quick_start() -> list[str]:
    """The command lines of the first code block after the '## Quick start' heading."""
    text = (ROOT / "README.md").read_text()
    section = text.split("## Quick start", 1)[1]
    block = re.search(r"```sh\n(.*?)```", section, re.S).group(1)
    return [line for line in block.splitlines() if line.strip()]


def test_quick_start_has_two_commands_and_ci_runs_the_test_one_verbatim():
    commands = quick_start()
    assert len(commands) == 2
    ci_lines = [line.strip() for line in (ROOT / ".ci" / "run").read_text().splitlines()]
    assert commands[1] in ci_lines
    assert commands[1] == 'python -m pip install -e ".[test]" && python -m pytest -n 2'


def test_quick_start_run_command_runs_the_default_scenario(tmp_path):
    """The part after the install, run as written from a directory that has the repository's
    scenarios/ (the install itself is exercised by .ci/run on a fresh virtual environment)."""
    install, _, run = quick_start()[0].partition(" && ")
    assert install == INSTALL
    argv = shlex.split(run)
    assert argv[:3] == ["python", "-m", "ftstab_mj"]
    (tmp_path / "scenarios").symlink_to(ROOT / "scenarios")
    proc = run_cli(*argv[3:], cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    out = argv[argv.index("--out") + 1]
    name = Path(argv[4]).stem
    assert name == "cart_r2_robust"  # the default scenario
    assert f"{name}: " in proc.stdout and "status completed" in proc.stdout
    assert (tmp_path / out / f"{name}.mcap").stat().st_size > 0 and (tmp_path / out / f"{name}.rrd").stat().st_size > 0


def test_no_tracked_file_sends_users_to_the_teams_private_notes():
    """Users never see the team's shared folder: no tracked file names it or its notes (the
    formulas a module implements are restated in the project's own docs)."""
    names = [".." + "/shared", *(stem + ".md" for stem in ("NOTES", "DESIGN", "LITERATURE"))]  # not literal here
    tracked = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout.split(b"\0")
    found = [(path.decode(), name) for path in tracked if path and (ROOT / path.decode()).is_file()
             for name in names if name.encode() in (ROOT / path.decode()).read_bytes()]
    assert found == []

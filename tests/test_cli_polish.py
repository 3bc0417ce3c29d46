"""Command-line polish, through the real command: --version, the bare command, a closed pipe, a
scenario name that does not exist."""

import subprocess
import sys

from conftest import ROOT, run_cli
from ftstab_mj import __version__


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

"""Shared fixtures. The autouse fixture enforces that global MuJoCo state is put back."""

import os
import re
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def pytest_configure(config):
    """Build the native kernel in place first (a no-op when it is up to date or installed), so that a
    source checkout tests the C path that ``pip install`` ships, not only the Python fallback. Once,
    in the main process (xdist workers start after it). A failed build (no compiler) leaves the
    native tests skipped, or failing under FTSTAB_REQUIRE_NATIVE=1 (CI). The compiler's intermediate
    files go to a temporary folder: the only file the build leaves in the checkout is the kernel
    itself (git-ignored, where an editable install puts it too)."""
    if os.environ.get("PYTEST_XDIST_WORKER") or not (ROOT / "setup.py").exists():
        return
    with tempfile.TemporaryDirectory() as temp:
        subprocess.run([sys.executable, "setup.py", "-q", "build_ext", "--inplace", "--build-temp", temp,
                        "--build-lib", temp], cwd=ROOT,
                       capture_output=True, timeout=300)


@pytest.fixture(autouse=True)
def no_control_callback_left_installed():
    """After every test, MuJoCo's global control callback is what it was before (None), and so is
    its timer callback (mjcb_time, which runs switch off)."""
    import mujoco

    from ftstab_mj.plants.callback import _timer_slot

    timer = _timer_slot()
    timer_before = timer.value if timer is not None else None
    before = mujoco.get_mjcb_control()
    yield
    after = mujoco.get_mjcb_control()
    mujoco.set_mjcb_control(before)  # put it back so one failure does not cascade
    assert after is before, f"a test left a MuJoCo control callback installed: {after!r}"
    if timer is not None:
        timer_after, timer.value = timer.value, timer_before
        assert timer_after == timer_before, "a test left MuJoCo's timer callback (mjcb_time) changed"


def _terminal_signals():
    # A suite started in the background (non-interactive shell, `cmd &`) runs with SIGINT ignored,
    # one started under `nohup` with SIGHUP ignored; the children inherit that, and the command rightly
    # leaves an ignored signal ignored: a Ctrl-C or SIGHUP test would wait for a run that cannot be
    # interrupted. Give the child what a terminal gives: SIGINT, SIGTERM and SIGHUP at their default.
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_DFL)


def start_cli(*args, cwd=None, **popen_kwargs):
    """Start ``python -m ftstab_mj ARGS`` in the background as a user's shell would (SIGINT,
    SIGTERM and SIGHUP at their default, so signal tests work whatever started the suite; a
    ``preexec_fn`` given runs after that). Returns the Popen."""
    then = popen_kwargs.pop("preexec_fn", None)

    def preexec():
        _terminal_signals()
        if then is not None:
            then()

    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    popen_kwargs.setdefault("stdout", subprocess.PIPE)
    popen_kwargs.setdefault("stderr", subprocess.PIPE)
    return subprocess.Popen([sys.executable, "-m", "ftstab_mj", *map(str, args)], cwd=cwd or ROOT, env=env,
                            text=True, preexec_fn=preexec, **popen_kwargs)


def wait_for_samples(log, size=200_000, timeout=120):
    """Wait until the log at ``log`` holds ``size`` bytes (samples are being written: the run has started)."""
    import time

    deadline = time.monotonic() + timeout
    while (not log.exists() or log.stat().st_size < size) and time.monotonic() < deadline:
        time.sleep(0.05)


def free_port() -> int:
    """A TCP port free on 127.0.0.1 now (bound to 0, then released), for a server that needs a number."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run_cli(*args, cwd=None, timeout=600):
    """Run ``python -m ftstab_mj ARGS`` as a user would (fresh process). Returns CompletedProcess."""
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.run([sys.executable, "-m", "ftstab_mj", *map(str, args)], capture_output=True,
                          text=True, cwd=cwd or ROOT, env=env, timeout=timeout)


def run_args(tmp_path, base, edit, sets) -> tuple[Path, Path, list[str]]:
    """(scenario path, output dir, ``run`` arguments) for a case of a malformed-input table: ``base``
    (a shipped scenario, or None for a missing file) with ``edit`` = (old, new) replaced in its text
    (None: unchanged), written to tmp_path/bad.toml, and one ``--set`` per text of ``sets``."""
    path = tmp_path / "bad.toml"
    if base is not None:
        text = base.read_text()
        if edit is not None:
            assert edit[0] in text, "the edit must apply to the shipped file"
            text = text.replace(edit[0], edit[1])
        path.write_text(text)
    out = tmp_path / "out"
    args = ["run", str(path), "--out", str(out)]
    for s in sets:
        args += ["--set", s]
    return path, out, args


def rrd_rows(path, entity: str) -> int:
    """Rows logged to ``entity`` in an .rrd, read with Rerun's own decoder (``rerun rrd print``,
    the one the viewer uses), which reads a file cut by SIGKILL as far as it goes. The Python
    RrdReader refuses any file whose last frame is cut (measured: 0 rows at every cut offset)."""
    printed = subprocess.run([str(Path(sys.executable).parent / "rerun"), "rrd", "print", str(path)],
                             capture_output=True, text=True, timeout=120)
    assert printed.returncode == 0, printed.stderr[-1000:]
    return sum(int(n) for n in re.findall(rf"with (\d+) rows .* - {re.escape(entity)} -", printed.stdout))


def record_run(plant, loops, duration, period, physics_step, sinks=(), metrics=False, batch_size=1000,
               scenario_dict=None, **sim_kw):
    """A run of ``loops`` on ``plant`` recorded by ``sinks`` (the scenario runner's record): its RunResult."""
    from ftstab_mj.scenario.run import record
    from ftstab_mj.simulation.run_loop import Run, Simulation

    sim = Simulation(plant, loops, period, physics_step, **sim_kw)
    return record(Run(sim, duration, batch_size, scenario_dict, keep_samples=True), sinks, metrics)[0]

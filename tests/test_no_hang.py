"""Nothing hangs (issue 44, H1): process-pool workers killed mid-row, and the command killed under its
workers, through the real CLI. Every command runs in a process group of its own, with a deadline, and the
group is killed at the end whatever happened, so a failure here cannot hang the suite."""

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from conftest import ROOT, rrd_rows, start_cli
from ftstab_mj.logs.reader import read_log
from ftstab_mj.logs.rerun_sink import TIMELINE_MAX_S, on_timeline
from ftstab_mj.logs.verify import CROSS_PATH_ULPS, first_tolerated_difference
from ftstab_mj.simulation import native
from ftstab_mj.studies.sweep.table import read_table

DEADLINE = 60  # s: any command here ends well within this, or the test fails (and kills its group)


def children(pid: int) -> list[int]:
    """The live (not zombie) child processes of ``pid`` (Linux /proc)."""
    out = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid and fields[0] != "Z":
            out.append(int(entry))
    return sorted(out)


def alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def cpu_s(pid: int) -> float:
    """User + system CPU time of ``pid`` (s)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
    except OSError:  # gone
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def wait_for(predicate, timeout, what):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def start(*args, cwd=None):
    """The CLI in a process group of its own (killed by :func:`finish`)."""
    return start_cli(*args, cwd=cwd, start_new_session=True)


def finish(proc, timeout=DEADLINE):
    """(returncode, stdout, stderr) within ``timeout`` s; the group is killed in any case."""
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, err = proc.communicate()
        raise AssertionError(f"the command did not end within {timeout} s (hang); stderr:\n{err[-3000:]}") from None
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)  # whatever the command left in its group
        except ProcessLookupError:
            pass
    return proc.returncode, out, err


def busy_workers(proc, n=2, cpu=0.3):
    """The command's ``n`` pool workers, once each has run ``cpu`` s of CPU (they are mid-row)."""
    def running():
        workers = children(proc.pid)
        return workers if len(workers) >= n and all(cpu_s(w) >= cpu for w in workers) else None

    return wait_for(running, 30, f"{n} workers running rows")


def comparison(tmp_path, duration=150.0):
    """2 laws x 2 periods of the r = 2 cart; each row ~1 s and returns its time series (a result larger than
    a pipe's buffer: the pool of issue 44 hung on a worker blocked writing it)."""
    path = tmp_path / "tiny.toml"
    path.write_text(f'''name = "tiny"
description = "two laws, two periods"
scenario = "{ROOT / "scenarios" / "cart_r2_robust.toml"}"
steps_per_period = 5
[set]
"sim.duration" = {duration}
[grid]
"sim.period" = [1e-3, 2e-3]
[[laws]]
label = "robust"
controller = {{ law = "robust", k = -0.2, gains = [1.0, 2.0], phibar = 1.0, gamma_m = 0.7 }}
[[laws]]
label = "linear"
controller = {{ law = "linear", poles = [-3.0, -3.0] }}
''')
    return path


def sweep(tmp_path, duration=15.0, samples=2):
    path = tmp_path / "small.toml"
    path.write_text(f'''name = "small"
description = "killed workers"
scenario = "{ROOT / "scenarios" / "cart_r2_robust.toml"}"
seed = 3
samples = {samples}
[set]
"sim.duration" = {duration}
"sim.physics_step" = 1e-4
[grid]
"loops.cart.disturbance.amplitude" = [0.4, 0.8]
[draw]
"loops.cart.z0[0]" = {{uniform = [-1.0, 1.0]}}
''')
    return path


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM], ids=["SIGKILL", "SIGTERM"])
def test_compare_whose_worker_is_killed_mid_row_reruns_its_rows_and_ends(tmp_path, sig):
    """A worker of `ftstab compare --workers 2` killed mid-row: the pool sees the death at once, says which
    rows did not finish, runs them again on a fresh pool, and the table is whole (SIGKILL: the pool used to
    wait for ever on the other worker, blocked writing its result; SIGTERM: the worker's inherited handler
    recorded its row "interrupted", a result that is none)."""
    out = tmp_path / "o"
    proc = start("compare", comparison(tmp_path), "--workers", "2", "--out", out)
    try:
        victim = busy_workers(proc)[0]
        os.kill(victim, sig)
    finally:
        code, stdout, err = finish(proc)
    assert code == 0, err
    assert "warning: a worker process died; rows " in err and "run again on a fresh pool (once)" in err, err
    t = read_table(out / "tiny.parquet")
    assert t["status"] == ["completed"] * 4, (t["status"], err)


def test_sweep_whose_worker_is_killed_mid_row_reruns_its_rows_and_ends(tmp_path):
    out = tmp_path / "o"
    proc = start("sweep", sweep(tmp_path), "--workers", "2", "--out", out)
    try:
        os.kill(busy_workers(proc)[-1], signal.SIGKILL)
    finally:
        code, _, err = finish(proc)
    assert code == 0, err
    assert "warning: a worker process died; row" in err, err
    assert read_table(out / "small.parquet")["status"] == ["completed"] * 4


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM], ids=["SIGKILL", "SIGTERM"])
def test_killing_the_command_leaves_none_of_its_workers_behind(tmp_path, sig):
    """SIGKILL of `ftstab sweep` under its 2 pool workers: they die with it (a parent-death signal), not
    orphaned to run on; SIGTERM: the command stops at once (it does not wait for the workers' rows), exit 143,
    with the finished rows in the table."""
    out = tmp_path / "o"
    proc = start("sweep", sweep(tmp_path, duration=60.0), "--workers", "2", "--out", out)
    try:
        workers = busy_workers(proc)
        t0 = time.monotonic()
        os.kill(proc.pid, sig)
        proc.wait(timeout=DEADLINE)
        stopped = time.monotonic() - t0
        wait_for(lambda: not any(alive(w) for w in workers), 10, f"the workers {workers} to die with the command")
    finally:
        code, _, err = finish(proc)
    if sig == signal.SIGTERM:
        assert code == 143 and "interrupted" in err and stopped < 10, (code, stopped, err)
        assert (out / "small.parquet").exists()
    else:
        assert code == -signal.SIGKILL


def run_to_end(*args, timeout=DEADLINE):
    return finish(start(*args), timeout)


@pytest.mark.parametrize("how", ["serve", "url"])
def test_a_rerun_port_held_by_a_socket_that_never_answers_is_refused_in_one_line(tmp_path, how):
    """H2: `--live serve --grpc-port P` with P held by another program (here a loopback socket that listens and
    never accepts) took P for a running Rerun server and streamed into it for ever; so did `--live URL` of
    it. Now: exit 2 within seconds, one line naming the port, no log written."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        live = (["--live", "serve", "--grpc-port", port, "--web-port", "0"] if how == "serve"
                else ["--live", f"rerun+http://127.0.0.1:{port}/proxy"])
        t0 = time.monotonic()
        code, _, err = run_to_end("run", "cart_r2_robust", "--set", "sim.duration=0.2", "--out", tmp_path / "o", *live,
                                  timeout=30)
    assert code == 2 and time.monotonic() - t0 < 20, (code, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: --") and str(port) in lines[0], err
    assert not list((tmp_path / "o").glob("*.mcap")) and not list((tmp_path / "o").glob("*.rrd"))


def test_a_live_url_where_nothing_listens_is_refused_in_one_line(tmp_path):
    from conftest import free_port

    port = free_port()
    code, _, err = run_to_end("run", "cart_r2_robust", "--set", "sim.duration=0.2", "--out", tmp_path / "o",
                              "--live", f"rerun+http://127.0.0.1:{port}/proxy", timeout=30)
    assert code == 2 and err.strip().splitlines() == [
        f"error: --live rerun+http://127.0.0.1:{port}/proxy: expected a Rerun viewer or server answering on "
        f"127.0.0.1:{port}, found none (nothing listens, or no gRPC answer within 2 s)"], err


KILLER = '''
"""A PD law that kills its process (SIGKILL) at its first evaluation when kp = 666: a row that always loses its
worker."""
import os
import signal
from dataclasses import dataclass

import numpy as np

from ftstab_mj.control import Law, LawOutput, Param, register_law


@register_law
@dataclass(frozen=True)
class KillerPD(Law):
    name = "killer_pd"
    summary = "u = -kp z1 - kd z2; kp = 666 kills the process"
    params = (Param("kp", float, "proportional gain", "1/s^2"), Param("kd", float, "derivative gain", "1/s"))
    r: int
    kp: float
    kd: float

    @classmethod
    def from_params(cls, r, values):
        return cls(r, float(values["kp"]), float(values["kd"]))

    def evaluate(self, z, state):
        if self.kp == 666.0:
            os.kill(os.getpid(), signal.SIGKILL)
        z = np.asarray(z, dtype=float)
        u = -self.kp * z[..., 0] - self.kd * z[..., 1]
        nan = np.full_like(u, np.nan)
        return LawOutput(u, nan, nan, nan, nan, nan)
'''


def killer_folder(tmp_path, kp):
    (tmp_path / "killer.py").write_text(KILLER)
    (tmp_path / "pd.toml").write_text(f'''name = "pd"
description = "a PD law that may kill its worker"
plugins = ["{tmp_path / "killer.py"}"]
[plant]
model = "cart"
[sim]
duration = 0.5
period = 0.002
physics_step = 0.001
[loops.cart]
z0 = [1.0, 0.0]
[loops.cart.controller]
law = "killer_pd"
kp = {kp}
kd = 10.0
''')
    (tmp_path / "cmp.toml").write_text('''name = "cmp"
description = "one law whose rows always kill their worker"
scenario = "pd.toml"
[grid]
"sim.period" = [0.002, 0.004]
[[laws]]
label = "pd"
controller = { law = "killer_pd", kp = 25.0, kd = 10.0 }
[[laws]]
label = "killer"
controller = { law = "killer_pd", kp = 666.0, kd = 10.0 }
''')
    return tmp_path


def test_compare_rows_lost_by_dead_workers_are_an_error_naming_them(tmp_path):
    """W4: the rows of a law that kills its worker each time are run twice then lost: `ftstab compare` said
    nothing and exited 0. Now exit 1 and a line naming the lost rows."""
    d = killer_folder(tmp_path, 25.0)
    code, _, err = run_to_end("compare", d / "cmp.toml", "--workers", "2", "--out", d / "o")
    assert code == 1, err
    line = next(x for x in err.splitlines() if x.startswith("error: "))
    assert " run(s) lost by dead worker processes (rows " in line and "2, 3)" in line, err
    t = read_table(d / "o" / "cmp.parquet")
    # a broken pool drops the chunks of every worker: the healthy rows may be lost with the killer's
    assert t["status"][2:] == ["lost", "lost"] and len(t["status"]) == 4


def test_montecarlo_states_lost_by_dead_workers_are_an_error(tmp_path):
    d = killer_folder(tmp_path, 666.0)
    code, _, err = run_to_end("montecarlo", d / "pd.toml", "--on", "plant", "--states", "4", "--workers", "2",
                              "--out", d / "o")
    assert code == 1, err
    assert "error: 4 state(s) lost by dead worker processes (rows 0, 1, 2, 3)" in err, err


# -- W2: a log records its kernel path; --verify compares across paths within the stated tolerance -------------

# ``python -m ftstab_mj`` on the Python path: the C kernel made unavailable before the command starts
PYTHON_PATH = ("import sys; import ftstab_mj.simulation.native as n; n.LIB = None; "
               "n.UNAVAILABLE_REASON = 'kernel off for this test'; from ftstab_mj.cli import main; sys.exit(main(sys.argv[1:]))")


def cli_on(kernel: str, *args, cwd):
    """(returncode, stdout, stderr) of the CLI on ``kernel`` ("native" | "python"), in a group of its own."""
    if kernel == "native":
        return finish(start(*args, cwd=cwd))
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.Popen([sys.executable, "-c", PYTHON_PATH, *map(str, args)], cwd=cwd, env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    return finish(proc)


@pytest.mark.skipif(not native.available(), reason=f"native kernel: {native.UNAVAILABLE_REASON}")
@pytest.mark.parametrize("written,replayed", [("native", "python"), ("python", "native"), ("native", "native"),
                                              ("python", "python")])
def test_verify_compares_across_kernel_paths_within_the_stated_tolerance(tmp_path, written, replayed):
    code, _, err = cli_on(written, "run", "cart_r2_adaptive", "--out", tmp_path, "--set", "sim.duration=1", cwd=tmp_path)
    assert code == 0, err
    log = tmp_path / "cart_r2_adaptive.mcap"
    assert read_log(str(log)).info.kernel == written  # the log says which path wrote it
    code, out, err = cli_on(replayed, "replay", log, "--verify", cwd=tmp_path)
    assert code == 0, err
    assert f"{written} kernel path" in out
    if written == replayed:  # same path: bit for bit, as before
        assert "logged values are bit-identical" in out
    elif "within the cross-path tolerance" in out:
        assert f"(written on the {written} kernel path, re-run on the {replayed} one; largest difference " in out
        worst = float(out.split("largest difference ")[1].split(" of that tolerance")[0])
        assert 0 < worst <= 1  # within the tolerance, and not 0: a difference of 0 is said to be bit-identical
    else:  # 0 where NumPy's pow is libm's (x86-64 without AVX-512): the same operations, the same bits
        assert f"logged values are bit-identical (written on the {written} kernel path, re-run on the {replayed} one)" in out


def test_the_cross_path_tolerance_is_a_few_ulp_per_sample():
    x = np.array([[1.0, 3.0], [1e-3, -2.0], [5.0, 0.0]])
    one_ulp = np.nextafter(x, np.inf)
    assert first_tolerated_difference(x, one_ulp, np.arange(3))[0] is None
    # at sample 0 the bound is CROSS_PATH_ULPS ulp of max(1, |value|): one more is a difference
    beyond = x.copy()
    beyond[0, 1] += (CROSS_PATH_ULPS + 1) * np.finfo(float).eps * 3.0
    assert first_tolerated_difference(x, beyond, np.arange(3))[0] == 0
    # ... and the same difference at sample 1000 is within it (the loop carries the earlier ones)
    assert first_tolerated_difference(x, beyond, np.arange(1000, 1003))[0] is None
    # a value only one side has (non-finite on the other) is a difference whatever the tolerance
    gone = x.copy()
    gone[2, 0] = np.nan
    assert first_tolerated_difference(x, gone, np.arange(10 ** 6, 10 ** 6 + 3))[0] == 2


# -- W5: every sink survives any gain the validator accepts ------------------------------------------------------

def test_a_time_bound_of_centuries_is_no_rerun_timeline_point_and_no_traceback(tmp_path):
    """k = -1e-12 is a valid homogeneity degree whose T(z0) is ~1e12 s, beyond Rerun's int64-ns timeline
    (292 years): the run with --rrd and `view` write their recordings, T stays a number in the metrics."""
    code, out, err = finish(start("run", "cart_r2_robust", "--out", tmp_path, "--rrd", "--set",
                                  "loops.cart.controller.k=-1e-12", "--set", "sim.duration=0.3", cwd=tmp_path))
    assert code == 0 and "Traceback" not in err, err
    T = float(next(line for line in out.splitlines() if line.strip().startswith("time_bound")).split()[1])
    assert T > TIMELINE_MAX_S  # the case does reach beyond the timeline
    assert rrd_rows(tmp_path / "cart_r2_robust.rrd", "/loop/cart/V1/envelope") > 0  # the envelope up to the run's end
    code, out, err = finish(start("view", tmp_path / "cart_r2_robust.mcap", "--open", "none", "--rrd",
                                  tmp_path / "view.rrd", cwd=tmp_path))
    assert code == 0 and "Traceback" not in err, err
    assert (tmp_path / "view.rrd").stat().st_size > 0


def test_the_timeline_keeps_the_times_it_can_hold():
    t = np.array([0.0, 1.0, 9.2e9, 9.3e9, 1e12, np.inf, np.nan, -1e13])
    assert on_timeline(t).tolist() == [True, True, True, False, False, False, False, False]


# -- the Python API: names are file names; a Foxglove address it cannot serve on is refused before the run ------

def test_an_api_scenario_name_never_writes_outside_the_output_folder(tmp_path):
    import dataclasses

    import ftstab_mj
    from ftstab_mj.config.errors import LogError, ScenarioError

    out = tmp_path / "deep" / "runs"
    with pytest.raises(ScenarioError, match=r"name: expected a non-empty name of ASCII letters"):
        ftstab_mj.run("cart_r2_robust", out=out, overrides={"name": "../escape", "sim.duration": 0.01})
    sc = dataclasses.replace(ftstab_mj.load_scenario("cart_r2_robust", {"sim.duration": 0.01}), name="../escape")
    with pytest.raises(LogError, match=r"the scenario name: expected .* found '\.\./escape'"):
        ftstab_mj.run(sc, out=out)  # a Scenario built by hand skips the loader: the log paths check it
    assert [p.name for p in tmp_path.rglob("*") if p.is_file()] == []


def test_an_api_foxglove_address_in_use_is_refused_before_the_run_and_leaves_no_log(tmp_path, monkeypatch):
    import socket

    import ftstab_mj
    from ftstab_mj.config.errors import LogError
    import ftstab_mj.logs.live as live

    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        port = held.getsockname()[1]
        with pytest.raises(LogError, match=rf"foxglove 127\.0\.0\.1:{port}: expected an address to serve on"):
            ftstab_mj.run("cart_r2_robust", out=tmp_path / "a", overrides={"sim.duration": 0.01},
                          foxglove=("127.0.0.1", port))
        assert not list((tmp_path / "a").glob("*"))  # no log at all
        # the port taken between the check and the first batch: the run fails in one line and its log is
        # complete (its summary, the status "failed" and why), never an MCAP cut short
        monkeypatch.setattr(live, "_check_bindable", lambda host, port: None)
        with pytest.raises(LogError, match=r"taken after the run was set up"):
            ftstab_mj.run("cart_r2_robust", out=tmp_path / "b", overrides={"sim.duration": 0.01},
                          foxglove=("127.0.0.1", port))
    log = read_log(str(tmp_path / "b" / "cart_r2_robust.mcap"))
    assert log.complete and log.recorded["status"] == "failed" and "foxglove" in log.recorded["message"]

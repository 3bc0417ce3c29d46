"""What makes a sweep cheap: rows validated once, worker processes forked where that is safe.

(The speed itself is measured in benchmarks/sweep_speedup.py, never here.)
"""

import json
import os
import pickle
import subprocess
import sys

import pytest

from conftest import ROOT
from ftstab_mj.studies.sweep import engine, expand, load_sweep
from ftstab_mj.studies.sweep import row as runner
from ftstab_mj.studies.sweep.run import run_sweep
from ftstab_mj.studies.sweep.row import ScenarioTask, prepare
from ftstab_mj.studies.sweep.table import read_table
from tests.sweep_chain import ChainTask, NoValidationTask, StopOnceTask
from tests.test_sweep_engine import CHAIN_SWEEP, results, write_sweep


def cart_sweep(tmp_path, samples=3):
    path = tmp_path / "cart.toml"
    path.write_text(f'''name = "cart"
description = "a few short cart runs"
scenario = "{ROOT / "scenarios" / "cart_r2_robust.toml"}"
seed = 5
samples = {samples}
[set]
"sim.duration" = 0.2
[draw]
"loops.cart.z0[0]" = {{uniform = [-1.0, 1.0]}}
''')
    return load_sweep(path)


def test_a_row_prepare_validated_runs_without_being_validated_again_and_gives_the_same_result(tmp_path, monkeypatch):
    sweep = cart_sweep(tmp_path)
    rows = expand(sweep)
    task, _ = prepare(sweep, rows)
    fresh = ScenarioTask(task.base, task.source)  # no prepared scenarios: validates each row itself
    expected = [fresh(r.index, r.params) for r in rows]

    def no_second_validation(*args):
        raise AssertionError("a row prepare() validated was validated again")

    monkeypatch.setattr(ScenarioTask, "scenario", no_second_validation)
    assert [task(r.index, r.params) for r in rows] == expected
    assert runner._PREPARED[task.token] == {}  # each kept scenario is used once, then dropped
    token = task.token
    del task
    assert token not in runner._PREPARED  # and the store goes with its task


def test_a_row_whose_parameters_differ_from_the_prepared_ones_is_validated_again(tmp_path):
    sweep = cart_sweep(tmp_path, samples=2)
    rows = expand(sweep)
    task, _ = prepare(sweep, rows)
    other = (("loops.cart.z0[0]", 0.25),)
    assert task(0, other) == ScenarioTask(task.base, task.source)(0, other)


def test_a_chunk_carries_its_prepared_rows_to_a_worker_that_does_not_share_the_parents_memory(tmp_path):
    """What a spawned or Dask worker gets: the task with the chunk's validated scenarios in it, run as
    they are (the task copy below validates nothing, and knows no prepared store of this process)."""
    sweep = cart_sweep(tmp_path)
    rows = expand(sweep)
    task, _ = prepare(sweep, rows)
    expected = [ScenarioTask(task.base, task.source)(r.index, r.params) for r in rows]
    shipped = pickle.loads(pickle.dumps(NoValidationTask.of(task).carrying([0, 2])))
    away = NoValidationTask(shipped.base, shipped.source, carried=shipped.carried)  # token "": no store here
    assert sorted(away.carried) == [0, 2]
    assert [away(i, rows[i].params) for i in (0, 2)] == [expected[0], expected[2]]
    with pytest.raises(AssertionError, match="row 1 validated again"):  # not carried: it would validate it
        away(1, rows[1].params)


def test_no_engine_validates_a_prepared_row_twice_and_every_engine_gives_the_same_results(tmp_path):
    """Serial (this process's store), forked processes (the store inherited), a Dask worker (the chunk
    carries its rows): a row validated again fails here, and the results are the unprepared task's."""
    sweep = cart_sweep(tmp_path, samples=4)
    rows = expand(sweep)
    task, _ = prepare(sweep, rows)
    expected = {r.index: ScenarioTask(task.base, task.source)(r.index, r.params) for r in rows}
    for engine_name, workers in (("serial", 1), ("processes", 2), ("dask", 1)):
        task, _ = prepare(sweep, rows)  # a fresh store: each engine's runs use theirs up
        got = dict(engine.execute([(r.index, r.params) for r in rows], NoValidationTask.of(task), engine_name, workers))
        assert sorted(got) == sorted(expected), engine_name
        for i, result in got.items():
            assert result["status"] == "completed", (engine_name, result["error"])
            assert (result["metrics"], result["error"]) == (expected[i]["metrics"], expected[i]["error"]), engine_name


FORK_CHECK = """
import threading
from ftstab_mj.plants.callback import control_callback
from ftstab_mj.studies.sweep.engine import start_method
print(start_method())
with control_callback(lambda m, d: None, owner="a run"):
    print(start_method())
t = threading.Thread(target=threading.Event().wait, args=(5,), daemon=True)
t.start()
print(start_method())
"""


def test_workers_are_forked_only_from_a_single_threaded_process_with_no_simulation_running():
    out = subprocess.run([sys.executable, "-c", FORK_CHECK], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert out.returncode == 0, out.stderr
    expected = ["fork", "spawn", "spawn"] if sys.platform.startswith("linux") else ["spawn"] * 3
    assert out.stdout.split() == expected


def test_a_dask_cluster_started_ahead_is_taken_over_by_the_sweep_or_closed_at_the_end_of_the_block(tmp_path):
    rows = expand(load_sweep(write_sweep(tmp_path, CHAIN_SWEEP)))
    serial = run_sweep("s", rows, ChainTask(), tmp_path / "serial", {}, progress=None)
    with engine.started_ahead("dask", 1) as ahead:
        started = ahead.connection
        out = run_sweep("s", rows, ChainTask(), tmp_path / "ahead", {}, engine="dask", workers=1, progress=None,
                        ahead=ahead)
        assert ahead.taken  # by the sweep, which has it closed beside its table
    client, cluster = started.result()
    assert client.status == "closed" and cluster.status.name == "closed"  # by the end of the block
    assert results(read_table(out.table)) == results(read_table(serial.table))
    with engine.started_ahead("dask", 1) as unused:  # e.g. a row fails validation: the sweep never runs
        pass
    client, cluster = unused.connection.result()
    assert not unused.taken and client.status == "closed" and cluster.status.name == "closed"
    assert not any(isinstance(v, (dict, engine.StartedAhead)) and v for k, v in vars(engine).items()
                   if not k.isupper() and not k.startswith("__"))  # no connection left in module state


def test_a_local_cluster_whose_worker_hangs_while_starting_is_an_engine_error_not_a_silent_wait(monkeypatch):
    """LocalCluster waits for its workers without end; a worker stuck in its start (here a preload that
    never returns) must fail the start within WORKER_START_TIMEOUT, with one line naming the engine."""
    import time

    from ftstab_mj.config.errors import EngineError

    monkeypatch.setattr(engine, "WORKER_START_TIMEOUT", 3.0)
    monkeypatch.setattr(engine, "LOCAL_PRELOAD", [*engine.LOCAL_PRELOAD, "tests.hung_worker"])
    t0 = time.monotonic()
    with pytest.raises(EngineError, match=r"--engine dask: expected a local cluster of 1 workers up within 3 s"):
        engine._dask_connect(1, None)
    assert time.monotonic() - t0 < 60  # the timeout, the nanny's kill and the cluster's close; not for ever



def test_a_local_cluster_start_failing_with_a_message_of_several_lines_is_one_line(monkeypatch):
    """distributed's start error carries the worker's own exception as its cause, whose message may span
    lines: multiprocessing's "An attempt has been made to start a new process before the current
    process has finished its bootstrapping phase" (a script without ``if __name__ == "__main__"``) is
    seven; the engine's error stays one line, with the whole message in it."""
    import distributed

    from ftstab_mj.config.errors import EngineError

    cause = RuntimeError("\n        An attempt has been made to start a new process before the\n"
                         "        current process has finished its bootstrapping phase.\n")

    def failing_start(*args, **kwargs):
        raise RuntimeError("Nanny failed to start.") from cause

    monkeypatch.setattr(distributed, "LocalCluster", failing_start)
    with pytest.raises(EngineError) as err:
        engine._dask_connect(1, None)
    assert "\n" not in str(err.value)
    assert str(err.value).endswith("(RuntimeError: An attempt has been made to start a new process before the "
                                   "current process has finished its bootstrapping phase.)")


FORKED_ROWS = """
import json, sys
from ftstab_mj.studies.sweep.engine import execute, start_method
from tests.sweep_chain import ChainTask, NoValidationTask
items = [(i, (("period", 0.01 * (i + 1)),)) for i in range(int(sys.argv[1]))]
assert start_method() == "fork"
out = {i: r["metrics"] for i, r in execute(items, ChainTask(), "processes", workers=2)}
print(json.dumps(out == {i: r["metrics"] for i, r in execute(items, ChainTask(), "serial")}))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="workers are forked on Linux only (spawned elsewhere)")
def test_forked_workers_after_the_first_row_run_in_the_parent_give_the_serial_results():
    for n in (1, 5, 16):  # one and five rows: all in forked workers; 16: the first here, 15 in forked workers
        out = subprocess.run([sys.executable, "-c", FORKED_ROWS, str(n)], capture_output=True, text=True, cwd=ROOT,
                             timeout=120)
        assert out.returncode == 0, out.stderr
        assert out.stdout.split() == ["true"]


WHERE_ROWS = """
import json, os, sys
from ftstab_mj.studies.sweep.engine import WARM_UP_ROWS_PER_WORKER, execute, start_method
from tests.sweep_chain import WhereTask
assert start_method() == "fork"
out = {}
for n in (2, 2 * WARM_UP_ROWS_PER_WORKER):
    items = [(i, (("period", 0.01),)) for i in range(n)]
    pids = {i: r["metrics"]["pid"] for i, r in execute(items, WhereTask(0.2), "processes", workers=2)}
    out[n] = sorted(i for i, pid in pids.items() if pid == os.getpid())
print(json.dumps(out))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="workers are forked on Linux only (spawned elsewhere)")
def test_the_parent_runs_a_warm_up_row_only_when_each_worker_has_many():
    """With fork, the parent runs the first row before forking (its lazy imports and caches are then inherited)
    only from WARM_UP_ROWS_PER_WORKER rows a worker: that row runs alone, so 2 long rows on 2 workers would
    otherwise run one after the other. 2 rows: none in the parent; 16: row 0 only."""
    out = subprocess.run([sys.executable, "-c", WHERE_ROWS], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout) == {"2": [], "16": [0]}


BATCH_PROCESS = """
import os, sys
sys.argv = ["ftstab", "sweep", sys.argv[1], "--out", sys.argv[2]]
from ftstab_mj.__main__ import main
code = main()
# pyarrow's allocator starts its own thread when the table is written, after the rows: not counted. That
# thread names itself once it runs (jemalloc calls pthread_setname_np inside it): until then it has this
# process's name, so under load it can be read as a second "python". Read again for up to 2 s until it
# has its name; OpenBLAS's threads, the ones this counts, would stay for the process's life.
import json, time
for _ in range(200):
    threads = [open(f"/proc/self/task/{t}/comm").read().strip() for t in os.listdir("/proc/self/task")]
    if len([t for t in threads if t != "jemalloc_bg_thd"]) == 1:
        break
    time.sleep(0.01)
print(json.dumps(threads))
print(code, os.environ["OPENBLAS_NUM_THREADS"], "glfw" in sys.modules, len([t for t in threads if t != "jemalloc_bg_thd"]))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="counts the process's threads in /proc")
def test_a_sweep_process_runs_with_one_blas_thread_and_without_opengl(tmp_path):
    """`ftstab sweep` sets OPENBLAS_NUM_THREADS=1 and MUJOCO_GL=disable before NumPy and MuJoCo load:
    the sweep runs, `import mujoco` loaded no GLFW, and the process has no thread but its own (OpenBLAS
    would have started one per core at `import numpy`)."""
    cart_sweep(tmp_path, samples=1)
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "MUJOCO_GL")}
    out = subprocess.run([sys.executable, "-c", BATCH_PROCESS, str(tmp_path / "cart.toml"), str(tmp_path / "o")],
                         capture_output=True, text=True, cwd=ROOT, env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split()[-4:] == ["0", "1", "False", "1"], f"threads: {out.stdout.splitlines()[-2:]}"


LOCAL_CLUSTER = """
import json, os
from ftstab_mj.studies.batch_env import batch_environment
batch_environment()  # as under `ftstab sweep`


def probe():  # in a worker: who its parent is, and what that parent runs
    parent = os.getppid()
    with open(f"/proc/{parent}/cmdline", "rb") as f:
        cmdline = f.read()
    with open(f"/proc/{parent}/maps") as f:
        mujoco = any("mujoco" in line for line in f)
    import dask

    return {"parent": parent, "forkserver": b"forkserver" in cmdline, "mujoco": mujoco,
            "parent_threads": len(os.listdir(f"/proc/{parent}/task")),
            "quiet": {key: dask.config.get(key) for key in QUIET}}


from ftstab_mj.studies.sweep.engine import QUIET

if __name__ == "__main__":
    from ftstab_mj.studies.sweep.engine import _dask_close, _dask_connect
    client, cluster = _dask_connect(2, None)
    try:
        print(json.dumps({"me": os.getpid(), "workers": list(client.run(probe).values())}))
    finally:
        _dask_close(client, cluster)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_a_local_dask_cluster_forks_its_workers_from_one_single_threaded_forkserver_that_loaded_mujoco(tmp_path):
    """The LocalCluster's workers are children of a forkserver (not of the command: not spawned), the
    same for both, with MuJoCo already loaded (they inherit the imports) and no thread but its main one
    (so forking it is safe), and with engine.QUIET's settings."""
    script = tmp_path / "cluster.py"
    script.write_text(LOCAL_CLUSTER)
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, cwd=ROOT, timeout=240)
    assert out.returncode == 0, out.stderr
    seen = json.loads(out.stdout.strip().splitlines()[-1])
    workers = seen["workers"]
    assert len(workers) == 2 and workers[0]["parent"] == workers[1]["parent"] != seen["me"]
    assert all(w["forkserver"] and w["mujoco"] and w["parent_threads"] == 1 for w in workers), workers
    # and they run with the local cluster's rarer periodic work (the nannies pass the settings on)
    import dask
    import distributed  # noqa: F401 - loads distributed's defaults into dask.config

    defaults = {key: dask.config.get(key) for key in engine.QUIET}  # this process: Dask's own
    assert engine.QUIET and all(engine.QUIET[k] != v for k, v in defaults.items())
    assert all(w["quiet"] == engine.QUIET for w in workers), workers


@pytest.mark.parametrize("rows, workers", [(1, 2), (5, 2), (199, 2), (1000, 2), (64, 1), (300, 7)])
def test_chunks_shrink_so_that_the_workers_run_out_of_rows_together(rows, workers):
    """Guided chunks: in order, every row once; no chunk holds more than MAX_CHUNK rows nor more than its
    share 1/(GUIDED x workers) of the rows still to hand out (or MIN_CHUNK), so when the last chunk is
    taken every other worker has at most that many rows of its own left; below MIN_CHUNK only where fewer
    than MIN_CHUNK rows per worker are left."""
    items = list(range(rows))
    cut = engine.chunks(items, workers)
    assert [i for c in cut for i in c] == items
    sizes = [len(c) for c in cut]
    left = rows
    for size in sizes:
        assert 1 <= size <= engine.MAX_CHUNK
        assert size <= max(engine.MIN_CHUNK, -(-left // (engine.GUIDED * workers)))
        assert size >= min(engine.MIN_CHUNK, -(-left // workers))
        left -= size
    assert sizes == sorted(sizes, reverse=True)
    assert sizes[-1] <= engine.MIN_CHUNK or len(sizes) == 1


def test_rows_of_equal_cost_end_after_their_share_of_one_worker_whatever_their_number():
    """The chunks taken in order by the first free worker (as the pool and the scheduler hand them out), rows
    of equal cost: the sweep ends after ceil(rows / workers) rows' time, the best any cut can do, for every
    number of rows up to 400 and 1-8 workers. The guided cut alone (MIN_CHUNK rows to the end) missed it on
    517 of these 1995 cases: 2 rows on 2 workers were one chunk, run one after the other (2 rows' time, not 1),
    6 rows took 4 rows' time: a sweep of a few long rows lost up to half of its workers."""
    import heapq

    for workers in (1, 2, 3, 4, 8):
        for rows in range(1, 400):
            free = [0] * workers  # when each worker is next free, in rows' time
            for chunk in engine.chunks(list(range(rows)), workers):
                heapq.heappush(free, heapq.heappop(free) + len(chunk))
            assert max(free) == -(-rows // workers), (rows, workers, [len(c) for c in engine.chunks(list(range(rows)), workers)])


MEANWHILE = """
import json, multiprocessing, sys
from ftstab_mj.studies.sweep.engine import execute
from tests.sweep_chain import ChainTask
items = [(i, (("period", 0.01 * (i + 1)),)) for i in range(6)]
seen = {}
for engine in ("serial", "processes"):
    calls, done = [], []
    for i, _ in execute(items, ChainTask(0.2), engine, workers=2 if engine != "serial" else 1,
                        meanwhile=lambda: calls.append((len(multiprocessing.active_children()), len(done)))):
        done.append(i)
    seen[engine] = [calls, sorted(done)]
print(json.dumps(seen))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="workers are forked on Linux only (spawned elsewhere)")
def test_the_callers_work_meanwhile_runs_once_after_the_workers_are_forked_and_before_their_results():
    """execute(meanwhile=...) runs the caller's work (a sweep: the table writer's imports) in this process once the
    processes engine's 2 workers exist (so they never inherit what it starts: pyarrow's allocator thread),
    before the workers' results are read (none is in by then); serial never calls it."""
    out = subprocess.run([sys.executable, "-c", MEANWHILE], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert out.returncode == 0, out.stderr
    seen = json.loads(out.stdout)
    assert seen["serial"] == [[], list(range(6))]
    assert seen["processes"] == [[[2, 0]], list(range(6))]  # 6 rows on 2 workers: no warm-up row in the parent


STOPPED_WORKER = """
import json, sys, time
from ftstab_mj.studies.sweep import engine
from tests.sweep_chain import ChainTask, StopOnceTask
engine.WORKER_STOP_TIMEOUT, engine.WATCH_INTERVAL = 1.0, 0.1
items = [(i, (("period", 0.01 * (1 + i % 5)),)) for i in range(40)]
t0 = time.monotonic()
got = dict(engine.execute(items, StopOnceTask(0.2, row=5, signal=sys.argv[1], marker=sys.argv[2]), "processes", 2))
wall = time.monotonic() - t0
serial = dict(engine.execute(items, ChainTask(0.2), "serial"))
print(json.dumps({"wall": wall, "rows": sorted(got), "lost": sorted(i for i, r in got.items() if r is None),
                  "same": all(r["metrics"] == serial[i]["metrics"] for i, r in got.items() if r is not None)}))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads the workers' states in /proc")
@pytest.mark.parametrize("sig", ["SIGSTOP", "SIGKILL"])
def test_a_process_worker_stopped_or_dead_mid_sweep_loses_no_row_its_rows_run_again_on_a_fresh_pool(tmp_path, sig):
    """A worker that stops (SIGSTOP) at row 5 is killed after WORKER_STOP_TIMEOUT (1 s here) with one warning
    line; one that dies breaks the pool as before. Either way the broken pool's unfinished rows (row 5's chunk
    and the healthy worker's) run again on a fresh pool: execute() ends, reports every row once, none lost,
    each with the serial result."""
    out = subprocess.run([sys.executable, "-c", STOPPED_WORKER, sig, str(tmp_path / "marker")], capture_output=True,
                         text=True, cwd=ROOT, timeout=120)
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout)
    assert (tmp_path / "marker").exists()  # row 5 did stop or kill its worker
    assert got["rows"] == list(range(40)) and got["lost"] == [] and got["same"]
    assert got["wall"] < 30  # the 1 s timeout, the pool's breakdown and shutdown, the fresh pool; not for ever
    warnings = [line for line in out.stderr.splitlines() if line.startswith("warning: sweep worker process")]
    assert len(warnings) == (sig == "SIGSTOP")
    if warnings:
        assert "stopped" in warnings[0] and "killed" in warnings[0] and "1 s" in warnings[0]


KILLER_ROW = """
import json, sys
from ftstab_mj.studies.sweep import engine
from tests.sweep_chain import ChainTask, KillAlwaysTask
items = [(i, (("period", 0.01 * (1 + i % 5)),)) for i in range(40)]
got = list(engine.execute(items, KillAlwaysTask(0.2, row=int(sys.argv[1]), marker=sys.argv[2]), "processes", 2))
serial = dict(engine.execute(items, ChainTask(0.2), "serial"))
print(json.dumps({"order": [i for i, _ in got], "lost": sorted(i for i, r in got if r is None),
                  "same": all(r["metrics"] == serial[i]["metrics"] for i, r in got if r is not None)}))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="workers are forked on Linux only")
def test_a_row_that_kills_its_worker_each_time_is_run_twice_then_lost_and_every_row_is_reported_once(tmp_path):
    """Row 7 kills its worker every time it runs: the first pool breaks, its unfinished rows run on a fresh pool,
    which breaks too; what that one left unfinished, row 7 with it, is lost (None: a resume retries it), not
    run a third time. Every row is reported exactly once, and every row reported finished has the serial
    result (the processes engine's first row runs in the parent, before the fork: row 0 is never the culprit)."""
    marker = tmp_path / "ran"
    out = subprocess.run([sys.executable, "-c", KILLER_ROW, "7", str(marker)], capture_output=True, text=True,
                         cwd=ROOT, timeout=120)
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout)
    assert sorted(got["order"]) == list(range(40)) and got["same"]
    assert 7 in got["lost"] and len(got["lost"]) < 40
    assert len(marker.read_text().split()) == 2  # in the first pool, then once in the fresh one


STOPPER_ROW = """
import sys
from ftstab_mj.studies.sweep import engine
from tests.sweep_chain import KillAlwaysTask
engine.WORKER_STOP_TIMEOUT, engine.WATCH_INTERVAL = 1.0, 0.1
items = [(i, (("period", 0.01 * (1 + i % 5)),)) for i in range(40)]
got = list(engine.execute(items, KillAlwaysTask(0.2, row=7, marker=sys.argv[1], signal="SIGSTOP"), "processes", 2))
print(sorted(i for i, r in got if r is None))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads the workers' states in /proc")
def test_a_row_that_stops_its_worker_each_time_is_warned_about_as_rerun_then_as_lost(tmp_path):
    """Row 7 stops (SIGSTOP) its worker every time it runs: killed after WORKER_STOP_TIMEOUT (1 s here) in the
    first pool, whose rows run again on a fresh pool, and again in that one, whose unfinished rows are lost.
    The two warnings say so in turn: the second does not promise a rerun that never comes."""
    marker = tmp_path / "ran"
    out = subprocess.run([sys.executable, "-c", STOPPER_ROW, str(marker)], capture_output=True, text=True,
                         cwd=ROOT, timeout=120)
    assert out.returncode == 0, out.stderr
    assert 7 in json.loads(out.stdout.strip().splitlines()[-1])
    assert len(marker.read_text().split()) == 2
    warnings = [line for line in out.stderr.splitlines() if line.startswith("warning: sweep worker process")]
    assert len(warnings) == 2, out.stderr
    assert warnings[0].endswith("run again on a fresh pool (once)") and warnings[1].endswith("are lost (a resume runs them)")


def test_a_local_dask_worker_stopped_mid_sweep_is_replaced_and_its_rows_run_again(tmp_path, monkeypatch):
    """A local cluster's worker stopped (SIGSTOP) at row 5 misses its heartbeats; with the cluster's short
    worker-ttl (WORKER_STOP_TIMEOUT; distributed's own floor: 10 heartbeats, 5 s) the scheduler has its nanny
    kill and restart it and runs its chunk again: the table is complete and the serial one, well before the 5 to
    10 minutes of distributed's default worker-ttl. The global Dask config is left as it was."""
    import time

    import dask
    import distributed  # noqa: F401 - registers its configuration defaults, read below (else a KeyError when run alone)

    monkeypatch.setattr(engine, "WORKER_STOP_TIMEOUT", 1.0)
    rows = [r for r in expand(load_sweep(write_sweep(tmp_path, CHAIN_SWEEP)))]
    serial = run_sweep("s", rows, ChainTask(0.2), tmp_path / "serial", {}, progress=None)
    ttl = dask.config.get("distributed.scheduler.worker-ttl")
    t0 = time.monotonic()
    out = run_sweep("s", rows, StopOnceTask(0.2, row=5, marker=str(tmp_path / "marker")), tmp_path / "dask", {},
                    engine="dask", workers=2, progress=None)
    assert time.monotonic() - t0 < 90
    assert (tmp_path / "marker").exists()  # the row did stop its worker
    assert out.lost == [] and out.done == len(rows)
    assert results(read_table(out.table)) == results(read_table(serial.table))
    assert dask.config.get("distributed.scheduler.worker-ttl") == ttl


def test_a_failure_to_close_the_dask_engine_is_one_line_on_stderr_and_the_rest_is_still_closed(capsys):
    """The client's or the local cluster's close may fail once the rows are in (also in started_ahead's thread,
    where an exception would go unseen): one warning line each, the other one still closed, nothing raised."""
    class Closes:
        def __init__(self, error=None):
            self.error, self.closed = error, False

        def close(self):
            self.closed = True
            if self.error:
                raise self.error

    client, cluster = Closes(RuntimeError("the scheduler\n  went away")), Closes()
    engine._dask_close(client, cluster)
    assert client.closed and cluster.closed
    assert capsys.readouterr().err == ("warning: --engine dask: closing the client failed (RuntimeError: the scheduler "
                                       "went away); the sweep's results are not affected\n")
    engine._dask_close(Closes(), Closes(OSError("port busy")))
    assert capsys.readouterr().err.splitlines() == ["warning: --engine dask: closing the local cluster failed (OSError: "
                                                    "port busy); the sweep's results are not affected"]


def test_the_readme_cluster_commands_set_exactly_the_local_clusters_quiet_configuration():
    """The sweeps page's (docs/sweeps.md) `export DASK_...` line for an external cluster's scheduler and workers, read by Dask as a
    `dask worker` reads it (a fresh process, distributed's defaults loaded), gives engine.QUIET's values for
    its keys, and names no key more: a renamed key or a misspelt variable would be silently ignored by Dask."""
    import re

    text = (ROOT / "docs" / "sweeps.md").read_text(encoding="utf-8")
    block = text[text.index("### A sweep on a Dask cluster of several machines"):]
    block = block[:block.index("dask scheduler")]
    names = dict(re.findall(r"(DASK_[A-Z_]+)=(\S+)", block))
    assert len(names) == len(engine.QUIET), names
    probe = ("import json, dask, distributed\n"
             f"print(json.dumps({{k: dask.config.get(k) for k in {sorted(engine.QUIET)!r}}}))")
    env = {k: v for k, v in os.environ.items() if not k.startswith("DASK_")} | names
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout.strip().splitlines()[-1]) == engine.QUIET


def test_the_stop_watch_counts_a_workers_stop_only_while_the_command_itself_was_watching(monkeypatch):
    """_StopWatch kills a worker seen stopped for WORKER_STOP_TIMEOUT s of the command's own watching (checks every
    WATCH_INTERVAL s): a worker stopped all along is killed at 10 s, and not earlier; but after a gap of 15 s
    between two checks (the command itself was stopped, e.g. Ctrl-Z of the whole group, or starved) it does not
    count that gap: a worker the command still reads as stopped just after its own resumption (the group's SIGCONT
    not yet delivered to it) is killed only after 10 s more of watching, not at once."""
    import multiprocessing

    class Proc:
        pid = 4242

    kills, clock = [], [0.0]
    monkeypatch.setattr(multiprocessing, "active_children", lambda: [Proc()])
    monkeypatch.setattr(engine, "_stopped", lambda pid: True)
    monkeypatch.setattr(os, "kill", lambda pid, sig: kills.append((pid, clock[0])))

    def watch_until(watch, times):
        for t in times:
            clock[0] = t
            watch.check(engine.WORKER_STOP_TIMEOUT)

    step = engine.WATCH_INTERVAL
    steady = engine._StopWatch(set(), clock=lambda: clock[0])
    watch_until(steady, [k * step for k in range(round(engine.WORKER_STOP_TIMEOUT / step) + 3)])
    assert kills == [(4242, engine.WORKER_STOP_TIMEOUT)]

    kills.clear()
    gap = engine._StopWatch(set(), clock=lambda: clock[0])
    watch_until(gap, [0.0, step, step + 15.0])  # the command stopped 15 s between its second and third look
    assert kills == []
    resumed = step + 15.0
    watch_until(gap, [resumed + k * step for k in range(1, round(engine.WORKER_STOP_TIMEOUT / step) + 3)])
    assert kills == [(4242, resumed + engine.WORKER_STOP_TIMEOUT)]

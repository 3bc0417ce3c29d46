"""Several simulations in one process. MuJoCo's control callback is one global slot: a Python
callback serves one run, while the native kernel's C callback finds each call's run from the MjData
it is called with and serves any number of runs in any threads.

Pinned here: a second Python-path run's callback cannot be installed while one is (a clear error,
never a wrong trajectory), in the same thread or another; native runs interleaved in one thread or
stepping at once in two threads (simulations and ``ftstab_mj.run``) give their single-run results;
the serial and processes engines run one simulation at a time per process, while the threads of the batch
engine and of a Dask worker run rows at once (native rows step together, a Python-path row waits for the slot),
so a real ``dask worker --nthreads 2`` runs two rows at once and gives the serial table.
"""

import ctypes
import json
import os
import subprocess
import sys
import threading
import time

import mujoco
import numpy as np
import pytest

from conftest import ROOT, run_cli
from test_sweep_cli import results, small_sweep
from ftstab_mj.simulation import native
from ftstab_mj.plants.callback import CallbackBusy, control_callback
from ftstab_mj.control import HongController, RobustLaw
from ftstab_mj.plants.disturbances import Signal
from ftstab_mj.plants import make_plant
from ftstab_mj.scenario import LoopSpec
from ftstab_mj.simulation.run_loop import Simulation
from ftstab_mj.studies.sweep.engine import beside, execute, guarded
from ftstab_mj.studies.sweep.row import ScenarioTask
from ftstab_mj.studies.sweep.table import read_table
from ftstab_mj.config.tomlfile import read_toml

LAW = RobustLaw(HongController(2, -0.2, (1.0, 2.0)), phibar=0.5, gamma_m=0.8)


def cart_sim(native_path="auto", amplitude=0.4):
    loops = [LoopSpec("cart", controller=LAW, disturbance=Signal("sine", amplitude=amplitude, freq=1.0), z0=(1.0, 0.0))]
    return Simulation(make_plant("cart"), loops, period=0.01, physics_step=0.001, native=native_path)


def in_thread(fn):
    """Run fn() in another thread; return what it raised (None if nothing)."""
    out = []

    def target():
        try:
            fn()
        except BaseException as exc:  # noqa: BLE001 - handed back to the test
            out.append(exc)

    t = threading.Thread(target=target, name="second")
    t.start()
    t.join(60)
    return out[0] if out else None


@pytest.mark.parametrize("native_path", [False])
def test_a_second_run_s_callback_is_refused_in_this_thread_and_the_first_run_goes_on(native_path):
    first, second = cart_sim(native_path), cart_sim(native_path, amplitude=0.8)
    alone = cart_sim(native_path)
    with alone.installed():
        reference = alone.advance(20).loops["cart"]["z"]
    with first.installed():
        a = first.advance(10).loops["cart"]["z"]
        with pytest.raises(CallbackBusy, match=r"cannot install a second simulation's control callback: MuJoCo's "
                                               r"control callback is one slot per process and another simulation holds it "
                                               r"\(Simulation 0x[0-9a-f]+, thread 'MainThread'\); .*start it once the "
                                               r"other has finished, or in another process .*share the slot$"):
            with second.installed():
                pass
        # stepping another simulation without installing its callback is refused too (the native
        # runs share one C function, so the callback's identity alone would not tell them apart)
        with pytest.raises(RuntimeError, match="needs its control callback installed"):
            second.advance(1)
        b = first.advance(10).loops["cart"]["z"]
    np.testing.assert_array_equal(np.concatenate([a, b]), reference)  # the refusals changed nothing
    with second.installed():  # free again once the first run's block is left
        second.advance(1)


def test_another_thread_can_neither_install_a_callback_nor_clear_the_slot_while_a_run_steps():
    sim, other = cart_sim(False), cart_sim(False)
    make_plant("cart").compile(0.001)  # a spec compiled before the run starts (below: reused, no slot needed)
    with sim.installed():
        busy = in_thread(lambda: other.installed().__enter__())
        assert isinstance(busy, CallbackBusy) and "thread 'MainThread'" in str(busy)
        # compiling a model not compiled before clears the slot (its forward pass would call the callback):
        # from another thread it would take the callback from under the run. A mass no other test uses.
        busy = in_thread(lambda: make_plant("cart", {"mass": 1.2345678}).compile(0.001))
        assert isinstance(busy, CallbackBusy) and "clear the control callback (to compile a model)" in str(busy)
        assert mujoco.get_mjcb_control() is sim.callback
        # the model of a spec compiled before is reused without a forward pass: no slot needed, none taken
        assert in_thread(lambda: make_plant("cart").compile(0.001)) is None
        assert mujoco.get_mjcb_control() is sim.callback
        with control_callback(None):  # the run's own thread may compile between two batches
            make_plant("cart").compile(0.001)
        assert mujoco.get_mjcb_control() is sim.callback
        sim.advance(2)
    assert in_thread(lambda: make_plant("cart").compile(0.001)) is None


needs_kernel = pytest.mark.skipif(not native.available(), reason="the C kernel is not built")


@needs_kernel
def test_the_native_kernel_serves_each_call_the_run_of_the_mjdata_it_is_called_with():
    """A run registered for another MjData (in another thread, never finished) does not take this
    simulation's calls, and an activation left behind (as if a Ctrl-C came before the first step)
    changes nothing."""
    from ftstab_mj.simulation.native.run import FtRun, _lib, data_layout

    lib = _lib()
    other = cart_sim(True)
    elsewhere = FtRun()  # zeroed: a callback serving it would read through NULL pointers
    layout = data_layout(other.data)
    assert in_thread(lambda: lib.ft_run_activate(ctypes.byref(elsewhere), other.data._address,
                                                 ctypes.byref(layout))) is None
    alone, sim = cart_sim(True), cart_sim(True)
    with alone.installed():
        reference = alone.advance(20).loops["cart"]["z"]
    with sim.installed():
        lib.ft_run_activate(ctypes.byref(sim._native.run), sim.data._address, ctypes.byref(sim._native.layout))
        np.testing.assert_array_equal(sim.advance(20).loops["cart"]["z"], reference)
    lib.ft_run_finish(ctypes.byref(elsewhere), other.data._address)


@needs_kernel
def test_native_runs_interleaved_in_one_thread_share_the_callback_and_keep_their_results():
    a_alone, b_alone = cart_sim(True), cart_sim(True, amplitude=0.8)
    refs = []
    for sim in (a_alone, b_alone):
        with sim.installed():
            refs.append(sim.advance(30).loops["cart"]["z"])
    a, b = cart_sim(True), cart_sim(True, amplitude=0.8)
    with a.installed(), b.installed():
        za = [a.advance(10).loops["cart"]["z"]]
        zb = [b.advance(15).loops["cart"]["z"]]
        za.append(a.advance(20).loops["cart"]["z"])
        zb.append(b.advance(15).loops["cart"]["z"])
    np.testing.assert_array_equal(np.concatenate(za), refs[0])
    np.testing.assert_array_equal(np.concatenate(zb), refs[1])
    assert mujoco.get_mjcb_control() is None  # the last run out put back what was there


@needs_kernel
def test_native_runs_stepping_at_once_in_two_threads_give_their_single_run_results():
    """Two threads step their simulations in many small batches at once, so their mj_step calls
    overlap (the GIL is released inside mj_step): each records its single-run trajectory."""
    amps = (0.4, 0.8)
    refs = []
    for amp in amps:
        sim = cart_sim(True, amplitude=amp)
        with sim.installed():
            refs.append(np.concatenate([sim.advance(1).loops["cart"]["z"] for _ in range(400)]))
    got = [None, None]
    start = threading.Barrier(2)

    def run(i):
        sim = cart_sim(True, amplitude=amps[i])
        start.wait()
        with sim.installed():
            got[i] = np.concatenate([sim.advance(1).loops["cart"]["z"] for _ in range(400)])

    threads = [threading.Thread(target=run, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    for i in range(2):
        np.testing.assert_array_equal(got[i], refs[i])


@needs_kernel
def test_the_api_runs_two_scenarios_in_two_threads_with_their_single_run_results():
    import ftstab_mj

    overrides = [{"sim.duration": 0.5, "loops.cart.disturbance.amplitude": a} for a in (0.2, 0.9)]
    path = ROOT / "scenarios" / "cart_r2_robust.toml"
    alone = [ftstab_mj.run(path, overrides=o).metrics for o in overrides]
    got = [None, None]

    def run(i):
        got[i] = ftstab_mj.run(path, overrides=overrides[i]).metrics

    threads = [threading.Thread(target=run, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert got == alone and alone[0] != alone[1]


def test_a_python_path_run_in_a_second_thread_is_refused_in_one_line_while_a_native_run_steps():
    native_sim, python_sim = cart_sim("auto"), cart_sim(False)
    with native_sim.installed():
        busy = in_thread(lambda: python_sim.installed().__enter__())
    assert isinstance(busy, CallbackBusy) and "\n" not in str(busy)
    assert mujoco.get_mjcb_control() is None


@pytest.mark.parametrize("run_row", [guarded, beside], ids=["guarded", "beside"])
def test_sweep_rows_run_in_threads_of_one_process_give_the_serial_results(tmp_path, run_row):
    """Several threads call the engine's guarded(task) (each waits for the process's one run) or beside(task)
    (what a multi-threaded Dask worker does: native rows step at once, a Python-path row (RK4) waits for the
    callback slot) at once; every row equals its serial result."""
    base = read_toml(ROOT / "scenarios" / "cart_r2_robust.toml", "scenario")
    base["sim"]["duration"] = 0.3
    task = ScenarioTask(base, "test")
    params = [(("loops.cart.disturbance.amplitude", a), ("sim.integrator", integ))
              for a, integ in ((0.2, "euler"), (0.4, "rk4"), (0.8, "euler"), (1.6, "euler"))]
    serial = [guarded(task, i, p) for i, p in enumerate(params)]
    threaded = [None] * len(params)

    def row(i):
        threaded[i] = run_row(task, i, params[i])

    threads = [threading.Thread(target=row, args=(i,)) for i in range(len(params))]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert [r["status"] for r in threaded] == ["completed"] * 4
    assert [r["metrics"] for r in threaded] == [r["metrics"] for r in serial]


@pytest.fixture(scope="module")
def dask_cluster(tmp_path_factory):
    """A real `dask scheduler` and `dask worker --nworkers 2 --nthreads 2`: 2 worker processes (as the
    README says to start them) of 2 threads each (the default of `dask worker` is several threads),
    as a user starts them; yields the scheduler address."""
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    dask = os.path.join(os.path.dirname(sys.executable), "dask")
    tmp_path = tmp_path_factory.mktemp("dask")
    info = tmp_path / "scheduler.json"
    quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL, "env": env, "cwd": tmp_path}
    procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                               "--scheduler-file", str(info)], **quiet)]
    try:
        deadline = time.monotonic() + 60
        address = None
        while address is None and time.monotonic() < deadline:
            try:  # the scheduler writes the file in more than one go: wait until it parses
                address = json.loads(info.read_text())["address"]
            except (FileNotFoundError, json.JSONDecodeError, KeyError):
                time.sleep(0.05)
        assert address, "the dask scheduler wrote no scheduler file within 60 s"
        procs.append(subprocess.Popen([dask, "worker", address, "--nworkers", "2", "--nthreads", "2", "--no-dashboard"],
                                      **quiet))
        from distributed import Client

        with Client(address, timeout="30s") as client:
            client.wait_for_workers(2, timeout=60)
            assert [w["nthreads"] for w in client.scheduler_info()["workers"].values()] == [2, 2]
        yield address
    finally:  # the worker first (it says goodbye to the scheduler), each killed if it lingers
        for p in reversed(procs):
            p.terminate()
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(timeout=10)


def test_a_sweep_on_two_dask_worker_processes_of_two_threads_gives_the_serial_table(tmp_path, dask_cluster):
    sweep = small_sweep(tmp_path)
    tables = {}
    for name, args in (("serial", ()), ("dask", ("--scheduler", dask_cluster))):
        res = run_cli("sweep", sweep, "--out", tmp_path / name, *args)
        assert res.returncode == 0, res.stderr
        assert "12/12 runs in the table (12 completed)" in res.stdout, res.stdout
        tables[name] = results(read_table(tmp_path / name / "small.parquet"))
    assert tables["dask"] == tables["serial"]


def test_a_dask_worker_s_two_threads_run_rows_at_once_and_give_the_serial_results(dask_cluster):
    """On `dask worker --nthreads 2`, the worker's two threads each run a chunk at once (no per-process lock):
    two native rows of one worker process overlap in time; Python-path rows (RK4) wait for the callback
    slot beside them; every row's metrics are the serial ones."""
    from tests.sweep_chain import WhereScenarioTask

    base = read_toml(ROOT / "scenarios" / "cart_r2_robust.toml", "scenario")
    base["sim"]["duration"] = 2.0  # ~10 ms of CPU a row: the first chunks (native) run together
    task = WhereScenarioTask(base, "test")
    grid = ([("euler", a) for a in (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8)]
            + [("rk4", a) for a in (0.1, 0.4, 0.7, 0.8)])
    items = [(i, (("sim.integrator", integ), ("loops.cart.disturbance.amplitude", a)))
             for i, (integ, a) in enumerate(grid)]
    serial = dict(execute(items, task, "serial"))
    got = dict(execute(items, task, "dask", scheduler=dask_cluster))
    assert all(r["status"] == "completed" for r in got.values()), [r["error"] for r in got.values()]
    pid = {i: r["metrics"].pop("pid") for i, r in got.items()}
    assert {i: r["metrics"] for i, r in got.items()} == {i: {k: v for k, v in r["metrics"].items() if k != "pid"}
                                                        for i, r in serial.items()}
    native = [i for i, (integ, _) in enumerate(grid) if integ == "euler"]
    span = {i: (got[i]["started_at"], got[i]["started_at"] + got[i]["elapsed_s"]) for i in native}
    overlap = [(a, b) for a in native for b in native if a < b and pid[a] == pid[b]
               and span[a][0] < span[b][1] and span[b][0] < span[a][1]]
    assert overlap, (pid, span)


def test_building_a_plant_in_a_second_thread_never_calls_the_python_run_s_callback(monkeypatch):
    """A flexible joint's construction runs forward passes on its own MjData once compiled (its constants,
    checked). A thread of an engine (waiting for the slot) building one while this thread's Python-path run
    installs its callback, between that compile and those passes, must wait for the slot, not have the passes
    call this run's callback: a sample of a foreign MjData (it made --engine batch rows differ from serial
    now and then under load)."""
    from ftstab_mj.plants.callback import waiting_for_slot
    from ftstab_mj.plants.flexible_joint import MODEL, FlexibleJointPlant

    compiled, installed, calls, built = threading.Event(), threading.Event(), [], []
    plain = FlexibleJointPlant.compile

    def compile_then_let_the_run_in(self, *args, **kwargs):
        out = plain(self, *args, **kwargs)
        if threading.current_thread().name == "builder":
            compiled.set()
            installed.wait(30)
        return out

    monkeypatch.setattr(FlexibleJointPlant, "compile", compile_then_let_the_run_in)

    def build():
        with waiting_for_slot():
            built.append(make_plant(MODEL))

    t = threading.Thread(target=build, name="builder")
    t.start()
    assert compiled.wait(30)
    with control_callback(lambda m, d: calls.append(d), owner=object()):
        installed.set()
        t.join(0.5)
        assert t.is_alive() and not built and calls == []  # waiting for the slot
    t.join(60)
    assert built and calls == []

"""Where the runs of a sweep execute: in this process, on local processes, or on a Dask cluster.

Every engine calls the same picklable ``task(index, params) -> {"status", "error", "metrics"}``
(index: the row; params: ((key path, value), ...)) through
:func:`guarded` and yields ``(index, result)`` as runs finish, in any order (the caller orders the
table). A run's result depends on its parameters only, so the table does not depend on the engine.

- ``serial``: one run after the other in this process.
- ``batch``: the rows on ``workers`` threads of this process (:func:`_batch`): rows on the native kernel
  step at once, rows on the Python control path one at a time; no process to start, nothing to pickle.
- ``processes``: a ``concurrent.futures`` pool of ``workers`` processes, forked from this one where
  that is safe (:func:`start_method`: Linux, no other thread, no simulation running), else spawned.
  A forked worker starts in milliseconds with everything this process imported and the scenarios it
  validated (runner.py); a spawned one pays ~0.3 s of CPU to import NumPy, MuJoCo and ftstab_mj.
- ``dask``: a ``dask.distributed`` cluster, a ``LocalCluster`` of ``workers`` single-threaded
  processes by default, or the scheduler at ``scheduler`` (its workers must have ftstab_mj
  installed). A worker's threads (``dask worker --nthreads T``) each run a chunk at once, as the
  batch engine's threads do (:func:`run_chunk_beside`). The local cluster stays N processes of one
  thread: on 2 cores, 96 rows of 2 s on the cart took 0.68 s of wall on 2 workers of 1 thread against
  1.00 s on 1 worker of 2 threads (medians of 3, load 0.7: a row's set-up is Python, which holds the
  GIL, so threads of one process overlap only the stepping). A local cluster's workers are forked
  from a forkserver (:func:`local_worker_method`) that imported distributed and what a row runs
  once, so a worker starts without paying those imports again.

One simulation at a time per process on the serial and processes engines: :func:`guarded` holds the
process's :data:`ftstab_mj.plants.callback.ONE_RUN` lock for the whole run. The threads of the batch engine
and of a Dask worker run rows :func:`beside` each other instead: no lock, each row waits for MuJoCo's
callback slot (native-kernel rows share it and step at once, a Python-path row has it alone), so a
``dask worker`` with several threads (its default) uses them all and the table is still the serial one.
A process worker runs its chunk on its one thread: on 2 cores, 2 processes already fill both cores, and
threads inside one process gained nothing on the same rows (``--engine batch --workers 2``: 1.0x serial).

Rows travel in chunks (:func:`chunks`): one engine task runs several rows one after the other, so the
engine's cost per task (pickling, scheduling, a round trip: ~1 ms on processes, several ms on Dask)
is paid once per chunk, not once per row; results still come back per row. Chunks shrink as the
sweep goes (large first, MIN_CHUNK rows last, then one row per worker where fewer rows are left than
MIN_CHUNK per worker), so the workers run out of rows together: with equal chunks, a worker that
finished early waited for a whole chunk of the other's (measured up to 0.3 s of one worker idle at the
end of 200 rows of 1 s on 2 processes, load 3); and a few long rows are never two to a chunk while a
worker has none (2 rows on 2 workers ran one after the other). When a process worker
dies (or is killed, stopped too long) its pool breaks and drops every unfinished chunk, the other
workers' too: those run once more on a fresh pool; what a second broken pool leaves is lost (a
resume retries it). On Dask the scheduler runs a dead worker's chunk again elsewhere. A worker that
does not share this process's memory (spawned, Dask) gets the task as ``task.carrying(indices)``
where the task has that method: what this process prepared for the chunk's rows travels with it
(runner.ScenarioTask: the validated scenarios, so no row is validated twice).

A result of ``None`` means the run was lost by the engine (its worker process died): it is not a
result of the run and the caller must not record it as one.

A process worker (:func:`worker_start`) does not keep the signal handlers it inherits from the command
(which turn SIGTERM into an "interrupted" run): SIGTERM kills it as it would any process, so the pool sees
the death at once (a SIGTERMed worker otherwise recorded its row "interrupted", and one blocked writing a
large result could not be ended by the pool, which then waited for ever); SIGINT and SIGHUP, which a
terminal sends to the whole process group, are left to the command, which kills its workers as it stops.
A worker dies with the command (Linux: a parent-death signal; elsewhere a thread watching its parent),
so killing the command (SIGKILL) leaves no worker behind.
"""

from __future__ import annotations

import time
import uuid
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager

from ftstab_mj.plants.callback import ONE_RUN
from ftstab_mj.config.errors import EngineError, UsageError
from ftstab_mj.simulation.records import FAILED


ENGINES = ("serial", "batch", "processes", "dask")
GUIDED = 2  # a chunk holds about 1 / (GUIDED x workers) of the rows not yet handed out (guided scheduling)
MIN_CHUNK = 2  # rows per task at least, unless a worker would be left without a task (chunks())
MAX_CHUNK = 32  # rows per task at most: a lost chunk (dead worker) costs a resume at most this many rows
WARM_UP_ROWS_PER_WORKER = 8  # rows a worker from which the parent runs the first row before the fork (_processes)
# a local cluster's worker not up within this (s) fails the start, which LocalCluster would otherwise wait
# for without end (a worker process stopped while starting kept `ftstab sweep` waiting, silent, 605 s)
WORKER_START_TIMEOUT = 60.0
# a worker stopped (SIGSTOP, a debugger) mid-sweep for this long (s) is killed and its rows run again on a fresh
# pool, once (processes),
# or declared dead by the scheduler and its rows run again elsewhere (a local cluster's worker-ttl); a worker
# running a row stays responsive (the rows run in its own thread on Dask; processes are watched from here)
WORKER_STOP_TIMEOUT = 10.0
WATCH_INTERVAL = 1.0  # s between two looks at the process workers' states
LOCAL_PRELOAD = ["ftstab_mj.studies.sweep.row"]  # what a local cluster's workers import as they start
# a cluster's periodic work, made rarer (a local cluster's; the README gives them for an external one): no
# statistical profiler (it samples the running row's stack every 10 ms, for the dashboard), the event-loop
# health check (20 ms by default: only warns when a loop blocks for seconds), the CPU, memory and I/O samples
# (500 ms: for the dashboard and the heartbeats' metrics) and the memory monitor (100 ms: a worker above its
# memory limit, "auto" = the machine's memory / workers, is stopped up to 1 s later). With Dask's defaults an
# idle scheduler and 2 workers with their nannies take 13 % of a core, 1.4 % with these (10 s idle, load 3)
QUIET = {"distributed.worker.profile.enabled": False, "distributed.admin.tick.interval": "1s",
         "distributed.admin.system-monitor.interval": "5s", "distributed.worker.memory.monitor-interval": "1s"}


def guarded(task: Callable[[int, tuple], dict], index: int, params: tuple, one_run=ONE_RUN) -> dict:
    """``task(index, params)`` with any exception turned into a failed result; adds ``elapsed_s`` (wall s)
    and ``started_at`` (when the run started, ``time.time()`` of the process that ran it: Unix s).

    A failed result is ``{"status": "failed", "error": "<ExceptionType>: <message>", "metrics": {}}``.
    KeyboardInterrupt is not caught: an interrupted run is not a result. The run holds
    :data:`~ftstab_mj.plants.callback.ONE_RUN` (one simulation at a time per process); ``elapsed_s`` does not
    count the wait for it. ``one_run``: the lock held for the run (the batch engine's threads hold none:
    they wait for MuJoCo's callback slot themselves, :func:`_batch`).
    """
    with one_run:
        started_at = time.time()
        t0 = time.perf_counter()
        try:
            out = dict(task(index, params))
        except Exception as exc:  # noqa: BLE001 - any failure of one run is recorded, the sweep goes on
            out = {"status": FAILED, "error": f"{type(exc).__name__}: {exc}", "metrics": {}}
        out["elapsed_s"] = time.perf_counter() - t0
    out["started_at"] = started_at
    return out


def run_chunk(task: Callable[[int, tuple], dict], chunk: list[tuple[int, tuple]]) -> list[tuple[int, dict]]:
    """[(index, guarded(task, index, params))] for every row of ``chunk``, one after the other."""
    return [(i, guarded(task, i, params)) for i, params in chunk]


def beside(task: Callable[[int, tuple], dict], index: int, params: tuple) -> dict:
    """:func:`guarded` for a row that runs beside other rows in threads of this process (the batch engine's
    threads, a Dask worker's): it holds no :data:`ONE_RUN` and waits for MuJoCo's callback slot instead
    (:func:`~ftstab_mj.plants.callback.waiting_for_slot`), so native-kernel rows step at once and a
    Python-path row steps alone. Same result as :func:`guarded`."""
    from contextlib import nullcontext

    from ftstab_mj.plants.callback import waiting_for_slot

    with waiting_for_slot():
        return guarded(task, index, params, one_run=nullcontext())


def run_chunk_beside(task: Callable[[int, tuple], dict], chunk: list[tuple[int, tuple]]) -> list[tuple[int, dict]]:
    """:func:`run_chunk` with each row run :func:`beside` the rows of the process's other threads: a Dask task,
    so that a worker's threads (``dask worker --nthreads T``) each run a chunk at once."""
    return [(i, beside(task, i, params)) for i, params in chunk]


def carrying(task, chunk: list[tuple[int, tuple]]):
    """``task.carrying([row indices of chunk])`` where the task has that method, else ``task``."""
    carry = getattr(task, "carrying", None)
    return task if carry is None else carry([i for i, _ in chunk])


def chunks(items: list, workers: int) -> list[list]:
    """``items`` cut into consecutive chunks of decreasing size, in the order the workers should take them:
    each about 1 / (GUIDED x workers) of the rows left, within [MIN_CHUNK, MAX_CHUNK], and never more than
    1 / workers of them (so that, rows of equal cost taken by the first free worker, the sweep ends after
    ceil(rows / workers) rows' time: no worker idles while another has a chunk of two rows to go).
    199 rows on 2 workers: 32, 32, 32, 26, 20, 15, 11, 8, 6, 5, 3, 3, 2, 2, 1, 1 (16 tasks); 2 rows: 1, 1."""
    out, k, w = [], 0, max(1, workers)
    while k < len(items):
        left = len(items) - k
        size = min(max(MIN_CHUNK, min(MAX_CHUNK, -(-left // (GUIDED * w)))), -(-left // w))
        out.append(items[k:k + size])
        k += size
    return out


def choose_engine(engine: str | None, workers: int, scheduler: str | None) -> str:
    """The engine of ``ftstab sweep``/``montecarlo --on plant`` options --engine, --workers N and --scheduler:
    dask with a scheduler; else local processes when N > 1 (a local Dask cluster costs about twice their
    CPU on 200 short rows), serial for N = 1. UsageError (one line naming the option) on a contradiction."""
    engine = engine or ("dask" if scheduler else "processes" if workers > 1 else "serial")
    if engine == "serial" and (workers > 1 or scheduler):
        raise UsageError("--engine serial: expected no --workers/--scheduler (one process runs everything)")
    if scheduler and engine != "dask":
        raise UsageError(f"--scheduler: expected --engine dask, found --engine {engine}")
    return engine


def execute(items: Iterable[tuple[int, tuple]], task: Callable[[int, tuple], dict], engine: str = "serial",
            workers: int = 1, scheduler: str | None = None, meanwhile: Callable[[], None] | None = None,
            ahead: StartedAhead | None = None) -> Iterator[tuple[int, dict | None]]:
    """Run ``task`` on every (index, params); yield (index, result or None if lost) as runs finish.

    ``meanwhile``: the caller's own work that can overlap the rows (``ftstab sweep``: the table writer's
    imports); the processes and Dask engines call it once in this process, after their workers are
    running (forked workers: after the fork, so they do not inherit what it starts), the serial one never.
    ``ahead``: what :func:`started_ahead` yielded; the Dask engine uses the connection it made.
    """
    items = list(items)
    if not items:  # nothing to run (e.g. resuming a finished sweep): start no engine
        return
    if engine == "serial":  # row by row: nothing to amortize, and a Ctrl-C loses no finished row
        for i, params in items:
            yield i, guarded(task, i, params)
    elif engine == "batch":
        yield from _batch(items, task, workers)
    elif engine == "processes":
        yield from _processes(items, task, workers, meanwhile)
    elif engine == "dask":
        yield from _dask(items, task, workers, scheduler, meanwhile, ahead)
    else:
        raise EngineError(f"engine: expected one of {', '.join(ENGINES)}, found {engine!r}")


def _batch(items, task, workers: int) -> Iterator[tuple[int, dict | None]]:
    """The rows on ``workers`` threads of this process, each thread taking the next row as it is free.

    A row whose control runs on the native kernel shares MuJoCo's control callback with the rows of the
    other threads (the kernel finds each call's run from its MjData) and steps while they step (MuJoCo
    releases the GIL in mj_step); a row on the Python control path (a law or integrator without a C
    twin) waits for the callback slot to itself (:func:`~ftstab_mj.plants.callback.waiting_for_slot`).
    Each run is the serial engine's run, so the table is the serial table at any thread count. A
    Ctrl-C stops the sweep once the rows running have ended; the rows not started are left for a resume.
    """
    import threading
    from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait

    def row(i, params):
        return i, beside(task, i, params)

    pending, queue = set(), iter(items)
    stop = threading.Event()
    with ThreadPoolExecutor(max(1, workers), thread_name_prefix="ftstab-batch") as pool:
        try:
            while True:
                while len(pending) < 2 * max(1, workers) and not stop.is_set():  # a few rows ahead, not the sweep
                    nxt = next(queue, None)
                    if nxt is None:
                        stop.set()
                        break
                    pending.add(pool.submit(row, *nxt))
                if not pending:
                    return
                done, pending = wait(pending, return_when=FIRST_COMPLETED)
                for f in done:
                    yield f.result()
        finally:
            for f in pending:
                f.cancel()


def start_method() -> str:
    """"fork" when forking this process is safe, else "spawn".

    Safe: on Linux (macOS's system libraries do not survive a fork), with no thread but this one
    (a child inherits the locks other threads hold, never the threads that would release them) and
    no simulation running (a child would inherit its MuJoCo callback). A sweep forks after its
    rows are validated and before any of them runs, so all of this holds for ``ftstab sweep``.
    """
    import multiprocessing
    import sys
    import threading

    from ftstab_mj.plants.callback import slot_owner

    if (sys.platform.startswith("linux") and "fork" in multiprocessing.get_all_start_methods()
            and threading.active_count() == 1 and slot_owner() is None):
        return "fork"
    return "spawn"


WORKER_SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")  # the signals the command handles (simulation/interrupts.py)
PARENT_WATCH_INTERVAL = 1.0  # s between two looks at the parent where no parent-death signal exists (not Linux)


def worker_start(parent: int) -> None:
    """Initializer of every process-pool worker: SIGTERM at its default (death), SIGINT and SIGHUP ignored
    (the command, which gets them too from the terminal, stops its workers itself), then unblocked (the pool
    forks with them blocked: :func:`_signals_blocked`); and the worker dies with ``parent`` (the command's pid)."""
    import os
    import signal

    for name, action in (("SIGTERM", signal.SIG_DFL), ("SIGINT", signal.SIG_IGN), ("SIGHUP", signal.SIG_IGN)):
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), action)
    die_with_parent(parent)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, _signal_numbers())
    if os.getppid() != parent:  # the command died before we could watch it
        os._exit(1)


def die_with_parent(parent: int) -> None:
    """Have this process killed (SIGKILL) when ``parent`` dies: prctl(PR_SET_PDEATHSIG) on Linux, else a daemon
    thread that looks at the parent every PARENT_WATCH_INTERVAL s and ends the process once it changed."""
    import os
    import sys

    if sys.platform.startswith("linux"):
        import ctypes
        import signal

        try:
            if ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL), 0, 0, 0) == 0:  # PR_SET_PDEATHSIG
                return
        except (OSError, AttributeError):
            pass
    import threading

    def watch():
        while os.getppid() == parent:
            time.sleep(PARENT_WATCH_INTERVAL)
        os._exit(1)

    threading.Thread(target=watch, name="ftstab-parent-watch", daemon=True).start()


def _signal_numbers() -> set:
    import signal

    return {getattr(signal, name) for name in WORKER_SIGNALS if hasattr(signal, name)}


@contextmanager
def _signals_blocked():
    """The command's signals blocked in this thread for the block (the pool's forks, whose children inherit the
    mask: no signal reaches a worker before :func:`worker_start` reset its handlers); delivered after."""
    import signal

    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    before = signal.pthread_sigmask(signal.SIG_BLOCK, _signal_numbers())
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, before)


def _rows_text(indices) -> str:
    """'rows 3, 4, 7' (the first 20, then 'and N more')."""
    indices = sorted(indices)
    shown = ", ".join(map(str, indices[:20]))
    return f"row{'s' if len(indices) > 1 else ''} {shown}" + (f" and {len(indices) - 20} more" if len(indices) > 20 else "")


def _stopped(pid: int) -> bool:
    """Whether process ``pid`` is stopped (SIGSTOP, SIGTSTP, a debugger: state T or t in /proc; Linux only)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] in ("T", "t")
    except (OSError, IndexError):  # gone, or no /proc (not Linux): not stopped as far as we can tell
        return False


class _StopWatch:
    """Kills a pool worker that stays stopped for WORKER_STOP_TIMEOUT s: ProcessPoolExecutor would wait for
    its chunk without end. Its death breaks the pool (BrokenProcessPool): the rows not finished run again
    on a fresh pool (_processes). The workers are this process's multiprocessing
    children that were not there before the pool (``before``). A stop counts only while this process
    watched: after a gap of more than 3 WATCH_INTERVAL between two checks (this process was stopped too,
    a Ctrl-Z of the whole group, or starved), the count starts again, so a worker read as stopped just
    after the command's own resumption (the group's SIGCONT not yet delivered to it) is not killed."""

    def __init__(self, before: set, clock: Callable[[], float] = time.monotonic):
        self.before, self.since, self.killed, self.clock, self.last = before, {}, [], clock, None

    def kill_all(self) -> None:
        """SIGKILL every worker of the pool now (a stopped one too: it could not act on SIGTERM)."""
        import multiprocessing

        for proc in set(multiprocessing.active_children()) - self.before:
            proc.kill()

    def check(self, timeout: float) -> None:
        """Kill every worker stopped for ``timeout`` s or more (0: every stopped worker, now)."""
        import multiprocessing
        import os
        import signal

        now = self.clock()
        if self.last is not None and now - self.last > 3 * WATCH_INTERVAL:  # we saw nothing meanwhile
            self.since = dict.fromkeys(self.since, now)
        self.last = now
        for proc in set(multiprocessing.active_children()) - self.before:
            if not _stopped(proc.pid):
                self.since.pop(proc.pid, None)
            elif now - self.since.setdefault(proc.pid, now) >= timeout:
                os.kill(proc.pid, signal.SIGKILL)  # a stopped process cannot act on SIGTERM
                self.killed.append(proc.pid)
                del self.since[proc.pid]


def _processes(items, task, workers, meanwhile=None) -> Iterator[tuple[int, dict | None]]:
    if start_method() == "fork" and len(items) >= WARM_UP_ROWS_PER_WORKER * workers:
        # the first row runs here, before the fork: what each worker would do at its first row (lazy
        # imports, the native kernel, the per-process caches: ~0.1 s of CPU) is done once and inherited.
        # That row runs alone, so it can add one row's time to the sweep's wall: with many rows a worker
        # that is a small share; with few (2 long rows on 2 workers) it would run them one after the other
        (i, params), items = items[0], items[1:]
        yield i, guarded(task, i, params)
        if not items:
            return
    # a worker that dies (or is killed, stopped: _StopWatch) breaks its pool, which then drops the rows of
    # every chunk not finished, the other workers' too: those run once more on a fresh pool, and what a
    # second broken pool leaves unfinished is lost (a row that kills its worker each time it runs)
    import sys

    unfinished = yield from _pool(items, task, workers, meanwhile)
    if unfinished:
        print(f"warning: a worker process died; {_rows_text(i for i, _ in unfinished)} did not finish: "
              f"they run again on a fresh pool (once)", file=sys.stderr, flush=True)
        unfinished = yield from _pool(unfinished, task, workers, last=True)
        if unfinished:
            print(f"warning: a worker process died again; {_rows_text(i for i, _ in unfinished)} are lost",
                  file=sys.stderr, flush=True)
    yield from ((i, None) for i, _ in unfinished)


def _pool(items, task, workers, meanwhile=None, last=False):
    """Yields (index, result) of the rows of ``items`` a pool of ``workers`` processes finished; returns the
    items (index, params) of the chunks it did not finish (its pool broke: a worker died or was killed).
    last: the caller runs nothing again (a stopped worker's warning then says its pool's rows are lost)."""
    import multiprocessing
    import os
    import sys
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    # checked again: a run may leave a thread behind (a log sink's), and then workers are spawned.
    # With "fork", the pool forks all its workers at the first submit, before it starts its own thread
    method = start_method()
    watch = _StopWatch(set(multiprocessing.active_children()))
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context(method),
                               initializer=worker_start, initargs=(os.getpid(),))
    unfinished, finished = [], False
    try:  # forked workers have this process's prepared rows in their memory; spawned ones get them sent
        with _signals_blocked():  # the workers start (at the submits) with the command's signals blocked
            futures = {pool.submit(run_chunk, task if method == "fork" else carrying(task, chunk), chunk): chunk
                       for chunk in chunks(items, workers)}
        if meanwhile is not None:
            meanwhile()
        pending = set(futures)
        while pending:
            done, pending = wait(pending, timeout=WATCH_INTERVAL, return_when=FIRST_COMPLETED)
            watch.check(WORKER_STOP_TIMEOUT)
            for fut in done:
                if fut.exception() is not None:  # the pool broke (BrokenProcessPool): this chunk did not finish
                    unfinished += futures[fut]
                else:
                    yield from fut.result()
        finished = True
    finally:
        if not finished:  # leaving early (Ctrl-C, SIGTERM, an error, the caller closed us): the shutdown would
            watch.kill_all()  # wait for every running chunk to end (35 s seen); their rows are not results
        watch.check(0)  # a stopped worker would keep the shutdown waiting
        pool.shutdown(wait=True, cancel_futures=True)
        for pid in watch.killed:
            print(f"warning: sweep worker process {pid} was stopped (SIGSTOP, Ctrl-Z or a debugger) for "
                  f"{WORKER_STOP_TIMEOUT:g} s or more: killed; the rows its pool had not finished "
                  + ("are lost (a resume runs them)" if last else "run again on a fresh pool (once)"), file=sys.stderr)
    return sorted(unfinished, key=lambda item: item[0])


def local_worker_method() -> str:
    """How a LocalCluster's nannies start their worker processes: "forkserver" where the platform has
    it (Linux, macOS), else "spawn" (Dask's default).

    The forkserver (batch_env.start_forkserver) is a fresh interpreter, started by fork + exec (safe
    whatever threads this process runs), that imports distributed and the modules a row needs once;
    each worker is a fork of it. Forking it is safe: it runs no thread but its main one (none of those
    imports starts a thread; under ``ftstab`` OpenBLAS has none either, batch_env.py; where it has
    one, OpenBLAS's own fork handlers stop and restart it). A spawned worker pays the interpreter and
    those imports itself (~0.5 s of CPU each). The workers are the forkserver's children, not this
    process's: getrusage(RUSAGE_CHILDREN) of the command's parent counts neither unless that parent
    is a subreaper (the benchmark is).
    """
    from ftstab_mj.studies.batch_env import start_forkserver

    # started here with our preload list; distributed's own, set when a nanny starts, comes too late
    return "forkserver" if start_forkserver() else "spawn"


def _dask_connect(workers: int, scheduler: str | None):
    """(client, local cluster or None): a client of the scheduler at ``scheduler``, or of a new
    LocalCluster of ``workers`` single-threaded processes. EngineError when it cannot be reached."""
    import logging

    import dask
    from distributed import Client, LocalCluster

    cluster = None
    try:
        if scheduler:
            return Client(scheduler, timeout="10s"), None
        # dashboard_address ":0": its HTTP server on a free port (None would still take 8787, and warn
        # when another cluster holds it). preload: each worker imports what a row needs as it starts
        # (runner.dask_setup), not when its first row arrives.
        # death_timeout: a nanny whose worker is not up by then gives up (LocalCluster then closes all).
        # worker_ttl: a worker silent (no heartbeat: every 0.5 s up to 10 workers) for WORKER_STOP_TIMEOUT s
        # is restarted by its nanny and its tasks run again elsewhere; distributed's default, 5 minutes (checked
        # every 5 minutes), kept a sweep waiting 5 to 10 minutes on a stopped worker. Ours only, not the config
        # QUIET: the event loops' periodic work, which costs the command 5 % of a core and each worker 2 % while
        # they wait (0.8 % and 0.25 % with it; load 4), beside the rows on the same cores (the nannies pass it on)
        with dask.config.set({"distributed.worker.multiprocessing-method": local_worker_method(), **QUIET}):
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                                   silence_logs=logging.ERROR, preload=LOCAL_PRELOAD,
                                   death_timeout=WORKER_START_TIMEOUT,
                                   scheduler_kwargs={"worker_ttl": f"{WORKER_STOP_TIMEOUT}s"})
        return Client(cluster), cluster
    except Exception as exc:  # noqa: BLE001 - any failure to start a local cluster is the engine's: one line
        if cluster is not None:
            cluster.close()
        if scheduler:
            if isinstance(exc, (OSError, TimeoutError)):
                raise EngineError(f"--scheduler: expected a reachable Dask scheduler, could not reach the scheduler "
                                  f"at {scheduler} ({_one_line(exc)})") from None
            if isinstance(exc, ValueError):  # distributed's parse of the address: no port, an unknown scheme
                raise EngineError(f"--scheduler: expected a Dask scheduler address such as tcp://HOST:PORT, found "
                                  f"{scheduler!r} (ValueError: {_one_line(exc)})") from None
            raise
        # e.g. "Nanny failed to start." (RuntimeError) from distributed's own AssertionError when a nanny
        # gives up on a worker still starting, or a port that cannot be bound (OSError)
        cause = exc.__cause__ or exc
        raise EngineError(f"--engine dask: expected a local cluster of {workers} workers up within "
                          f"{WORKER_START_TIMEOUT:g} s, it did not start ({type(cause).__name__}: {_one_line(cause)})") from None


def _one_line(exc: BaseException) -> str:
    """An exception's message on one line (a worker's own error, passed on by distributed, may span several)."""
    return " ".join(str(exc).split())


def _dask_close(client, cluster) -> None:
    """Close the client, then the local cluster (None: none). A failure is one line on stderr, not an
    exception: the rows' results are in by then (the table and the exit status do not depend on it), and it
    may run in started_ahead's thread, whose errors nobody would see."""
    import sys

    for what, thing in (("client", client), ("local cluster", cluster)):
        if thing is None:
            continue
        try:
            thing.close()
        except Exception as exc:  # noqa: BLE001 - whatever went wrong, the sweep's results stand
            print(f"warning: --engine dask: closing the {what} failed ({type(exc).__name__}: {_one_line(exc)}); "
                  f"the sweep's results are not affected", file=sys.stderr)


class StartedAhead:
    """A Dask connection being made in a background thread for one ``with started_ahead(...)`` block, which
    owns it (no state outside it). ``connection``: the Future of (client, local cluster or None).
    :func:`execute` given it with the same workers and scheduler takes it over (:meth:`take`) and has it
    closed in the same thread once its rows are done (:meth:`close_beside`)."""

    def __init__(self, workers: int, scheduler: str | None):
        from concurrent.futures import ThreadPoolExecutor

        self.key = (workers, scheduler)
        self._thread = ThreadPoolExecutor(1, thread_name_prefix="ftstab-dask-start")
        self.connection = self._thread.submit(_dask_connect, workers, scheduler)
        self.taken = False

    def take(self, workers: int, scheduler: str | None):
        """(client, cluster) made ahead for (workers, scheduler) (its EngineError, if it failed); None when it
        was made for others or is already taken."""
        if self.taken or self.key != (workers, scheduler):
            return None
        self.taken = True
        return self.connection.result()

    def close_beside(self, client, cluster) -> None:
        self._thread.submit(_dask_close, client, cluster)

    def finish(self) -> None:
        """Wait for the closes submitted; close the connection if it was never taken."""
        self._thread.shutdown(wait=True)
        if not self.taken and self.connection.exception() is None:
            _dask_close(*self.connection.result())


@contextmanager
def started_ahead(engine: str, workers: int = 1, scheduler: str | None = None):
    """Start ``engine`` in a background thread while the block runs, so that its start-up overlaps
    what the block does first (``ftstab sweep`` validates the rows); yields a :class:`StartedAhead`
    (None for the engines that do not start ahead), which :func:`execute` given it (``ahead=``) takes
    over (and reports its EngineError, if any, as it would have).

    Only the Dask engine starts ahead: a LocalCluster's worker processes take ~1 s of wall to start,
    a scheduler a round trip to answer. Serial needs nothing, and process workers are forked when the
    rows run so that they inherit what was validated. What was started and not taken over is closed
    at the end of the block; what :func:`execute` took over it closes in the same background thread
    once its rows are done (a LocalCluster takes ~0.05-0.1 s to stop its workers), so the caller
    writes its table meanwhile, and the end of the block waits for it.
    """
    if engine != "dask":
        yield None
        return
    ahead = StartedAhead(workers, scheduler)
    try:
        yield ahead
    finally:
        ahead.finish()


def _dask(items, task, workers, scheduler, meanwhile=None, ahead: StartedAhead | None = None
          ) -> Iterator[tuple[int, dict | None]]:
    from distributed import as_completed

    made = ahead.take(workers, scheduler) if ahead is not None else None
    client, cluster = made if made is not None else _dask_connect(workers, scheduler)
    tag = uuid.uuid4().hex[:8]  # keys unique to this sweep on a shared scheduler
    try:
        if scheduler:  # the cluster's worker threads now (more may join later): each runs a chunk at once
            workers = max(1, sum(w.get("nthreads", 1) for w in client.scheduler_info().get("workers", {}).values()))
        futures = {client.submit(run_chunk_beside, carrying(task, chunk), chunk, key=f"ftstab-{tag}-{chunk[0][0]}",
                                 pure=False): chunk
                   for chunk in chunks(items, workers)}
        if meanwhile is not None:
            meanwhile()
        for fut in as_completed(futures):
            if fut.status != "finished":  # "error": the task killed its workers (KilledWorker)
                yield from ((i, None) for i, _ in futures[fut])
            else:
                yield from fut.result()
            fut.release()
    finally:
        if made is not None:  # started_ahead's block waits for it, after the caller wrote its table
            ahead.close_beside(client, cluster)
        else:
            _dask_close(client, cluster)

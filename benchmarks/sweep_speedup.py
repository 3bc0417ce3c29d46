"""Speed-up of `ftstab sweep` from 1 to 2 workers, the set-up cost of one sweep row, and the fixed costs.

    python -m benchmarks sweep_speedup [--case rows|periods] [--samples N] [--repeat 3] [--no-external]

Cases:
- ``rows`` (default, issue 16): ``--samples`` rows (default 200) of 1 s simulated of the r = 2 robust
  cart, z0[0] drawn in [-1, 1] m: ~3 ms of CPU a row, so engine start-up and per-task costs weigh
  as much as the runs.
- ``periods`` (issue 7): the 7 control periods of robust_accuracy_vs_period.toml at 20 s, physics step
  0.1 ms, times 8 initial positions: 56 rows of ~0.3 s of CPU each.

First the set-up cost of a row, in this process: CPU per row of 1 s and of 2 s rows (the task the
engines call, 40 rows each, alternated, median of 5), extrapolated linearly to a 0 s row, both for a
row validated by prepare() in this process (serial, forked workers) and for one the worker validates
again (spawned and Dask workers). Then the fixed costs of the command, in a fresh process with the
command's environment (ftstab_mj.studies.batch_env; median of 3): interpreter, imports, load + expand +
prepare, writing the table, and for Dask ``import
distributed`` and a LocalCluster of 2 workers started and closed; from them and the rows' CPU, the
best speed-up 2 workers could give if starting them cost nothing. Then each configuration runs the
real command in a fresh process (wall from the command's start: engine start-up included),
alternately, --repeat times: serial, 2 dask workers (LocalCluster), 2 processes, and 2 workers of each
of two external ``dask scheduler`` started once by this script (``dask worker --nworkers 2 --nthreads 1``:
start-up paid once, as on a standing cluster), one with Dask's default configuration, one with the
README's (engine.QUIET: no profiler, rarer periodic work), and a third (README's configuration) with one
worker of 2 threads (``--nworkers 1 --nthreads 2``: a worker's threads each run a chunk); and the batch
engine on 2 threads. Prints median and range of the wall times, the
speed-up of the medians over serial (of the command's wall, as before), the sweep's own wall next
to it (from the first run's start to the table written, as the command prints it: what the engines
gain without the start-up; its ratio to serial's is labelled "x"), the CPU of the command and its own workers, or of the
command and the external cluster (scheduler, nannies, workers) while it ran (what a configuration
costs whatever the machine's other load), the 1-minute load average before each run,
and checks that every configuration wrote the same table. The machine's other load counts: before each repeat,
:func:`machine_parallelism` measures what 2 processes can gain at all at that moment.

Every command runs as an installed package does, with its bytecode cached (benchmarks/_common.child_env).
Where PYTHONDONTWRITEBYTECODE is set and the tree has no ``__pycache__`` (this machine's sessions), Python
compiles the ~55 modules a sweep imports from source at every start (~0.1 s of CPU, printed): a cost of that
environment, not of the command, which no install pays (pip compiles a wheel's modules).
"""

import argparse
import json
import os
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks._common import ROOT, child_env
from ftstab_mj.studies.batch_env import batch_environment
from ftstab_mj.studies.sweep.table import VARYING_COLUMNS, read_table

BASE = ROOT / "scenarios" / "cart_r2_robust.toml"
CASES = {
    "rows": '''samples = {samples}
[set]
"sim.duration" = {duration}
[draw]
"loops.cart.z0[0]" = {{uniform = [-1.0, 1.0]}}
''',
    "periods": '''samples = 8
[set]
"sim.duration" = 20.0
"sim.physics_step" = 1e-4
[grid]
"sim.period" = [1e-4, 2e-4, 5e-4, 1e-3, 2e-3, 5e-3, 1e-2]
[draw]
"loops.cart.z0[0]" = {{uniform = [-1.0, 1.0]}}
''',
}


def sweep_file(folder: Path, case: str, duration: float = 1.0, samples: int = 200) -> Path:
    path = folder / f"{case}.toml"
    path.write_text(f'name = "{case}"\ndescription = "benchmark"\nscenario = "{BASE}"\nseed = 1\n'
                    + CASES[case].format(duration=duration, samples=samples))
    return path


def setup_cost(folder: Path) -> dict[str, tuple[float, float, float]]:
    """{"prepared" | "validated": (ms of CPU per 1 s row, per 2 s row, extrapolated to a 0 s row)}: the
    task as the engines call it, on rows prepare() validated in this process (serial engine, forked
    workers) and on rows the task validates itself (spawned and Dask workers)."""
    from ftstab_mj.studies.sweep import expand, load_sweep
    from ftstab_mj.studies.sweep.engine import run_chunk
    from ftstab_mj.studies.sweep.row import prepare

    sweeps = {}
    for d in (1.0, 2.0):
        sw = load_sweep(sweep_file(folder, "rows", d))
        rows = expand(sw)[:40]
        task, _ = prepare(sw, rows)
        run_chunk(task, [(r.index, r.params) for r in rows[:2]])  # warm: imports, the certificate, the caches
        sweeps[d] = (sw, rows)
    per_row = {(kind, d): [] for kind in ("prepared", "validated") for d in (1.0, 2.0)}
    for _ in range(5):
        for kind in ("prepared", "validated"):
            for d, (sw, rows) in sweeps.items():
                task, _ = prepare(sw, rows)
                if kind == "validated":
                    task = type(task)(task.base, task.source)  # no prepared scenarios: each row validated again
                t0 = time.process_time()
                run_chunk(task, [(r.index, r.params) for r in rows])
                per_row[(kind, d)].append((time.process_time() - t0) / len(rows) * 1e3)
    out = {}
    for kind in ("prepared", "validated"):
        c1, c2 = statistics.median(per_row[(kind, 1.0)]), statistics.median(per_row[(kind, 2.0)])
        out[kind] = (c1, c2, 2 * c1 - c2)
    return out


# The fixed costs of the command, phase by phase, in a fresh process: (CPU s, wall s) of each phase.
PHASES = r"""
import json, sys, time


def main():
    marks = [("start", time.process_time(), time.perf_counter())]

    def mark(name):
        marks.append((name, time.process_time(), time.perf_counter()))

    import ftstab_mj.cli, ftstab_mj.metrics.run_metrics, ftstab_mj.scenario.run, ftstab_mj.simulation.run_loop, ftstab_mj.studies.sweep.row
    mark("imports")
    from pathlib import Path
    from ftstab_mj.studies.sweep import expand, load_sweep
    from ftstab_mj.studies.sweep.row import prepare
    sweep = load_sweep(sys.argv[1])
    rows = expand(sweep)
    prepare(sweep, rows)
    mark("load, expand, prepare")
    from ftstab_mj.studies.sweep.table import load_writer, read_journal, write_table
    load_writer(Path(sys.argv[3]))
    mark("import the table writer")
    write_table(list(read_journal(Path(sys.argv[2])).values()), Path(sys.argv[3]))
    mark("write the table")
    import distributed
    mark("import distributed")
    from ftstab_mj.studies.sweep.engine import _dask_close, _dask_connect
    client, cluster = _dask_connect(2, None)
    mark("LocalCluster of 2 up")
    started = sorted(client.run(worker_cpu).values())  # the workers' own CPU, not in this process's
    _dask_close(client, cluster)
    mark("LocalCluster closed")
    phases = [(b[0], b[1] - a[1], b[2] - a[2]) for a, b in zip(marks, marks[1:])]
    phases.append(("a Dask worker's own start", started[-1][0], 0.0))
    if started[-1][1] is not None:  # forked from a forkserver: its imports are paid there, once
        phases.append(("their forkserver", started[-1][1], 0.0))
    print(json.dumps(phases))


def worker_cpu():  # (CPU s of this process, CPU s of its parent if that is a forkserver, else None)
    import os
    import resource

    r = resource.getrusage(resource.RUSAGE_SELF)
    parent = None
    with open(f"/proc/{os.getppid()}/cmdline", "rb") as f:
        if b"forkserver" in f.read():
            with open(f"/proc/{os.getppid()}/stat") as g:
                fields = g.read().rsplit(")", 1)[1].split()
            parent = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime + stime
    return r.ru_utime + r.ru_stime, parent


if __name__ == "__main__":  # a spawned Dask worker imports this file again: it must do nothing then
    main()
"""


COMPILE = r"""
import sys, time
import ftstab_mj.cli, ftstab_mj.metrics.run_metrics, ftstab_mj.scenario.run, ftstab_mj.simulation.run_loop, ftstab_mj.studies.sweep.row
files = [m.__file__ for m in list(sys.modules.values())
         if getattr(m, "__file__", None) and m.__name__.startswith("ftstab_mj") and m.__file__.endswith(".py")]
t0 = time.process_time()
for f in files:
    with open(f, "rb") as src:
        compile(src.read(), f, "exec")
print(len(files), time.process_time() - t0)
"""


def compile_cost(env: dict) -> tuple[int, float]:
    """(modules, CPU s): compiling the ftstab_mj modules a sweep imports from their sources, what Python does at
    every start where they have no bytecode (PYTHONDONTWRITEBYTECODE set, no __pycache__); median of 3."""
    runs = [subprocess.run([sys.executable, "-c", COMPILE], cwd=ROOT, env=env, capture_output=True, text=True,
                           check=True).stdout.split() for _ in range(3)]
    return int(runs[0][0]), statistics.median(float(r[1]) for r in runs)


def fixed_costs(folder: Path, sweep: Path, journal: Path, env: dict) -> dict[str, tuple[float, float]]:
    """{phase: (median CPU s, median wall s)} of 3 fresh processes; "interpreter" is `python -c pass` (wall)."""
    script = folder / "phases.py"
    script.write_text(PHASES)
    runs = []
    for _ in range(3):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", "pass"], check=True, env=env)
        start = time.perf_counter() - t0
        out = subprocess.run([sys.executable, str(script), str(sweep), str(journal), str(folder / "t.parquet")],
                             cwd=ROOT, capture_output=True, text=True, check=True, env=env)
        reap()
        runs.append([("interpreter", start, start)] + [tuple(p) for p in json.loads(out.stdout.strip().splitlines()[-1])])
    return {name: (statistics.median(r[k][1] for r in runs), statistics.median(r[k][2] for r in runs))
            for k, (name, _, _) in enumerate(runs[0])}


def best_speedup(fixed: float, beside: float, extra: float, rows: int, per_row: float, check: float) -> float:
    """Serial's wall over 2 workers' at best (Amdahl): ``fixed`` s of the command that does not split, of which
    ``beside`` s runs beside the workers (sharing the cores with them), ``extra`` s the engine adds to the
    command (Dask: ``import distributed``; its cluster's start and per-row costs taken as free), and ``rows``
    rows of ``per_row`` s each, each validated first by the command itself (``check`` s a row, serial)."""
    return (fixed + rows * (per_row + check)) / (fixed - beside + extra + rows * check + (rows * per_row + beside) / 2)


def rows_for(target: float, fixed: float, beside: float, extra: float, per_row: float, check: float) -> float:
    """The rows from which :func:`best_speedup` reaches ``target`` (inf where it never does: the rows'
    validation, serial, caps it at (per_row + check) / (per_row / 2 + check))."""
    gain = per_row * (1 - target / 2) - check * (target - 1)
    need = target * (fixed - beside / 2 + extra) - fixed
    return max(0.0, need / gain) if gain > 0 else float("inf")


def config_environment(config: dict) -> dict[str, str]:
    """Dask configuration {key: value} as the environment variables a `dask scheduler` or `dask worker` reads
    (DASK_ + the key's parts joined by __, upper case; Dask reads "-" and "_" as the same)."""
    return {"DASK_" + "__".join(part.upper().replace("-", "_") for part in key.split(".")): str(value)
            for key, value in config.items()}


def start_external(folder: Path, env: dict, name: str = "defaults", nworkers: int = 2, nthreads: int = 1):
    """A `dask scheduler` and `dask worker --nworkers 2 --nthreads 1` (or ``nworkers``, ``nthreads``) as
    subprocesses, with Dask's default configuration ("defaults") or with engine.QUIET's as the README's cluster
    commands set it (any other name); (address, procs)."""
    from ftstab_mj.studies.sweep.engine import QUIET

    env = {**env, **(config_environment(QUIET) if name != "defaults" else {})}
    addr_file = folder / f"scheduler-{name}.json"
    dask = [sys.executable, "-m", "distributed.cli.dask_scheduler"]
    sched = subprocess.Popen(dask + ["--scheduler-file", str(addr_file), "--port", "0", "--dashboard-address", ":0"],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    for _ in range(300):
        if addr_file.exists() and addr_file.stat().st_size:
            break
        time.sleep(0.1)
    worker = subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", "--scheduler-file", str(addr_file),
                               "--nworkers", str(nworkers), "--nthreads", str(nthreads), "--no-dashboard"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    from distributed import Client

    with Client(scheduler_file=str(addr_file), timeout="30s") as client:
        client.wait_for_workers(nworkers, timeout=60)
        address = client.scheduler.address
    return address, (worker, sched)


def tree_cpu(roots) -> float:
    """CPU s (user + system) so far of the live processes ``roots`` (pids) and all their descendants (Linux:
    /proc; 0 elsewhere): an external cluster's scheduler, nannies and workers, which no rusage of ours counts."""
    parent, cpu = {}, {}
    for entry in os.listdir("/proc") if sys.platform.startswith("linux") else ():
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:  # gone meanwhile
            continue
        parent[int(entry)] = int(fields[1])
        cpu[int(entry)] = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    total = 0.0
    for pid in cpu:
        p = pid
        while p > 1 and p not in roots:
            p = parent.get(p, 0)
        if p in roots:
            total += cpu[pid]
    return total


def become_subreaper() -> None:
    """Make this process (Linux) the reaper of its orphaned descendants, so that the CPU of a local Dask
    cluster's forkserver and its workers, which outlive the command, still counts in RUSAGE_CHILDREN."""
    import ctypes

    if sys.platform.startswith("linux"):
        ctypes.CDLL(None, use_errno=True).prctl(36, 1, 0, 0, 0)  # PR_SET_CHILD_SUBREAPER


def reap(keep=(), timeout: float = 60.0) -> None:
    """Wait for every child of this process but ``keep`` (pids): the orphans a command left (see above)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        children = []
        for entry in os.listdir("/proc") if sys.platform.startswith("linux") else ():
            try:
                with open(f"/proc/{entry}/stat") as f:
                    ppid = int(f.read().rsplit(")", 1)[1].split()[1])
            except (OSError, ValueError, IndexError):
                continue
            if ppid == os.getpid() and int(entry) not in keep:
                children.append(int(entry))
        if not children:
            return
        for pid in children:
            try:
                os.waitpid(pid, 0)
            except ChildProcessError:
                pass


def _spin(n: int) -> None:
    x = 0
    for i in range(n):
        x += i


def machine_parallelism(n: int = 4_000_000) -> float:
    """Wall of some pure-Python work in 1 process / the same work split over 2 (forked) processes: the
    speed-up this machine gives 2 workers right now. It is ~2 on 2 idle cores, and ~1 when the other
    sessions keep both busy: Linux shares the CPU between sessions (autogroups) before processes, so
    a command's extra processes add CPU only while another session leaves a core idle."""
    import multiprocessing

    t0 = time.perf_counter()
    _spin(2 * n)
    one = time.perf_counter() - t0
    ctx = multiprocessing.get_context("fork")
    t0 = time.perf_counter()
    procs = [ctx.Process(target=_spin, args=(n,)) for _ in range(2)]
    for p in procs:
        p.start()
    for p in procs:
        p.join()
    return one / (time.perf_counter() - t0)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", choices=tuple(CASES), default="rows")
    ap.add_argument("--samples", type=int, default=200, help="rows of the rows case (default 200)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-external", action="store_true", help="skip the external dask scheduler")
    args = ap.parse_args()
    become_subreaper()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        env = batch_environment(child_env(extra_warm=("distributed", "dask")))
        costs = setup_cost(tmp)
        for kind, (c1, c2, c0) in costs.items():
            print(f"CPU per row, {kind:<9}: {c1:.2f} ms (1 s rows), {c2:.2f} ms (2 s rows); set-up of a row "
                  f"(0 s extrapolated): {c0:.2f} ms   (load: {os.getloadavg()[0]:.2f})", flush=True)
        sweep = sweep_file(tmp, args.case, samples=args.samples)
        if args.case == "rows":  # the fixed costs, and what they leave of the speed-up
            ref = tmp / "ref"
            subprocess.run([sys.executable, "-m", "ftstab_mj", "sweep", str(sweep), "--out", str(ref)], cwd=ROOT,
                           capture_output=True, check=True, env=env)
            phases = fixed_costs(tmp, sweep, ref / f"{args.case}.jsonl", env)
            modules, cpu = compile_cost(env)
            print(f"bytecode: cached, as installed; compiling the {modules} modules a sweep imports "
                  f"from source at every start (PYTHONDONTWRITEBYTECODE, no __pycache__) would add {cpu:.3f} s of CPU")
            print(f"fixed costs of the command, fresh process, median of 3 (load: {os.getloadavg()[0]:.2f}):")
            for name, (cpu, wall) in phases.items():
                print(f"  {name:<24} {cpu:6.3f} s CPU {wall:6.3f} s wall")
            # a row's validation: prepare() validates the base scenario and every row (the files' reading: ~1 ms)
            check = phases["load, expand, prepare"][0] / (args.samples + 1)
            fixed = sum(phases[k][0] for k in ("interpreter", "imports", "import the table writer", "write the table"))
            per_row = costs["prepared"][0] / 1e3
            beside = phases["import the table writer"][0]  # made while the workers run (engine.execute's meanwhile)
            print(f"  serial = {fixed:.2f} s fixed + {args.samples} x ({check * 1e3:.2f} ms validated + {per_row * 1e3:.2f} ms "
                  f"run); 2 workers started for free, the runs split evenly, the table writer's import ({beside:.3f} s) "
                  f"beside them, the validation serial:")
            for name, extra in (("processes", 0.0), ("dask", phases["import distributed"][0])):
                bound = [best_speedup(fixed, beside, extra, n, per_row, check) for n in (args.samples, 1000, 2000)]
                print(f"    {name:<9} + {extra:.2f} s ({'nothing' if not extra else 'import distributed'}) give at best "
                      f"{bound[0]:.2f}x; 1.6x from {rows_for(1.6, fixed, beside, extra, per_row, check):.0f} rows of this "
                      f"size (x{bound[1]:.2f} at 1000, x{bound[2]:.2f} at 2000)", flush=True)
        configs = {
            "serial": ("--workers", "1"),
            "dask, 2 workers": ("--engine", "dask", "--workers", "2"),
            "processes, 2 workers": ("--workers", "2"),
            "batch, 2 threads": ("--engine", "batch", "--workers", "2"),
        }
        procs, clusters = (), {}
        if not args.no_external:  # Dask's defaults, the README's configuration, and 1 worker of 2 threads
            for how, shape in (("defaults", (2, 1)), ("quiet", (2, 1)), ("quiet, 1 worker x 2 threads", (1, 2))):
                address, started = start_external(tmp, env, how, *shape)
                procs += started
                configs[f"external dask, {how}"] = ("--scheduler", address)
                clusters[f"external dask, {how}"] = {p.pid for p in started}
        try:
            walls, sweeps, cpus, tables = {}, {}, {}, {}
            capacity = []
            for rep in range(args.repeat):
                capacity.append(machine_parallelism())
                print(f"machine: pure-Python work on 2 processes x{capacity[-1]:.2f} faster than on 1 "
                      f"(load: {os.getloadavg()[0]:.2f})", flush=True)
                for k, (name, extra) in enumerate(configs.items()):
                    out = tmp / f"{rep}-{k}"
                    load = os.getloadavg()[0]
                    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
                    c0 = tree_cpu(clusters.get(name, ()))
                    t0 = time.perf_counter()
                    proc = subprocess.run([sys.executable, "-m", "ftstab_mj", "sweep", str(sweep), "--out", str(out),
                                           *extra], cwd=ROOT, capture_output=True, text=True, env=env)
                    wall = time.perf_counter() - t0
                    reap(keep={p.pid for p in procs})  # a local cluster's forkserver and workers: their CPU counts too
                    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
                    # CPU of the command and of the workers it started, or of the external cluster it ran on: the
                    # scheduler, nannies and workers (an idle cluster's periodic work while the command runs included)
                    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime) + tree_cpu(clusters.get(name, ())) - c0
                    if proc.returncode != 0:
                        sys.exit(f"{name}: exit {proc.returncode}: {proc.stderr.strip().splitlines()[-1]}")
                    own = float(re.search(r"\(([0-9.]+) s from the first run's start to the table\)", proc.stdout)[1])
                    print(f"{name:<44} {wall:6.2f} s wall ({own:5.2f} s of sweep) {cpu:6.2f} s CPU   "
                          f"(load before: {load:.2f})", flush=True)
                    walls.setdefault(name, []).append(wall)
                    sweeps.setdefault(name, []).append(own)
                    cpus.setdefault(name, []).append(cpu)
                    table = read_table(out / f"{args.case}.parquet")
                    # a sweep whose rows failed (e.g. a C kernel not built for this tree) is fast and
                    # identical across engines: it measures nothing
                    failed = [s for s in table["status"] if s != "completed"]
                    if failed:
                        sys.exit(f"{name}: {len(failed)} of {len(table['status'])} rows not completed "
                                 f"({failed[0]}): nothing to measure (is the C kernel built for this tree?)")
                    tables[name] = {c: v for c, v in table.items() if c not in VARYING_COLUMNS}
        finally:
            for p in procs:
                p.terminate()
                p.wait(timeout=30)
        n = len(tables["serial"]["row"])
        serial, serial_own = statistics.median(walls["serial"]), statistics.median(sweeps["serial"])
        print(f"\n{n} runs, median [min, max] of {args.repeat}, on {os.cpu_count()} cores; speed-up: of the "
              f"command's wall over serial's; sweep: wall from the first run's start to the table written:")
        for name, ws in walls.items():
            med, own = statistics.median(ws), statistics.median(sweeps[name])
            print(f"  {name:<44} {med:6.2f} s [{min(ws):.2f}, {max(ws):.2f}]   speed-up {serial / med:4.2f}   "
                  f"sweep {own:5.2f} s [{min(sweeps[name]):.2f}, {max(sweeps[name]):.2f}] (x{serial_own / own:4.2f})   "
                  f"CPU {statistics.median(cpus[name]):6.2f} s")
        print(f"  the machine meanwhile: 2 processes x{statistics.median(capacity):.2f} faster than 1 on pure-Python "
              f"work (median; range {min(capacity):.2f} to {max(capacity):.2f})")
        same = all(t == tables["serial"] for t in tables.values())
        print(f"  tables identical across engines: {'yes' if same else 'NO'}")


if __name__ == "__main__":
    main()

"""The cost of a whole run against MuJoCo's own, whole processes and in process, as CPU-time ratios.

    python -m benchmarks run_speed [--repeat 5] [--duration 100] [--scenarios cart_r2_robust,arm_robust]

For each scenario (default: the default scenario cart_r2_robust and the arm, arm_robust), ratios
each of alternated timings A B A B ... (a change of machine load hits both), median and min-max
over the repetitions, CPU time (user + system) of this process or of the child process:

  process     A: `python -m ftstab_mj run NAME --set sim.duration=D --out TMP` (the MCAP log, the
              metrics, the printed report; `ftstab view` makes the .rrd later); B: `python -c "import
              mujoco; <load the same MJCF>; mj_step x S"`, S the run's physics steps (D /
              physics_step). Target <= 1.6 for the README's scenario, cart_r2_robust. Then the same with
              --rrd (the Rerun recording as it goes).
  in process  A: run_scenario(scenario, sinks) in this process (imports done, certificate cached,
              after one untimed run) with the MCAP log, with both logs, and without logs; B: bare
              `mj_step(m, d, nstep=S)` of the same compiled model with mjcb_time NULLed as the run
              does (callback.timer_off).

The breakdown rows say where A's time goes, each against the same B (alternated too): the child
process that only imports what `ftstab run` imports (and what --rrd adds: rerun-sdk), the one that
runs 1 sample (start-up and every fixed cost), in process the run without sinks or metrics and with
the metrics stream, and the bare step with the bindings' default timer.

Child processes run with the bytecode cached, as an installed package has it (benchmarks/_common.child_env:
this machine sets PYTHONDONTWRITEBYTECODE, which makes every process compile ftstab_mj's sources again):
``--bytecode env`` keeps the environment.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import mujoco  # noqa: E402

from benchmarks._common import child_env  # noqa: E402

from ftstab_mj.plants.callback import timer_off  # noqa: E402
from ftstab_mj.logs import McapSink, RerunSink  # noqa: E402
from ftstab_mj.plants import make_plant  # noqa: E402
from ftstab_mj.scenario import find_scenario, load_scenario  # noqa: E402
from ftstab_mj.scenario.loader import scenario_to_dict  # noqa: E402
from ftstab_mj.scenario.run import record, run_scenario  # noqa: E402
from ftstab_mj.simulation.run_loop import Run, Simulation  # noqa: E402

# what `ftstab run` imports on its way (cli.run, the run loop, the MCAP sink, the metrics); --rrd adds rerun
RUN_IMPORTS = ("ftstab_mj.cli", "ftstab_mj.scenario.run", "ftstab_mj.simulation.run_loop", "ftstab_mj.logs",
               "ftstab_mj.metrics.run_metrics", "ftstab_mj.logs.mcap_sink", "foxglove.messages",
               "google.protobuf.descriptor_pb2", "mcap.records", "lz4.frame")


def cpu_of(fn, children: bool = False) -> float:
    """CPU seconds (user + system) of fn(): this process's, or its waited-for children's."""
    if children:
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        fn()
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        return r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime
    c0 = time.process_time()
    fn()
    return time.process_time() - c0


def summary(values) -> str:
    return f"{statistics.median(values):7.3f} ({min(values):.3f}-{max(values):.3f})"


class Case:
    """One scenario at ``duration`` s: its model, its step count, and the commands of the process rows."""

    def __init__(self, name: str, duration: float, tmp: Path, env: dict):
        self.name, self.tmp, self.env = name, tmp, env
        self.scenario = load_scenario(find_scenario(name), [f"sim.duration={duration:g}"])
        s = self.scenario.sim
        self.steps = int(round(duration / s.physics_step))
        sim = self.simulation()
        self.native = sim._native is not None
        self.model_path = tmp / f"{name}.xml"
        self.model_path.write_text(sim.model_xml)
        self.m, self.d = sim.model, sim.data
        py = sys.executable
        self.run_cmd = [py, "-m", "ftstab_mj", "run", name, "--set", f"sim.duration={duration:g}", "--out", str(tmp)]
        self.run_rrd_cmd = [*self.run_cmd, "--rrd"]
        self.one_sample_cmd = [py, "-m", "ftstab_mj", "run", name, "--set", f"sim.duration={s.period:g}",
                               "--out", str(tmp)]
        self.plain_cmd = [py, "-c", "import mujoco; m = mujoco.MjModel.from_xml_path(%r); d = mujoco.MjData(m); "
                          "mujoco.mj_step(m, d, nstep=%d)" % (str(self.model_path), self.steps)]
        # what `ftstab run` imports, with the collector as the command has it (ftstab_mj/__main__.py)
        self.imports_cmd = [py, "-c", "; ".join(["import gc", "gc.disable()", *(f"import {m}" for m in RUN_IMPORTS),
                                                 "gc.freeze()"])]
        self.imports_rerun_cmd = [py, "-c", "; ".join(["import gc", "gc.disable()", *(
            f"import {m}" for m in (*RUN_IMPORTS, "rerun")), "gc.freeze()"])]

    def simulation(self) -> Simulation:
        s, sc = self.scenario.sim, self.scenario
        return Simulation(make_plant(sc.plant.model, sc.plant.params), sc.loops, period=s.period,
                          physics_step=s.physics_step, integrator=s.integrator, divergence_limit=s.divergence_limit)

    # -- A and B of the rows -------------------------------------------------------------------------
    def child(self, cmd) -> float:
        return cpu_of(lambda: subprocess.run(cmd, check=True, capture_output=True, env=self.env, cwd=self.tmp),
                      children=True)

    def bare(self, timer: bool = False) -> float:
        """mj_step(nstep = S) of the run's compiled model from its start, no control callback."""
        mujoco.mj_resetData(self.m, self.d)
        if timer:
            return cpu_of(lambda: mujoco.mj_step(self.m, self.d, nstep=self.steps))
        with timer_off():
            return cpu_of(lambda: mujoco.mj_step(self.m, self.d, nstep=self.steps))

    def full(self, mcap: bool = True, rerun: bool = False) -> float:
        sinks = ([McapSink(self.tmp / "in.mcap", force=True)] if mcap else []) + (
            [RerunSink(self.tmp / "in.rrd", force=True)] if rerun else [])
        return cpu_of(lambda: run_scenario(self.scenario, sinks))

    def sim_only(self, metrics: bool) -> float:
        """The run as run_scenario builds it, without sinks; with or without the metrics stream."""
        sc = self.scenario

        def go():
            run = Run(self.simulation(), sc.sim.duration, scenario_dict=scenario_to_dict(sc), metric_settings=sc.metrics)
            record(run, (), metrics=metrics)

        return cpu_of(go)


def alternate(a, b, repeat: int) -> tuple[list[float], list[float]]:
    """CPU seconds of a() and b(), run A B A B ... ``repeat`` times each."""
    ta, tb = [], []
    for _ in range(repeat):
        ta.append(a())
        tb.append(b())
    return ta, tb


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=5, help="repetitions of every pair (default 5)")
    ap.add_argument("--duration", type=float, default=100.0, help="simulated seconds per run (default 100)")
    ap.add_argument("--scenarios", default="cart_r2_robust,arm_robust", help="comma-separated shipped scenarios")
    ap.add_argument("--bytecode", choices=("cached", "env"), default="cached",
                    help="child processes: bytecode cached in a private directory (default), or the environment as is")
    ap.add_argument("--no-breakdown", action="store_true", help="only the two ratios")
    args = ap.parse_args(argv)
    R = args.repeat
    print(f"ftstab_mj run speed: {args.duration:g} s simulated, {R} alternated repetitions, CPU time (user + sys), "
          f"mujoco {mujoco.__version__}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f} at start")
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        env = child_env() if args.bytecode == "cached" else dict(os.environ, PYTHONPATH=str(ROOT))
        print(f"{'':44s} {'A CPU s':>22s} {'B CPU s':>22s} {'A / B':>22s}  target")
        for name in args.scenarios.split(","):
            case = Case(name.strip(), args.duration, tmp, env)
            print(f"{case.name}: {case.steps} physics steps, "
                  f"{'native' if case.native else 'Python'} control callback")
            case.child(case.run_rrd_cmd), case.child(case.plain_cmd)  # warm-up: bytecode written, certificate cached
            case.full(rerun=True)
            plain = lambda: case.child(case.plain_cmd)  # noqa: E731
            readme = 1.6 if case.name == "cart_r2_robust" else None  # the target: the README's scenario
            rows = [("process: `ftstab run` / plain mujoco", lambda: case.child(case.run_cmd), plain, readme),
                    ("process: `ftstab run --rrd` / plain mujoco", lambda: case.child(case.run_rrd_cmd), plain, None),
                    ("in process: run, MCAP / bare", case.full, case.bare, None),
                    ("in process: run, MCAP + Rerun / bare", lambda: case.full(rerun=True), case.bare, None),
                    ("in process: run, no logs / bare", lambda: case.full(mcap=False), case.bare, None)]
            if not args.no_breakdown:
                rows += [("  process: imports only / plain", lambda: case.child(case.imports_cmd), plain, None),
                         ("  process: imports + rerun-sdk / plain", lambda: case.child(case.imports_rerun_cmd), plain,
                          None),
                         ("  process: 1-sample run / plain", lambda: case.child(case.one_sample_cmd), plain, None),
                         ("  in process: sim only / bare", lambda: case.sim_only(False), case.bare, None),
                         ("  in process: sim + metrics / bare", lambda: case.sim_only(True), case.bare, None),
                         ("  in process: Rerun only / bare", lambda: case.full(mcap=False, rerun=True), case.bare,
                          None),
                         ("  bare with default mjcb_time / bare", lambda: case.bare(timer=True), case.bare, None)]
            for label, a, b, target in rows:
                ta, tb = alternate(a, b, R)
                ratios = [x / y for x, y in zip(ta, tb)]
                met = "" if target is None else ("  yes" if statistics.median(ratios) <= target else "  NO")
                print(f"{label:44s} {summary(ta):>22s} {summary(tb):>22s} {summary(ratios):>22s}  "
                      f"{'' if target is None else f'<= {target:g}'}{met}",
                      flush=True)
    print(f"load average {os.getloadavg()[0]:.2f} at the end")
    return 0


if __name__ == "__main__":
    sys.exit(main())

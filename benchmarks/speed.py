"""Speed of the testbed against MuJoCo's own cost: the ratios of issue 6, measured, as a table.

    python -m benchmarks speed [--repeat 5] [--steps 100000]

Every ratio compares two timings of the same model over the same number of physics steps, taken
one after the other in each repetition (so a change in machine load hits both); the table shows
the median ratio over the repetitions and its min-max, for wall-clock time and for CPU time (this
process, or the child process). On an idle machine the two agree for the single-threaded rows; on
a shared, loaded machine (load average above the CPU count) wall time mostly measures the other
processes, and the CPU-time ratio is the testbed's own cost. "met" is judged on the CPU-time
figures; for the ideal chain (split over the CPUs) that is trajectory-steps per CPU-second, i.e.
what one core sustains (the wall-clock rate of an idle machine is that times the threads used).
A whole run, in process with and without logs and as a whole `ftstab run` process against a plain
mujoco process: benchmarks/run_speed.py.

  callback     Simulation.advance with the paper's controller in the (native) control callback,
               one control sample per 1 ms physics step, batches of 1000 samples as simulate()
               uses, vs mj_step(m, d, nstep) of the same compiled model with no callback.
  ideal chain  simulate_chain(native=True), robust law, r = 2, 1,000 initial states x 1,000
               periods: trajectory-steps per second (the NumPy loop for reference).
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import sys
import time
from pathlib import Path

import mujoco
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ftstab_mj.simulation import native  # noqa: E402
from ftstab_mj.control import AdaptiveLaw, HongController, RobustLaw  # noqa: E402
from ftstab_mj.plants.disturbances import Signal  # noqa: E402
from ftstab_mj.simulation.ideal_chain import simulate_chain  # noqa: E402
from ftstab_mj.plants import make_plant  # noqa: E402
from ftstab_mj.scenario import LoopSpec  # noqa: E402
from ftstab_mj.simulation.run_loop import Simulation  # noqa: E402

STEP = 1e-3  # s, physics step and control period
BATCH = 1000  # samples per Simulation.advance, simulate()'s default batch
HONG = {2: HongController(2, -0.2, (1.0, 2.0)), 3: HongController(3, -0.1, (1.0, 1.7, 5.0))}


def law(kind: str, r: int):
    return RobustLaw(HONG[r], 1.0, 0.5) if kind == "robust" else AdaptiveLaw(HONG[r], 1.0, 0.5, 2.0, 0.5, 0.05)


def loops(kind: str, r: int):
    return [LoopSpec("cart", controller=law(kind, r), disturbance=Signal("sine", 0.0, 0.8, freq=0.5),
                     gain=Signal("sine", 1.0, 0.4, freq=0.3, phase=1.0), z0=(1.0,) + (0.0,) * (r - 1))]


class Clock:
    """(wall, cpu) seconds of a call: cpu of this process, plus its children when ``children``."""

    def __init__(self, fn, children=False):
        r0, c0, w0 = resource.getrusage(resource.RUSAGE_CHILDREN), time.process_time(), time.perf_counter()
        fn()
        self.wall = time.perf_counter() - w0
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        self.cpu = (r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime) if children else time.process_time() - c0

    def __truediv__(self, other):
        return self.wall / other.wall, self.cpu / other.cpu


timed = Clock


def bare(plant, steps: int) -> float:
    """mj_step(nstep) of the plant's compiled model, no callback installed."""
    m, d, _ = plant.compile(STEP)
    return timed(lambda: mujoco.mj_step(m, d, nstep=steps))


def with_callback(plant, kind: str, r: int, steps: int, use_native) -> float:
    sim = Simulation(plant, loops(kind, r), STEP, STEP, native=use_native)

    def go():
        with sim.installed():
            for _ in range(steps // BATCH):
                sim.advance(BATCH)

    return timed(go)


def chain_rate(use_native, n_traj=1000, n_steps=1000) -> tuple[float, float]:
    """Trajectory-steps per wall second and per CPU second of the batched ideal chain."""
    z0 = np.random.default_rng(0).uniform(-2.0, 2.0, (n_traj, 2))
    t = Clock(lambda: simulate_chain(law("robust", 2), z0, STEP, n_steps * STEP, Signal("sine", 0.0, 0.8, freq=0.5),
                                     native=use_native))
    return n_traj * n_steps / t.wall, n_traj * n_steps / t.cpu


def summary(values):
    return statistics.median(values), min(values), max(values)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=5, help="repetitions of every measurement (default 5)")
    ap.add_argument("--steps", type=int, default=100_000, help="physics steps per timing (default 100000)")
    args = ap.parse_args(argv)
    if not native.available():
        print(f"note: {native.UNAVAILABLE_REASON}: the native rows cannot be measured", file=sys.stderr)
        return 2
    steps, R = args.steps, args.repeat
    rows = []  # (what, unit, [(wall, cpu) per repetition], target text, test of the CPU median or None)
    cases = [("cart", {}, 2, "robust"), ("cart", {}, 2, "adaptive"),
             ("cart_integrating", {}, 3, "robust"), ("cart_integrating", {}, 3, "adaptive"),
             ("cart_integrating", {"sensor_refresh": False}, 3, "robust")]
    for model, params, r, kind in cases:
        plant = make_plant(model, params)
        ratios, per_step = [], []
        for _ in range(R):
            b = bare(plant, steps)
            ratios.append(with_callback(plant, kind, r, steps, True) / b)
            per_step.append((b.wall / steps * 1e6, b.cpu / steps * 1e6))
        label = f"callback {kind} r={r} ({model}{', no sensor refresh' if params else ''})"
        rows.append((label, "x bare", ratios, "<= 1.3", lambda v: v <= 1.3))
        rows.append((f"  bare mj_step, {model}", "us/step", per_step, "", None))
    plant = make_plant("cart")
    py = [with_callback(plant, "robust", 2, 10 * BATCH, False) / bare(plant, 10 * BATCH) for _ in range(min(R, 3))]
    rows.append(("  (Python callback, robust r=2, for reference)", "x bare", py, "", None))
    from ftstab_mj.simulation.native import chain_threads

    rates = [tuple(v / 1e6 for v in chain_rate(True)) for _ in range(R)]
    rows.append((f"ideal chain r=2, 1000 initial states, native ({chain_threads(1000)} threads)", "M traj-steps/s",
                 rates, ">= 10", lambda v: v >= 10))
    ref = [tuple(v / 1e6 for v in chain_rate(False, n_steps=100)) for _ in range(min(R, 3))]
    rows.append(("  (same, NumPy loop, for reference)", "M traj-steps/s", ref, "", None))

    print(f"ftstab_mj speed: {steps} steps of {STEP * 1e3:g} ms, {R} repetitions, load average "
          f"{os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs, mujoco {mujoco.__version__}")
    print(f"{'measurement':62s} {'wall median (min-max)':>24s} {'CPU median (min-max)':>24s}  {'unit':15s} "
          f"{'target':7s} met")
    for what, unit, values, target, ok in rows:
        cols = []
        for k in (0, 1):
            med, lo, hi = summary([v[k] for v in values])
            cols.append(f"{med:.3g} ({lo:.3g}-{hi:.3g})")
        met = "" if ok is None else ("yes" if ok(summary([v[1] for v in values])[0]) else "NO")
        print(f"{what:62s} {cols[0]:>24s} {cols[1]:>24s}  {unit:15s} {target:7s} {met}")
    return 0

if __name__ == "__main__":
    sys.exit(main())

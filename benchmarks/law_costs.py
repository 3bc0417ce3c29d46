"""Cost of every registered control law in the run loop, as a ratio to bare MuJoCo stepping.

    python benchmarks/law_costs.py [--repeat 5] [--steps 20000] [--r 2]

For each law (the shipped comparison's parameters, scenarios/compare/cart_r<r>.toml) and each path it
can run on (native C callback where kernel.c has its twin, the Python callback always), one
repetition times Simulation.advance over ``steps`` control samples (period = physics step = 1 ms,
batches of 1000) and, right after it, mj_step(m, d, nstep) of the same compiled model with no
callback; the table shows the median CPU-time ratio over the repetitions with its min-max, and the
extra cost per control sample in microseconds of the controlled run over bare stepping (median of
(run time - bare time) / samples: the law plus, on the Python path, the run loop's Python callback).
CPU time of this process: on a shared machine wall time mostly measures the other processes.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import mujoco

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ftstab_mj.simulation import native  # noqa: E402
from ftstab_mj.plants.callback import timer_off  # noqa: E402
from ftstab_mj.studies.compare import load_comparison  # noqa: E402
from ftstab_mj.plants import make_plant  # noqa: E402
from ftstab_mj.scenario import LoopSpec  # noqa: E402
from ftstab_mj.scenario.schema import ControllerSpec  # noqa: E402
from ftstab_mj.plants.disturbances import Signal  # noqa: E402
from ftstab_mj.simulation.run_loop import Simulation  # noqa: E402

STEP = 1e-3
BATCH = 1000


def cpu(fn) -> float:
    t0 = time.process_time()
    fn()
    return time.process_time() - t0


def law_run(plant, controller: dict, r: int, steps: int, use_native) -> float:
    spec = ControllerSpec.of(**controller)
    loop = LoopSpec("cart", z0=(1.0,) + (0.0,) * (r - 1), controller=spec,
                    disturbance=Signal("sine", 0.0, 0.8, freq=0.5), gain=Signal("sine", 1.0, 0.4, freq=0.3, phase=1.0))
    sim = Simulation(plant, [loop], STEP, STEP, native=use_native)

    def go():
        with sim.installed():
            for _ in range(steps // BATCH):
                sim.advance(BATCH)

    return cpu(go)


def bare(plant, steps: int) -> float:
    """mj_step(nstep) with no callback and, like the run loop, MuJoCo's profiling timer off."""
    m, d, _ = plant.compile(STEP)
    with timer_off():
        return cpu(lambda: mujoco.mj_step(m, d, nstep=steps))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--steps", type=int, default=20000)
    ap.add_argument("--r", type=int, default=2, choices=(2, 3))
    args = ap.parse_args(argv)
    cmp = load_comparison(ROOT / "scenarios" / "compare" / f"cart_r{args.r}.toml")
    plant = make_plant("cart" if args.r == 2 else "cart_integrating")
    print(f"law costs on the cart, r = {args.r}: {args.steps} samples of 1 ms, {args.repeat} repetitions, CPU time")
    print(f"{'law':<32} {'path':<7} {'x bare (median, min-max)':>26} {'extra us/sample':>16}")
    for entry in cmp.laws:
        paths = [False]
        spec_law = ControllerSpec.of(**entry.controller).build(args.r)
        if native.use_native("auto", spec_law):
            paths.insert(0, True)
        for use_native in paths:
            ratios, extra = [], []
            for _ in range(args.repeat):  # A then B in each repetition: a load change hits both
                t_law = law_run(plant, entry.controller, args.r, args.steps, use_native)
                t_bare = bare(plant, args.steps)
                ratios.append(t_law / t_bare)
                extra.append((t_law - t_bare) / args.steps * 1e6)
            med = statistics.median(ratios)
            print(f"{entry.label:<32} {'native' if use_native else 'python':<7} "
                  f"{med:>10.2f} ({min(ratios):.2f}-{max(ratios):.2f}){'':>6} {statistics.median(extra):>16.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

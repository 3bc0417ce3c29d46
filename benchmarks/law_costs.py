"""Cost of every registered control law in the run loop, on the cart and on the arm, as a ratio to bare
MuJoCo stepping.

    python -m benchmarks law_costs [--repeat 3] [--steps 10000] [--r 2] [--no-python] [--law LABEL ...]

The laws: every entry of the shipped comparisons scenarios/compare/cart_r<r>.toml and field_r<r>.toml
(their parameters, one row per label). The plants: the cart (r = 2, or the integrating cart at r = 3)
and the two-joint arm (the same law on both joints; r = 2 only). Each law runs on each path it can take:
the native C callback (its twin in laws.c) and, unless --no-python, the Python callback (the reference
path a plugin law takes). One repetition times Simulation.advance over ``steps`` control samples
(period = physics step = 1 ms, batches of 1000) and, right after it, mj_step(m, d, nstep) of the same
compiled model with no callback; the table shows the median CPU-time ratio over the repetitions with
its min-max, and the extra cost per control sample in microseconds over bare stepping (median of (run
time - bare time) / samples). A run that diverges before its last sample is marked (its time covers
fewer samples). CPU time of this process: on a shared machine wall time mostly measures the others.

The Python path against a hand loop (r = 2): each repetition also times what a user writes by hand
with the same law objects, on the same compiled model from the same state (``hand_loop``: per
sample, z from qpos and qvel, ``law.evaluate``, ``law.advance`` for a law with a state, ctrl = u,
mj_step); the column "x hand" is the median of (Python path time) / (hand loop time). The Python
path also records every field of every sample, the true phi and gamma and the body poses, and
injects the disturbance and the gain: the hand loop does none of it. Goal: <= 2.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import mujoco
import numpy as np

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


def loops_for(plant, controller: dict, r: int) -> list:
    """One LoopSpec per loop of the plant, all under ``controller``: the cart with the comparisons'
    disturbance and gain, the arm's joints from 0.2 rad off their set points."""
    spec = ControllerSpec.of(**controller)
    if plant.model_name.startswith("cart"):
        return [LoopSpec("cart", z0=(1.0,) + (0.0,) * (r - 1), controller=spec,
                         disturbance=Signal("sine", 0.0, 0.8, freq=0.5),
                         gain=Signal("sine", 1.0, 0.4, freq=0.3, phase=1.0))]
    return [LoopSpec(name, z0=(0.2,) + (0.0,) * (r - 1), controller=spec, ref=0.3 * i)
            for i, name in enumerate(plant.loop_names)]


def law_run(plant, controller: dict, r: int, steps: int, use_native) -> tuple[float, bool]:
    """(CPU seconds of the controlled run, whether it ran to its last sample)."""
    sim = Simulation(plant, loops_for(plant, controller, r), STEP, STEP, native=use_native)
    if use_native is True and sim._native is None:
        raise RuntimeError("native run asked for but the Python callback was installed")

    def go():
        with sim.installed():
            for _ in range(steps // BATCH):
                sim.advance(BATCH)
                if sim.stop_reason:
                    return

    return cpu(go), not sim.stop_reason


def hand_loop(plant, controller: dict, r: int, steps: int) -> float:
    """CPU seconds of a user's loop (r = 2) with the Python path's law objects, model and initial state."""
    sim = Simulation(plant, loops_for(plant, controller, r), STEP, STEP, native=False)
    m, d, laws, refs = sim.model, sim.data, sim.laws, sim.refs.tolist()
    n = len(laws)
    dof = list(range(n)) if plant.dof_ids is None else [int(i) for i in plant.dof_ids]
    act = list(range(n)) if plant.actuator_ids is None else [int(i) for i in plant.actuator_ids]
    states = [law.initial_state() for law in laws]
    qpos, qvel, ctrl, z = d.qpos, d.qvel, d.ctrl, np.zeros(2)

    def go():
        for _ in range(steps):
            for i, law in enumerate(laws):
                z[0], z[1] = qpos[dof[i]] - refs[i], qvel[dof[i]]
                out = law.evaluate(z, states[i])
                if law.state_size:
                    states[i] = law.advance(z, states[i], out, STEP)
                ctrl[act[i]] = out.u
            mujoco.mj_step(m, d)

    with timer_off():
        return cpu(go)


def bare(plant, steps: int) -> float:
    """mj_step(nstep) with no callback and, like the run loop, MuJoCo's profiling timer off."""
    m, d, _ = plant.compile(STEP)
    with timer_off():
        return cpu(lambda: mujoco.mj_step(m, d, nstep=steps))


def entries(r: int) -> list:
    """(label, controller) of every law of the shipped comparisons at chain length r, first label kept."""
    out, seen = [], set()
    for name in ("cart", "field"):
        path = ROOT / "scenarios" / "compare" / f"{name}_r{r}.toml"
        if path.exists():
            for e in load_comparison(path).laws:
                if e.label not in seen:
                    seen.add(e.label)
                    out.append((e.label, e.controller))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--steps", type=int, default=10000)
    ap.add_argument("--r", type=int, default=2, choices=(2, 3))
    ap.add_argument("--no-python", action="store_true", help="time the native path only")
    ap.add_argument("--law", action="append", metavar="LABEL", help="only this law (repeatable; default: all)")
    args = ap.parse_args(argv)
    plants = [make_plant("cart" if args.r == 2 else "cart_integrating")] + ([make_plant("arm")] if args.r == 2 else [])
    print(f"law costs, r = {args.r}: {args.steps} samples of 1 ms, {args.repeat} repetitions, CPU time")
    print(f"{'law':<32} {'plant':<17} {'path':<7} {'x bare (median, min-max)':>26} {'extra us/sample':>16}"
          f"{'  x hand' if args.r == 2 else ''}")
    for label, controller in entries(args.r):
        if args.law and label not in args.law:
            continue
        law = ControllerSpec.of(**controller).build(args.r)
        paths = ([True] if native.use_native("auto", law) else []) + ([] if args.no_python else [False])
        for plant in plants:
            for use_native in paths:
                ratios, extra, by_hand, whole = [], [], [], True
                against_hand = args.r == 2 and not use_native
                for _ in range(args.repeat):  # A then B in each repetition: a load change hits both
                    t_law, done = law_run(plant, controller, args.r, args.steps, use_native)
                    t_bare = bare(plant, args.steps)
                    if against_hand:
                        by_hand.append(t_law / hand_loop(plant, controller, args.r, args.steps))
                    whole = whole and done
                    ratios.append(t_law / t_bare)
                    extra.append((t_law - t_bare) / args.steps * 1e6)
                med = statistics.median(ratios)
                note = "" if whole else "  (diverged: fewer samples)"
                hand = f"{statistics.median(by_hand):>8.2f}" if by_hand else (" " * 8 if args.r == 2 else "")
                print(f"{label:<32} {plant.model_name:<17} {'native' if use_native else 'python':<7} "
                      f"{med:>10.2f} ({min(ratios):.2f}-{max(ratios):.2f}){'':>6} {statistics.median(extra):>16.2f}"
                      f"{hand}{note}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The physical loop (sensor, observer, actuator stages): its cost in the control callback and its figures.

    python -m benchmarks physical_loop [--repeat 5] [--steps 100000] [--figures]

Cost. The robust law on the cart (r = 2) and the integrating cart (r = 3), one control sample per
1 ms physics step, batches of 1000 samples: Simulation.advance with every stage on (position-only
sensor with uniform noise and a one-period delay, Levant's differentiator of order r - 1, actuator
with saturation, rate limit and a first-order lag) against the same run without stages and against
bare mj_step(nstep) of the same model, taken one after the other in each repetition (median and
min-max of the ratios, wall and CPU time; CPU is the testbed's own cost on a loaded machine). The
Python pipeline is measured the same way for reference.

Figures (--figures): the fitted slopes of Levant's differentiator on sin t (noise-free against
the sampling period, noisy against the noise amplitude), the output-feedback accuracy of the robust
law against the noise, and the chattering amplitude against the actuator lag (first and second
order). The same computations as tests/test_loop_stages.py and tests/test_physical_loop.py.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.speed import BATCH, STEP, Clock, bare, loops, summary  # noqa: E402
from ftstab_mj.simulation import native  # noqa: E402
from ftstab_mj.plants import make_plant  # noqa: E402
from ftstab_mj.scenario.schema import ActuatorSpec, ObserverSpec, SensorSpec  # noqa: E402
from ftstab_mj.simulation.run_loop import Simulation  # noqa: E402

STAGES = dict(sensor=SensorSpec(measured="position", noise=1e-4, delay=1, seed=1),
              observer=ObserverSpec(kind="levant", L=20.0),
              actuator=ActuatorSpec(u_max=50.0, rate_max=1e5, tau=0.002))


def advance(plant, r: int, steps: int, use_native, staged: bool) -> Clock:
    from dataclasses import replace

    lps = loops("robust", r)
    if staged:
        lps = [replace(lp, **STAGES) for lp in lps]
    sim = Simulation(plant, lps, STEP, STEP, native=use_native)
    if use_native is True and sim._native is None:
        raise RuntimeError("the native callback did not take this simulation")

    def go():
        with sim.installed():
            for _ in range(steps // BATCH):
                sim.advance(BATCH)

    return Clock(go)


def cost(repeat: int, steps: int) -> list:
    rows = []
    for model, r in (("cart", 2), ("cart_integrating", 3)):
        plant = make_plant(model)
        on, off, on_off = [], [], []
        for _ in range(repeat):
            b = bare(plant, steps)
            a = advance(plant, r, steps, True, False)
            s = advance(plant, r, steps, True, True)
            on.append(s / b)
            off.append(a / b)
            on_off.append(s / a)
        rows += [(f"native callback r={r}, all stages on", "x bare", on),
                 (f"native callback r={r}, no stages", "x bare", off),
                 (f"  stages on / off, native r={r}", "x", on_off)]
        short = max(steps // 10, BATCH)
        py = [advance(plant, r, short, False, True) / advance(plant, r, short, False, False)
              for _ in range(min(repeat, 3))]
        per = [(c.wall / short * 1e6, c.cpu / short * 1e6) for c in
               (advance(plant, r, short, False, True) for _ in range(min(repeat, 3)))]
        rows += [(f"  Python pipeline r={r}: stages on / off", "x", py),
                 (f"  Python pipeline r={r}, stages on", "us/sample", per)]
    return rows


def figures() -> None:
    sys.path.insert(0, str(ROOT / "tests"))
    from test_loop_stages import L, differentiate, slopes

    from ftstab_mj.simulation.stages import LevantDifferentiator
    from ftstab_mj.scenario import SCENARIO_DIR, load_scenario
    from ftstab_mj.scenario.run import run_scenario

    taus = 1e-3 * 2.0 ** np.arange(4)
    print("Levant's differentiator on sin t (L = 2), max |z_i - f^(i)| over the second half of the run")
    for n, nf in ((1, 0), (2, 0), (3, 0), (2, 1)):
        fit = slopes(taus, differentiate(LevantDifferentiator(n, L, nf), taus, 0.0, T=20.0))
        print(f"  noise-free, n = {n}{', filtering n_f = 1' if nf else ''}: slopes vs tau (1..8 ms) "
              f"{np.round(fit, 3).tolist()}  theory {list(range(n + 1, 0, -1))}")
    eps = 10.0 ** np.arange(-4.0, 1.0)
    for n in (1, 2):
        fit = slopes(eps, differentiate(LevantDifferentiator(n, L), 2.5e-4, eps, T=10.0))
        theory = [round((n - i + 1) / (n + 1), 3) for i in range(n + 1)]
        print(f"  noisy, n = {n}, tau = 0.25 ms: slopes vs eps (1e-4..1) {np.round(fit, 3).tolist()}  theory {theory}")
    robust = SCENARIO_DIR / "cart_r2_robust.toml"
    eps = np.array([1e-4, 3e-4, 1e-3, 3e-3, 1e-2])
    acc = []
    for e in eps:
        run = run_scenario(load_scenario(robust, [
            "loops.cart.sensor.measured=position", f"loops.cart.sensor.noise={e}", "loops.cart.observer.kind=levant",
            "loops.cart.observer.L=5", "sim.period=0.00025", "sim.physics_step=0.00025", "metrics.final_fraction=0.5"]))
        acc.append(run.metrics["loops"]["cart"]["final_abs_z_max"])
    acc = np.array(acc)
    fit = [np.polyfit(np.log(eps), np.log(acc[:, i]), 1)[0] for i in range(2)]
    print("Output feedback, robust law, cart r = 2, position with uniform noise eps, levant n = 1, L = 5, 0.25 ms")
    for e, a in zip(eps, acc):
        print(f"  eps = {e:g} m: final max |x| = {a[0]:.3g} m, |x'| = {a[1]:.3g} m/s")
    print(f"  slopes {np.round(fit, 3).tolist()}  theory eps^(p_i / (r p_r)) = [0.625, 0.5]")
    print("Chattering amplitude (final max |x'|, m/s) vs actuator lag, robust law, cart r = 2, h = 0.5 ms, 6 s")
    base = ["sim.duration=6", "sim.physics_step=0.0005"]
    free = run_scenario(load_scenario(robust, base)).metrics["loops"]["cart"]["final_abs_z_max"][1]
    print(f"  no lag: {free:.3g}")
    for tau in (0.002, 0.005, 0.01, 0.02):
        amp = [run_scenario(load_scenario(robust, base + [f"loops.cart.actuator.tau={tau}"] + extra))
               .metrics["loops"]["cart"]["final_abs_z_max"][1]
               for extra in ([], ["loops.cart.actuator.lag_order=2"])]
        print(f"  tau = {tau * 1e3:g} ms: first order {amp[0]:.3g}, second order {amp[1]:.3g}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=5, help="repetitions of every measurement (default 5)")
    ap.add_argument("--steps", type=int, default=100_000, help="physics steps per timing (default 100000)")
    ap.add_argument("--figures", action="store_true", help="also print the accuracy and chattering figures")
    args = ap.parse_args(argv)
    if not native.available():
        print(f"note: {native.UNAVAILABLE_REASON}: the native rows cannot be measured", file=sys.stderr)
        return 2
    rows = cost(args.repeat, args.steps)
    print(f"ftstab_mj physical loop cost: {args.steps} steps of {STEP * 1e3:g} ms, {args.repeat} repetitions, "
          f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs")
    print(f"{'measurement':48s} {'wall median (min-max)':>24s} {'CPU median (min-max)':>24s}  unit")
    for what, unit, values in rows:
        cols = []
        for k in (0, 1):
            med, lo, hi = summary([v[k] for v in values])
            cols.append(f"{med:.3g} ({lo:.3g}-{hi:.3g})")
        print(f"{what:48s} {cols[0]:>24s} {cols[1]:>24s}  {unit}")
    if args.figures:
        figures()
    return 0


if __name__ == "__main__":
    sys.exit(main())

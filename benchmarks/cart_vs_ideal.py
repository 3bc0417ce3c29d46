"""Discrepancy between the MuJoCo carts and the ideal chain (the figures of issue 3's closing note).

    python -m benchmarks.cart_vs_ideal

Same robust law, phi(t) = 0.5 sin(2 pi t), gamma(t) = 1 + 0.2 sin(pi t), cart mass 2 kg, z0 = (1, 0[, 0]),
6 s. For each chain length r, control period and physics step h (N = period / h steps per period)
and integrator, prints max |z_mj - z_ideal| per component over the transient (samples before the
ideal V1 first drops below 1e-2) and over the whole run (which includes the chattering phase, where
both stay in an O(period) band but need not agree sample by sample).
"""

import numpy as np

from ftstab_mj.control import HongController, RobustLaw
from ftstab_mj.plants.disturbances import Signal
from ftstab_mj.simulation.ideal_chain import simulate_chain
from ftstab_mj.plants import make_plant
from ftstab_mj.scenario import LoopSpec

from ftstab_mj.simulation.run_loop import simulate

HONG = {2: HongController(2, -0.2, (1.0, 2.0)), 3: HongController(3, -0.1, (1.0, 1.7, 5.0))}
MODEL = {2: "cart", 3: "cart_integrating"}
PHI = Signal("sine", amplitude=0.5, freq=1.0)
GAMMA = Signal("sine", offset=1.0, amplitude=0.2, freq=0.5)


def discrepancy(r, period, N, integrator, duration=6.0):
    law = RobustLaw(HONG[r], phibar=0.5, gamma_m=0.8)
    z0 = np.array((1.0,) + (0.0,) * (r - 1))
    res = simulate(make_plant(MODEL[r], {"mass": 2.0}), [LoopSpec("cart", controller=law, disturbance=PHI, gain=GAMMA, z0=tuple(z0))],
                   duration=duration, period=period, physics_step=period / N, integrator=integrator)
    chain = simulate_chain(law, z0, period, duration, PHI, GAMMA, substeps=N)
    diff = np.abs(res.loops["cart"]["z"] - chain.z)
    end = int(np.argmax(chain.V1 < 1e-2))
    return diff[:end].max(axis=0), diff.max(axis=0)


def main():
    fmt = lambda a: "[" + ", ".join(f"{x:.2e}" for x in a) + "]"  # noqa: E731
    print(f"{'r':>2} {'period':>7} {'N':>4} {'h':>8} {'integrator':>10}  transient max|dz|            whole run max|dz|")
    for r in (2, 3):
        for period in (0.01, 0.02):
            for N in (10, 100):
                for integ in ("euler", "rk4"):
                    tr, full = discrepancy(r, period, N, integ)
                    print(f"{r:>2} {period:>7g} {N:>4} {period / N:>8g} {integ:>10}  {fmt(tr):<28} {fmt(full)}")


if __name__ == "__main__":
    main()

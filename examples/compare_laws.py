"""Robust against adaptive law on the cart under the same disturbance: settle time, final accuracy,
chattering, from the Python API. Run: python examples/compare_laws.py [--duration S] [--out DIR]"""

import argparse

import numpy as np

import ftstab_mj


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--duration", type=float, default=10.0, help="simulated seconds per run")
    ap.add_argument("--out", default=None, help="also write each run's logs here")
    args = ap.parse_args(argv)
    rows = []
    for name in ("cart_r2_robust", "cart_r2_adaptive"):
        res = ftstab_mj.run(name, out=args.out, overrides={"sim.duration": args.duration})
        cart = res.metrics["loops"]["cart"]
        z = res.samples["cart"]["z"]  # (n, 2): position and velocity errors, m and m/s
        rows.append((name, res.status, cart["settle_time"], float(np.abs(z[-100:, 0]).max()), cart["chattering"]))
    print(f"{'scenario':<18} {'status':<10} {'settled at (s)':>14} {'final |x| (m)':>14} {'chattering':>11}")
    for name, status, settle, final, chat in rows:
        settle = "never" if settle is None else f"{settle:.3f}"
        print(f"{name:<18} {status:<10} {settle:>14} {final:>14.3g} {chat:>11.4g}")
    return rows


if __name__ == "__main__":
    main()
